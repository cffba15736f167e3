"""Identical SUMO days run once: SUMO is deterministic for a (scenario, choices, CAV mask, seed).

URB's test phase repeats one joint action: greedy policies meet frozen deterministic humans, so
all `test_eps` days of a seed are the same day. Simulating it once and reusing the result gives
the same records as simulating it 100 times (`tests/test_sumo_pool.py` checks that days are
deterministic across workers and repeats), at a hundredth of the cost.
"""

from __future__ import annotations

import hashlib

import numpy as np

from urb_jax.sumo_bridge.batch import as_batch
from urb_jax.sumo_bridge.types import DayExecutor, DayResult


class MemoExecutor:
    """Wraps an executor; a batch runs each distinct (choices, mask, seed) it has not seen once."""

    def __init__(self, inner: DayExecutor) -> None:
        self.inner = inner
        self.cache: dict[tuple[int, str], DayResult] = {}
        self.simulated = 0
        self.reused = 0

    @staticmethod
    def _key(scenario: object, choices: np.ndarray, seed: int, mask: np.ndarray | None) -> tuple[int, str]:
        h = hashlib.sha256(np.ascontiguousarray(choices, dtype=np.int64).tobytes())
        h.update(b"-" if mask is None else np.ascontiguousarray(mask, dtype=bool).tobytes())
        h.update(str(seed).encode())
        return id(scenario), h.hexdigest()

    def run_days(self, scenario: object, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        choices, seeds, cavs = as_batch(choices, seeds, is_cav)
        keys = [self._key(scenario, c, s, m) for c, s, m in zip(choices, seeds, cavs, strict=True)]
        todo: dict[tuple[int, str], int] = {}
        for i, key in enumerate(keys):
            if key not in self.cache and key not in todo:
                todo[key] = i
        if todo:
            rows = list(todo.values())
            mask_arg = None if cavs[0] is None else np.stack([cavs[i] for i in rows])
            for key, res in zip(todo, self.inner.run_days(scenario, choices[rows], [seeds[i] for i in rows],
                                                          is_cav=mask_arg), strict=True):
                self.cache[key] = res
        self.simulated += len(todo)
        self.reused += len(keys) - len(todo)
        return [self.cache[k] for k in keys]

    def close(self) -> None:
        self.inner.close()
