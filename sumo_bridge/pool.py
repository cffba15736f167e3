"""Many SUMO days in parallel: worker processes that each own one libsumo simulation.

`SumoPool.run_days(scenario, choices[B, N], seeds)` returns B DayResults in order. Days are
scheduled by `scheduler.schedule_days` (one retry loop for the pool and the Ray executor): a
worker that crashes, raises, or exceeds the per-day wall-clock limit is killed and restarted, and
its day is retried once; a second failure raises `SumoDayError` naming the network, the day and
SUMO's error output (the tail of that worker's log). A worker that runs out of memory sends its
MemoryError back as such ("oom"); one killed by SIGKILL without a result (the kernel's out-of-memory
killer) is taken for the same: a day that fails twice so raises `SumoOutOfMemoryError`. SUMO's
messages go to one log file per worker.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import shutil
import signal
import tempfile
import traceback
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import cast

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.interrupt import ignore_stop_signals
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.sumo_bridge.keys import sumo_version
from urb_jax.sumo_bridge.logs import log_folder, log_tail, redirect_fds
from urb_jax.sumo_bridge.scheduler import (
    DayJob,
    Failed,
    KeptScenarios,
    SumoDayError,
    memory_error_text,
    schedule_days,
)
from urb_jax.sumo_bridge.sim import Simulator
from urb_jax.sumo_bridge.types import DayResult


def _worker_main(conn: Connection, config: SumoConfig, log_path: str) -> None:
    """Worker loop: owns one Simulator; SUMO's output goes to the worker's log file. Ctrl-C, SIGTERM
    and SIGHUP are the parent's to handle (it kills us); a parent gone (EOF, a broken pipe) ends
    the loop quietly."""
    ignore_stop_signals()
    with redirect_fds(log_path):
        sim = Simulator(config, console_warnings=True)  # our stdout/stderr already go to the log
        with contextlib.suppress(EOFError, BrokenPipeError, ConnectionResetError):
            _serve_days(conn, sim)
        sim.close()


def _serve_days(conn: Connection, sim: Simulator) -> None:
    scenarios: KeptScenarios[Scenario] = KeptScenarios()
    conn.send(("ready", os.getpid()))
    while True:
        msg = conn.recv()
        if msg[0] == "stop":
            break
        _, tid, key, scn, choices, seed, is_cav, next_seed = msg
        if scn is not None:
            scenarios.add(key, scn)
        try:
            res = sim.run_day(scenarios[key], choices, seed=seed, is_cav=is_cav, next_seed=next_seed)
            conn.send(("ok", tid, res))
            sim.preload()  # the next day's network, while the parent takes this result
        except (BrokenPipeError, ConnectionResetError):
            raise  # the parent is gone
        except MemoryError:
            conn.send(("oom", tid, memory_error_text()))
        except Exception:
            conn.send(("err", tid, traceback.format_exc()))


class _Worker:
    """One worker process and its pipe, as the pool sees it (a `scheduler.Slot`)."""

    def __init__(self, ctx: mp.context.SpawnContext, index: int, config: SumoConfig, log_path: Path) -> None:
        self.index = index
        self.log_path = log_path
        self.shm_dir = config.shm_dir if os.path.isdir(config.shm_dir) else tempfile.gettempdir()
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker_main, args=(child, config, str(log_path)),
                                name=f"sumo-worker-{index}", daemon=True)
        self.proc.start()
        child.close()
        self.scenarios: KeptScenarios[None] = KeptScenarios()  # what the worker holds
        self.task: int | None = None
        self.started = 0.0
        self.finished = 0.0

    def wait_ready(self, timeout: float) -> None:
        if not self.conn.poll(timeout):
            raise SumoDayError(f"SUMO worker {self.index} did not start within {timeout:.0f} s; "
                               f"log {self.log_path}:\n{log_tail(self.log_path)}")
        try:
            self.conn.recv()
        except (EOFError, OSError) as exc:
            raise SumoDayError(f"SUMO worker {self.index} died while starting ({exc!r}, exit code "
                               f"{self.proc.exitcode}); log {self.log_path}:\n{log_tail(self.log_path)}"
                               ) from exc

    def kill(self) -> None:
        if self.proc.is_alive():
            with contextlib.suppress(ProcessLookupError):
                os.kill(cast(int, self.proc.pid), signal.SIGKILL)  # alive: started, so it has a pid
        self.proc.join(timeout=10)
        self.conn.close()
        for d in Path(self.shm_dir).glob(f"urbjax-sumo-{self.proc.pid}-*"):  # a killed worker's files
            shutil.rmtree(d, ignore_errors=True)


class SumoPool:
    """`n_workers` processes, each loading networks once per day with libsumo (reload, not restart)."""

    def __init__(self, n_workers: int = 2, config: SumoConfig | None = None,
                 log_dir: str | os.PathLike | None = None, day_timeout_s: float = 600.0,
                 start_timeout_s: float = 120.0) -> None:
        if n_workers < 1:
            raise ValueError("SumoPool needs n_workers >= 1 (use InProcessExecutor for none)")
        self.config = config or SumoConfig()
        self.day_timeout_s = float(day_timeout_s)
        self.start_timeout_s = float(start_timeout_s)
        self.log_dir, self._tmp = log_folder(log_dir, "urbjax-sumo-logs-")
        self._ctx = mp.get_context("spawn")  # never fork a process that may hold JAX threads
        self.restarts = 0
        self.slots = [self._spawn(i) for i in range(n_workers)]
        for w in self.slots:
            w.wait_ready(self.start_timeout_s)

    @property
    def simulator(self) -> str:
        """What runs the days (part of every stored day's key): `keys.sumo_version()`."""
        return sumo_version()

    def _spawn(self, index: int) -> _Worker:
        return _Worker(self._ctx, index, self.config, self.log_dir / f"sumo_worker{index}.log")

    def busy_pids(self) -> list[int]:
        """Process ids of workers running a day now (for fault-injection tests)."""
        return [w.proc.pid for w in self.slots if w.task is not None and w.proc.pid is not None]

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        return schedule_days(self, scenario, choices, seeds, is_cav, day_timeout_s=self.day_timeout_s)

    # --- the scheduler's backend (scheduler.Workers) ------------------------------------------
    def submit(self, w: _Worker, job: DayJob) -> Failed | None:
        send_scn = None if job.key in w.scenarios else job.scenario  # pickled to a worker once
        try:
            w.conn.send(("day", job.day, job.key, send_scn, job.choices, job.seed, job.is_cav, job.next_seed))
        except (BrokenPipeError, OSError) as exc:
            return _failed(w, f"worker {w.index} could not take the day ({exc!r})")
        if send_scn is not None:
            w.scenarios.add(job.key, None)
        return None

    def wait(self, busy: list[_Worker], timeout: float) -> dict[int, DayResult | Failed]:
        ready = wait([w.conn for w in busy] + [w.proc.sentinel for w in busy], timeout=timeout)
        out: dict[int, DayResult | Failed] = {}
        for w in busy:
            if w.conn in ready:
                try:
                    kind, _, payload = w.conn.recv()
                except (EOFError, OSError):
                    out[w.index] = _died(w)
                    continue
                out[w.index] = _outcome(w, kind, payload)
            elif w.proc.sentinel in ready:
                out[w.index] = _died(w)
        return out

    def overdue(self, w: _Worker) -> Failed:
        return _failed(w, f"worker {w.index} exceeded the {self.day_timeout_s:.0f} s day limit")

    def restart(self, w: _Worker) -> None:
        w.kill()
        self.restarts += 1
        nw = self._spawn(w.index)
        nw.wait_ready(self.start_timeout_s)
        self.slots[w.index] = nw

    def close(self) -> None:
        """Idle workers stop; busy ones (a day abandoned by Ctrl-C or an error) are killed at once."""
        for w in self.slots:
            if w.task is not None:
                w.kill()
                continue
            with contextlib.suppress(Exception):
                w.conn.send(("stop",))
        for w in self.slots:
            w.proc.join(timeout=5)
            w.kill()
        self.slots = []
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> SumoPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _failed(w: _Worker, reason: str, memory: bool = False) -> Failed:
    return Failed(f"{reason}\n--- SUMO log tail ({w.log_path}) ---\n{log_tail(w.log_path)}", str(w.log_path),
                  memory)


def _outcome(w: _Worker, kind: str, payload: object) -> DayResult | Failed:
    """A worker's answer: its day, the MemoryError it ran into, or the error it raised."""
    if kind == "ok":
        return cast(DayResult, payload)
    if kind == "oom":
        return _failed(w, f"worker {w.index} ran out of memory (MemoryError):\n{payload}", memory=True)
    return _failed(w, f"worker {w.index} raised:\n{payload}")


def _died(w: _Worker) -> Failed:
    """A worker that ended without an answer; killed by SIGKILL: most likely the kernel's
    out-of-memory killer (a kill -9 by hand reads the same, and is retried the same)."""
    w.proc.join(timeout=1)
    code = w.proc.exitcode
    if code == -signal.SIGKILL:
        return _failed(w, f"worker {w.index} died (exit code {code}: killed by SIGKILL, as the kernel's "
                          "out-of-memory killer does when memory runs out)", memory=True)
    return _failed(w, f"worker {w.index} died (exit code {code})")
