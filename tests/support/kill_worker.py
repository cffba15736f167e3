"""Kill one busy SUMO worker mid-day while an executor runs a batch: the crash test the process pool
and the Ray executor share (each then checks its own restart count, warning and log)."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable
from typing import Any


def run_killing_a_busy_worker(executor: Any, run: Callable[[], Any]) -> tuple[Any, list[int]]:
    """`run()`'s result, and the pid killed (SIGKILL) once a worker of `executor` (its `busy_pids()`)
    is 0.05 s into a day; the list is empty when no worker was busy within 60 s."""
    killed: list[int] = []

    def killer() -> None:
        deadline = time.monotonic() + 60
        while not executor.busy_pids() and time.monotonic() < deadline:
            time.sleep(0.002)
        time.sleep(0.05)  # into the day (a grid day takes a few tenths of a second)
        pids = executor.busy_pids()
        if pids:
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])

    th = threading.Thread(target=killer)
    th.start()
    try:
        out = run()
    finally:
        th.join()
    return out, killed
