"""The contract every other layer codes against: what a SUMO day returns (`DayResult`) and what
runs a batch of days (`DayExecutor`).

Arrays are per vehicle, in the Scenario's agent order (sorted by departure).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Protocol

import numpy as np

from urb_jax.city.scenario import Scenario

ARRIVED = 0
REMOVED_STUCK = 1  # stood still too long (SumoConfig.stuck_rule), charged SumoConfig.stuck_penalty
REMOVED_CAP = 2  # still driving or waiting at SumoConfig.max_sim_time_s, charged like stuck
STAYED_HOME = 3  # chose ABSENT (the task's day_participation): no vehicle, every time NaN


@dataclass(frozen=True)
class DayResult:
    travel_time: np.ndarray  # [N] minutes, URB's measure: (arrival step - scheduled depart) / 60,
    #                          insertion delay included; stuck vehicles get the stuck penalty
    duration: np.ndarray  # [N] s, SUMO tripinfo duration (NaN if removed)
    route_length: np.ndarray  # [N] m, distance driven
    mean_speed: np.ndarray  # [N] m/s, route_length / duration (NaN if removed)
    time_loss: np.ndarray  # [N] s, SUMO timeLoss
    depart_delay: np.ndarray  # [N] s, SUMO departDelay
    status: np.ndarray  # [N] int8: ARRIVED, REMOVED_STUCK, REMOVED_CAP or STAYED_HOME
    seed: int
    # Day statistics as SUMO's statistic output reports them (arrived vehicles).
    stat_mean_speed: float  # m/s, mean over arrived trips of routeLength / duration
    stat_mean_route_length: float  # m
    stat_mean_duration: float  # s
    teleports: int
    n_removed: int
    sim_end_time: float  # s, SUMO time when the day ended
    wall_time: float  # s
    leave_time: np.ndarray | None = None  # [N] s, SUMO time of arrival or removal
    # SumoConfig.emissions only (else None): SUMO's emission device, default emission class, totals
    # up to arrival or removal; NaN for a vehicle SUMO never inserted (no tripinfo).
    co2_g: np.ndarray | None = None  # [N] g of CO2
    fuel_mg: np.ndarray | None = None  # [N] mg of fuel (SUMO's unit)

    def same_as(self, other: DayResult) -> bool:
        """Equal in everything SUMO decides (wall_time excluded); NaNs compare equal."""
        for f in fields(self):
            if f.name == "wall_time":
                continue
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(a, b, equal_nan=True):
                    return False
            elif a != b:
                return False
        return True

    @property
    def n(self) -> int:
        return int(self.travel_time.shape[0])


class DayExecutor(Protocol):
    """Runs B SUMO days and returns their results in batch order: `SumoPool` (processes),
    `RayExecutor` (Ray actors), `InProcessExecutor` (this process), `MemoExecutor` (around one of
    them: each distinct day once). `choices` [B, N]; `seeds` one or [B]; `is_cav` [N] or [B, N]."""

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]: ...

    def close(self) -> None: ...


def one_day(executor: DayExecutor, scenario: Scenario, choices: np.ndarray, seed: int,
            is_cav: np.ndarray | None = None) -> DayResult:
    """One day on `executor`: a batch of one (the protocol's days, which depend on yesterday's)."""
    mask = None if is_cav is None else np.asarray(is_cav)[None]
    return executor.run_days(scenario, np.asarray(choices)[None], [int(seed)], mask)[0]

