"""Authoritative SUMO days through libsumo: `run_day` for one day, a `DayExecutor` for many.

`run_days` runs a batch in this process (no workers: safe in a script without a main guard).
Executors: `InProcessExecutor` (this process), `SumoPool` (worker processes), `RayExecutor` (Ray
actors; Ray is imported only when one is built), `MemoExecutor` (around any of them: each
distinct day once, optionally kept on disk).
"""

from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.sumo_bridge.keys import day_key, scenario_key
from urb_jax.sumo_bridge.memo import MemoExecutor
from urb_jax.sumo_bridge.pool import SumoPool
from urb_jax.sumo_bridge.ray_executor import RayExecutor
from urb_jax.sumo_bridge.scheduler import SumoDayError, SumoOutOfMemoryError
from urb_jax.sumo_bridge.sim import InProcessExecutor, Simulator, run_day, run_days
from urb_jax.sumo_bridge.types import ARRIVED, REMOVED_CAP, REMOVED_STUCK, DayExecutor, DayResult, one_day

__all__ = [
    "ARRIVED", "REMOVED_CAP", "REMOVED_STUCK", "DayExecutor", "DayResult", "InProcessExecutor",
    "MemoExecutor", "RayExecutor", "Simulator", "SumoConfig", "SumoDayError", "SumoOutOfMemoryError",
    "SumoPool", "day_key", "one_day", "run_day", "run_days", "scenario_key",
]
