"""Authoritative SUMO days through libsumo: `run_day` for one day, `SumoPool` for many."""

from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.sumo_bridge.pool import DayExecutor, InProcessExecutor, SumoDayError, SumoPool
from urb_jax.sumo_bridge.sim import Simulator, run_day
from urb_jax.sumo_bridge.types import ARRIVED, REMOVED_CAP, REMOVED_STUCK, DayResult

__all__ = [
    "ARRIVED", "REMOVED_CAP", "REMOVED_STUCK", "DayExecutor", "DayResult", "InProcessExecutor",
    "Simulator", "SumoConfig", "SumoDayError", "SumoPool", "run_day",
]
