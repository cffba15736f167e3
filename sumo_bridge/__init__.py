"""Authoritative SUMO days through libsumo: `run_day` for one day, `SumoPool` for many."""

from sumo_bridge.config import SumoConfig
from sumo_bridge.pool import DayExecutor, InProcessExecutor, SumoDayError, SumoPool
from sumo_bridge.sim import Simulator, run_day
from sumo_bridge.types import ARRIVED, REMOVED_CAP, REMOVED_STUCK, DayResult

__all__ = [
    "ARRIVED", "REMOVED_CAP", "REMOVED_STUCK", "DayExecutor", "DayResult", "InProcessExecutor",
    "Simulator", "SumoConfig", "SumoDayError", "SumoPool", "run_day",
]
