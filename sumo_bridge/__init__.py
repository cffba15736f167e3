"""Authoritative SUMO days through libsumo: `run_day` for one day, `SumoPool` for many."""

from sumo_bridge.types import ARRIVED, REMOVED_STUCK, DayResult

__all__ = ["ARRIVED", "REMOVED_STUCK", "DayResult"]
