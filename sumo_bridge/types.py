"""What a SUMO day returns. The contract every other layer codes against.

Arrays are per vehicle, in the Scenario's agent order (sorted by departure).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ARRIVED = 0
REMOVED_STUCK = 1


@dataclass(frozen=True)
class DayResult:
    travel_time: np.ndarray  # [N] minutes, URB's measure: (arrival step - scheduled depart) / 60,
    #                          insertion delay included; stuck vehicles get the stuck penalty
    duration: np.ndarray  # [N] s, SUMO tripinfo duration (NaN if removed)
    route_length: np.ndarray  # [N] m, distance driven
    mean_speed: np.ndarray  # [N] m/s, route_length / duration (NaN if removed)
    time_loss: np.ndarray  # [N] s, SUMO timeLoss
    depart_delay: np.ndarray  # [N] s, SUMO departDelay
    status: np.ndarray  # [N] int8: ARRIVED or REMOVED_STUCK
    seed: int
    # Day statistics as SUMO's statistic output reports them (arrived vehicles).
    stat_mean_speed: float  # m/s, mean over arrived trips of routeLength / duration
    stat_mean_route_length: float  # m
    stat_mean_duration: float  # s
    teleports: int
    n_removed: int
    sim_end_time: float  # s, SUMO time when the day ended
    wall_time: float  # s

    @property
    def n(self) -> int:
        return int(self.travel_time.shape[0])
