"""A SUMO pool worker whose day runs out of memory: the pool's real worker loop (`pool._worker_main`)
around a stand-in simulator (FakeDay's days, no SUMO) that, as $URB_JAX_TEST_OOM says, raises
MemoryError ("memory"), is killed by SIGKILL as the kernel's out-of-memory killer does ("kill"), or
raises MemoryError on the first day only and runs the retry ("memory-once:<marker file>").
A test sets the variable and puts `worker_main` in place of `pool._worker_main`: spawned workers
inherit the environment and import this module by name."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

from support.fakeday import FakeDay
from urb_jax.sumo_bridge import pool

MODE = "URB_JAX_TEST_OOM"


class OutOfMemorySim:
    """Simulator's interface (run_day, close) on FakeDay, failing as $URB_JAX_TEST_OOM says."""

    def __init__(self, config: Any, console_warnings: bool = False) -> None:
        self.day = FakeDay()

    def run_day(self, scenario: Any, choices: Any, *, seed: int, is_cav: Any = None, next_seed: Any = None):
        mode = os.environ.get(MODE, "")
        if mode == "kill":
            os.kill(os.getpid(), signal.SIGKILL)
        if mode == "memory" or (mode.startswith("memory-once:") and _first(Path(mode.split(":", 1)[1]))):
            raise MemoryError("simulated: out of memory in a SUMO worker")
        return self.day(scenario, choices, seed=seed, is_cav=is_cav)

    def close(self) -> None:
        pass


def _first(marker: Path) -> bool:
    """True the first time (creating `marker`), False after."""
    try:
        marker.touch(exist_ok=False)
    except FileExistsError:
        return False
    return True


def worker_main(conn: Any, config: Any, log_path: str) -> None:
    pool.Simulator = OutOfMemorySim  # type: ignore[misc]  # this process only
    pool._worker_main(conn, config, log_path)
