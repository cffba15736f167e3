"""Many SUMO days in parallel: worker processes that each own one libsumo simulation.

`SumoPool.run_days(scenario, choices[B, N], seeds)` returns B DayResults in order. A worker that
crashes, raises, or exceeds the per-day wall-clock limit is killed and restarted, and its day is
retried once; a second failure raises `SumoDayError` naming the network, the day and SUMO's
error output (the tail of that worker's log). SUMO's messages go to one log file per worker.

`DayExecutor` is the interface the trainer codes against; `InProcessExecutor` runs days in this
process, and a Ray executor can stand in later with the same two methods.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import shutil
import signal
import tempfile
import time
import traceback
from collections import deque
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Protocol

import numpy as np

from urb_jax.core.errors import UrbJaxError
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.sumo_bridge.sim import Simulator, cav_mask, check_choices, redirect_fds, scenario_key
from urb_jax.sumo_bridge.types import DayResult


class SumoDayError(UrbJaxError):
    """A SUMO day failed twice."""


class DayExecutor(Protocol):
    def run_days(self, scenario: object, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]: ...

    def close(self) -> None: ...


def failed_twice(scenario: object, day: int, seed: int, attempts: list[str], where: str = "") -> SumoDayError:
    """The error for a day that failed on its retry too: network, day, seed and both attempts' logs."""
    return SumoDayError(
        f"SUMO day {day} (seed {seed}) of network {getattr(scenario, 'name', '?')} failed twice{where}.\n"
        + "\n".join(f"attempt {i + 1}: {f}" for i, f in enumerate(attempts))
    )


def _batch(scenario: object, choices: np.ndarray, seeds: list[int] | np.ndarray,
           is_cav: np.ndarray | None) -> tuple[np.ndarray, list[int], list[np.ndarray | None]]:
    choices = np.asarray(choices)
    if choices.ndim != 2:
        raise ValueError(f"choices has shape {choices.shape}; expected [B, N]")
    seeds = [int(s) for s in np.broadcast_to(np.asarray(seeds), (choices.shape[0],))]
    if is_cav is None:
        cavs: list[np.ndarray | None] = [None] * len(seeds)
    else:
        m = np.asarray(is_cav, dtype=bool)
        if m.shape not in (choices.shape, choices.shape[1:]):
            raise ValueError(f"is_cav has shape {m.shape}; expected [N] or [B, N] = {choices.shape}")
        cavs = list(np.broadcast_to(m, choices.shape))
    return choices, seeds, cavs


