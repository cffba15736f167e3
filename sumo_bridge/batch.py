"""A batch of SUMO days as every executor receives it, checked against the Scenario.

`DayExecutor.run_days(scenario, choices[B, N], seeds, is_cav)` takes one seed or B, and no CAV
mask (the Scenario's own agent kinds), one mask [N] for every day, or one per day [B, N].
Bad input fails here, in the caller's process, not twice in a worker.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from urb_jax.city.demand import ABSENT
from urb_jax.city.scenario import Scenario


class DayBatch(NamedTuple):
    choices: np.ndarray  # [B, N] route indices in the Scenario's agent order
    seeds: list[int]  # [B]
    cavs: list[np.ndarray | None]  # [B] of [N] bool masks, or None: the Scenario's agent kinds


def as_batch(choices: np.ndarray, seeds: int | Sequence[int] | np.ndarray, is_cav: np.ndarray | None
             ) -> DayBatch:
    """Broadcast seeds and the CAV mask to one per day (shapes only; see `check_batch`)."""
    choices = np.asarray(choices)
    if choices.ndim != 2:
        raise ValueError(f"choices has shape {choices.shape}; expected [B, N]")
    seed_list = [int(s) for s in np.broadcast_to(np.asarray(seeds), (choices.shape[0],))]
    if is_cav is None:
        cavs: list[np.ndarray | None] = [None] * len(seed_list)
    else:
        m = np.asarray(is_cav, dtype=bool)
        if m.shape not in (choices.shape, choices.shape[1:]):
            raise ValueError(f"is_cav has shape {m.shape}; expected [N] or [B, N] = {choices.shape}")
        cavs = list(np.broadcast_to(m, choices.shape))
    return DayBatch(choices, seed_list, cavs)


def check_batch(scenario: Scenario, batch: DayBatch) -> None:
    """Every day's choices and mask fit the Scenario (raises ValueError otherwise)."""
    for c, m in zip(batch.choices, batch.cavs, strict=True):
        check_choices(scenario, c)
        cav_mask(scenario, m)


def cav_mask(scenario: Scenario, is_cav: np.ndarray | None) -> np.ndarray:
    """[N] bool: the given mask, or the Scenario's own kinds (agents.csv 'AV') when None."""
    n = scenario.n_agents
    if is_cav is None:
        return np.array([k == "AV" for k in scenario.agent_kind], dtype=bool)
    mask = np.asarray(is_cav, dtype=bool)
    if mask.shape != (n,):
        raise ValueError(f"is_cav has shape {mask.shape}; expected ({n},) in the Scenario's agent order")
    return mask


def check_choices(scenario: Scenario, choices: np.ndarray) -> np.ndarray:
    """[N] int64 route indices in [0, K), or ABSENT (-1: the driver stays home that day), or
    ValueError."""
    c = np.asarray(choices)
    n, k = scenario.n_agents, scenario.k
    if c.shape != (n,):
        raise ValueError(f"choices has shape {c.shape}; expected ({n},) route indices in Scenario order")
    if not np.issubdtype(c.dtype, np.integer) or c.min() < ABSENT or c.max() >= k:
        raise ValueError(f"choices must be integer route indices in [0, {k}) or {ABSENT} (stays home); got "
                         f"{c.dtype} in [{c.min()}, {c.max()}]")
    return c.astype(np.int64)
