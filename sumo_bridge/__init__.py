"""Authoritative SUMO days through libsumo: `run_day` for one day, `SumoPool` for many."""

from sumo_bridge.config import SumoConfig
from sumo_bridge.sim import Simulator, run_day
from sumo_bridge.types import ARRIVED, REMOVED_CAP, REMOVED_STUCK, DayResult

__all__ = ["ARRIVED", "REMOVED_CAP", "REMOVED_STUCK", "DayResult", "Simulator", "SumoConfig", "run_day"]