class InProcessExecutor:
    """Days one after another in this process (libsumo: one simulation per process)."""

    def __init__(self, config: SumoConfig | None = None, log_file: str | os.PathLike | None = None) -> None:
        self.sim = Simulator(config, log_file)

    def run_days(self, scenario: object, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        choices, seeds, cavs = _batch(scenario, choices, seeds, is_cav)
        nxt = [*seeds[1:], seeds[-1]] if seeds else []
        return [self.sim.run_day(scenario, c, seed=s, is_cav=m, next_seed=n)
                for c, s, m, n in zip(choices, seeds, cavs, nxt, strict=True)]

    def close(self) -> None:
        self.sim.close()


def _worker_main(conn: Connection, config: SumoConfig, log_path: str) -> None:
    """Worker loop: owns one Simulator; SUMO's output goes to the worker's log file."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and kills us
    with redirect_fds(log_path):
        sim = Simulator(config, console_warnings=True)  # our stdout/stderr already go to the log
        scenarios: dict[str, object] = {}
        conn.send(("ready", os.getpid()))
        while True:
            try:
                msg = conn.recv()
            except EOFError:
                break
            if msg[0] == "stop":
                break
            _, tid, key, scn, choices, seed, is_cav, next_seed = msg
            if scn is not None:
                scenarios[key] = scn
            try:
                res = sim.run_day(scenarios[key], choices, seed=seed, is_cav=is_cav, next_seed=next_seed)
                conn.send(("ok", tid, res))
            except Exception:
                conn.send(("err", tid, traceback.format_exc()))
        sim.close()


class _Worker:
    def __init__(self, ctx: mp.context.BaseContext, index: int, config: SumoConfig, log_path: Path) -> None:
        self.index = index
        self.log_path = log_path
        self.shm_dir = config.shm_dir if os.path.isdir(config.shm_dir) else tempfile.gettempdir()
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker_main, args=(child, config, str(log_path)),
                                name=f"sumo-worker-{index}", daemon=True)
        self.proc.start()
        child.close()
        self.scenarios: set[str] = set()
        self.task: int | None = None
        self.started = 0.0
        self.ready = False

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
        self.ready = True

    def kill(self) -> None:
        if self.proc.is_alive():
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.join(timeout=10)
        self.conn.close()
        for d in Path(self.shm_dir).glob(f"urbjax-sumo-{self.proc.pid}-*"):  # a killed worker's files
            shutil.rmtree(d, ignore_errors=True)


def log_tail(path: Path, chars: int = 3000) -> str:
    try:
        text = Path(path).read_text(errors="replace")
    except OSError:
        return "(no SUMO log)"
    return text[-chars:].strip() or "(SUMO wrote nothing)"


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
        self._tmp = None if log_dir else tempfile.TemporaryDirectory(prefix="urbjax-sumo-logs-")
        self.log_dir = Path(log_dir) if log_dir else Path(self._tmp.name)  # type: ignore[union-attr]
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self._ctx = mp.get_context("spawn")  # never fork a process that may hold JAX threads
        self.restarts = 0
        self.workers = [self._spawn(i) for i in range(n_workers)]
        for w in self.workers:
            w.wait_ready(self.start_timeout_s)

    def _spawn(self, index: int) -> _Worker:
        return _Worker(self._ctx, index, self.config, self.log_dir / f"sumo_worker{index}.log")

    def _restart(self, w: _Worker) -> _Worker:
        w.kill()
        self.restarts += 1
        nw = self._spawn(w.index)
        nw.wait_ready(self.start_timeout_s)
        self.workers[w.index] = nw
        return nw

    def busy_pids(self) -> list[int]:
        """Process ids of workers running a day now (for fault-injection tests)."""
        return [w.proc.pid for w in self.workers if w.task is not None and w.proc.pid is not None]

    def run_days(self, scenario: object, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        choices, seeds, cavs = _batch(scenario, choices, seeds, is_cav)
        for c, m in zip(choices, cavs, strict=True):  # bad input fails here, not twice in a worker
            check_choices(scenario, c)
            cav_mask(scenario, m)
        key = scenario_key(scenario)
        todo = deque(range(len(seeds)))
        results: list[DayResult | None] = [None] * len(seeds)
        failures: dict[int, list[str]] = {}

        def fail(w: _Worker, reason: str) -> None:
            tid = w.task
            assert tid is not None
            log = log_tail(w.log_path)
            failures.setdefault(tid, []).append(f"{reason}\n--- SUMO log tail ({w.log_path}) ---\n{log}")
            self._restart(w)
            if len(failures[tid]) >= 2:
                for other in self.workers:  # abandon in-flight days, keep the pool usable
                    if other.task is not None:
                        self._restart(other)
                raise failed_twice(scenario, tid, seeds[tid], failures[tid])
            todo.appendleft(tid)

        try:
            while todo or any(w.task is not None for w in self.workers):
                for w in list(self.workers):
                    if w.task is None and todo:
                        tid = todo.popleft()
                        send_scn = None if key in w.scenarios else scenario
                        w.task, w.started = tid, time.monotonic()
                        try:
                            ahead = tid + len(self.workers)  # likely this worker's next day: pre-load it
                            nxt = seeds[ahead] if ahead < len(seeds) else seeds[tid]
                            w.conn.send(("day", tid, key, send_scn, choices[tid], seeds[tid], cavs[tid], nxt))
                            w.scenarios.add(key)
                        except (BrokenPipeError, OSError) as exc:
                            fail(w, f"worker {w.index} could not take the day ({exc!r})")
                busy = [w for w in self.workers if w.task is not None]
                if not busy:
                    continue
                now = time.monotonic()
                timeout = max(0.0, min(w.started + self.day_timeout_s - now for w in busy))
                ready = wait([w.conn for w in busy] + [w.proc.sentinel for w in busy], timeout=timeout)
                for w in busy:
                    if w.conn in ready:
                        try:
                            kind, tid, payload = w.conn.recv()
                        except (EOFError, OSError):
                            fail(w, f"worker {w.index} died (exit code {w.proc.exitcode})")
                            continue
                        if kind == "ok":
                            results[tid] = payload
                            w.task = None
                        else:
                            fail(w, f"worker {w.index} raised:\n{payload}")
                    elif w.proc.sentinel in ready:
                        w.proc.join(timeout=1)
                        fail(w, f"worker {w.index} died (exit code {w.proc.exitcode})")
                    elif time.monotonic() - w.started > self.day_timeout_s:
                        fail(w, f"worker {w.index} exceeded the {self.day_timeout_s:.0f} s day limit")
        except BaseException:
            for w in self.workers:
                if w.task is not None:
                    w.task = None
                    self._restart(w)
            raise
        return results  # type: ignore[return-value]

    def close(self) -> None:
        for w in self.workers:
            with contextlib.suppress(Exception):
                w.conn.send(("stop",))
        for w in self.workers:
            w.proc.join(timeout=5)
            w.kill()
        self.workers = []
        if self._tmp is not None:
            self._tmp.cleanup()

    def __enter__(self) -> SumoPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
