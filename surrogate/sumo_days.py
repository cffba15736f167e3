"""SUMO days for calibration and validation, kept on disk between runs.

Every day runs through `sumo_bridge` (the project's one SUMO runner: URB's insertion, travel
time and stuck semantics, see docs/sumo_bridge.md) and is cached by its one day cache,
`sumo_bridge.MemoExecutor`, in the day store every run shares (`$URB_JAX_CACHE/sumo_days/`).
"""

from __future__ import annotations

import contextlib

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.sumo_bridge import SumoConfig, SumoPool, run_day
from urb_jax.sumo_bridge.batch import as_batch
from urb_jax.sumo_bridge.keys import sumo_version
from urb_jax.sumo_bridge.memo import day_store
from urb_jax.sumo_bridge.types import DayResult


def backend_name() -> str:
    """Recorded in validation reports."""
    return "sumo_bridge"


class _PoolPerBatch:
    """A `DayExecutor` that starts `workers` processes only for days not cached (a pool sized to
    the batch), or runs them in this process when `workers` <= 1."""

    config = SumoConfig()  # the defaults `run_day` and `SumoPool` use

    @property
    def simulator(self) -> str:
        return sumo_version()

    def __init__(self, workers: int) -> None:
        self.workers = workers

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        if self.workers > 1:
            with SumoPool(min(self.workers, len(choices))) as pool:
                return pool.run_days(scenario, choices, seeds, is_cav=is_cav)
        batch = as_batch(choices, seeds, is_cav)
        return [run_day(scenario, c, seed=s, is_cav=m) for c, s, m in zip(*batch, strict=True)]

    def close(self) -> None:
        pass


def sumo_days(
    scn: Scenario, choices: np.ndarray, seeds: np.ndarray | int = 42, *, workers: int = 2,
    use_cache: bool = True,
) -> list[DayResult]:
    """SUMO days for choices [B, N] (from the day store unless `use_cache` is False or the store is
    off: `sumo_bridge.memo.day_store`), the days not stored run `workers` at a time."""
    batch = as_batch(np.asarray(choices), seeds, None)
    with contextlib.closing(day_store(_PoolPerBatch(workers), enabled=use_cache)) as days:
        return days.run_days(scn, batch.choices, list(batch.seeds))
