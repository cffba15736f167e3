"""A deterministic stand-in for a SUMO day: route time = FFT * (1 + load / 20) per (OD, route),
SUMO duration 2 s shorter (as `sumo_bridge` records them), itself a DayExecutor that runs a batch
a day at a time (a driver who chose ABSENT, -1, stays home: no load, NaN times, STAYED_HOME, as
`sumo_bridge` records it); and FakeExecutor, a DayExecutor that runs it and remembers every batch (the
tests', tests/support/compile_cache_run.py's and benchmarks/gpu_hybrid_check.py's)."""

from __future__ import annotations

import numpy as np

from urb_jax.sumo_bridge.batch import as_batch
from urb_jax.sumo_bridge.types import ARRIVED, STAYED_HOME, DayResult


class FakeDay:
    """Callable with sumo_bridge.run_day's signature, and a DayExecutor; counts days and remembers
    every input (choices [N], CAV mask [N] or None)."""

    def run_days(self, scenario, choices, seeds, is_cav=None) -> list[DayResult]:
        batch = as_batch(choices, seeds, is_cav)
        return [self(scenario, c, seed=s, is_cav=m) for c, s, m in zip(*batch, strict=True)]

    def close(self) -> None:
        pass

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray | None]] = []

    def __call__(self, scenario, choices, *, seed, is_cav=None) -> DayResult:
        choices = np.asarray(choices)
        self.calls.append((choices.copy(), None if is_cav is None else np.asarray(is_cav).copy()))
        n = choices.shape[0]
        rows = np.arange(n)
        od = scenario.agent_od
        home = choices < 0  # ABSENT: no vehicle
        key = np.where(home, -1 - rows, od.astype(np.int64) * scenario.k + choices)  # alone, unseen
        _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
        load = counts[inv] - 1
        route = np.where(home, 0, choices)
        tt = np.where(home, np.nan, scenario.fft[rows, route] * (1.0 + load / 20.0))
        length = np.where(home, np.nan, scenario.od_route_length[od, route])
        dur = tt * 60.0 - 2.0  # SUMO's duration lacks RouteRL's 2 s recording lag (sumo_bridge)
        status = np.where(home, STAYED_HOME, ARRIVED).astype(np.int8)
        mean = np.nanmean if home.any() else np.mean
        return DayResult(
            travel_time=tt, duration=dur, route_length=length, mean_speed=length / dur,
            time_loss=np.zeros(n), depart_delay=np.zeros(n), status=status,
            seed=seed, stat_mean_speed=float(mean(length / dur)),
            stat_mean_route_length=float(mean(length)), stat_mean_duration=float(mean(dur)),
            teleports=0, n_removed=0, sim_end_time=0.0, wall_time=0.0,
        )


class FakeExecutor:
    """DayExecutor on FakeDay; remembers every batch and can fail on a chosen call (a kill)."""

    def __init__(self, fail_on_call: int | None = None, simulator: str | None = None) -> None:
        self.day = FakeDay()
        self.batches: list[tuple[np.ndarray, np.ndarray | None]] = []
        self.fail_on_call = fail_on_call
        # what runs its days, for the SUMO day store (sumo_bridge.memo.day_store): None keeps its
        # days out of the store, a name lets a test store them (under keys no SUMO day has)
        self.simulator = simulator

    def run_days(self, scenario, choices, seeds, is_cav=None):
        if self.fail_on_call is not None and len(self.batches) + 1 == self.fail_on_call:
            raise KeyboardInterrupt("simulated kill during a SUMO batch")
        choices = np.asarray(choices)
        self.batches.append((choices.copy(), None if is_cav is None else np.asarray(is_cav).copy()))
        return self.day.run_days(scenario, choices, seeds, is_cav)

    def close(self) -> None:
        pass
