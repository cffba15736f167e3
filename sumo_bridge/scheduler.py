"""The one retry scheduler for SUMO days on a set of workers (pool processes or Ray actors).

Days wait in a queue and go to idle workers one at a time; the scheduler waits on the busy ones
with the per-day wall-clock limit. A worker that fails (dies, raises, overruns the limit, cannot
take the day) is restarted and its day retried once, first in the queue; a second failure of the
same day restarts the other busy workers (their days are abandoned, the executor stays usable)
and raises `SumoDayError` with both attempts. Any other exception abandons the days in flight
the same way; Ctrl-C restarts nothing (the run is stopping, and closing the executor kills the
busy workers at once). A day whose attempts ran out of memory (a MemoryError the worker sent back,
or a worker killed by SIGKILL, as the kernel's out-of-memory killer does) raises
`SumoOutOfMemoryError` instead, with what uses less memory. A backend supplies only submit / wait /
overdue / restart.
"""

from __future__ import annotations

import logging
import time
import traceback
from collections import OrderedDict, deque
from typing import Generic, NamedTuple, Protocol, TypeVar

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.phase import IN_PROCESS_MEMORY_HINT, SUMO_MEMORY_HINT
from urb_jax.sumo_bridge.batch import DayBatch, as_batch, check_batch
from urb_jax.sumo_bridge.keys import scenario_key
from urb_jax.sumo_bridge.types import DayResult

log = logging.getLogger(__name__)


class SumoDayError(UrbJaxError):
    """A SUMO day failed twice (or a worker could not start)."""


def memory_error_text() -> str:
    """In a worker's `except MemoryError`: its traceback, or its name where formatting it needs memory
    there is not."""
    try:
        return traceback.format_exc()
    except MemoryError:
        return "MemoryError"


class SumoOutOfMemoryError(SumoDayError):
    """A SUMO day failed twice, and memory ran out in its worker (`memory_hint`: what uses less)."""

    memory_hint = SUMO_MEMORY_HINT


def out_of_memory_in_process(scenario: Scenario, exc: MemoryError) -> SumoOutOfMemoryError:
    """The error for a SUMO day that ran out of memory in this process (the in-process executor: one
    SUMO worker): SUMO shares the process with JAX, so both hints apply; nothing restarts it."""
    err = SumoOutOfMemoryError(
        f"a SUMO day of network {scenario.name} ran out of memory in this process (SUMO runs in the "
        f"trainer's own process with one SUMO worker) ({type(exc).__name__}: {exc})\n"
        f"{IN_PROCESS_MEMORY_HINT}.")
    err.memory_hint = IN_PROCESS_MEMORY_HINT
    return err


def out_of_memory_twice(scenario: Scenario, day: int, seed: int, attempts: list[Failed],
                        where: str = "") -> SumoOutOfMemoryError:
    """The error for a day that failed twice, memory running out in a worker: the first line says so
    (with the newest SUMO log), the hint and each attempt follow."""
    return SumoOutOfMemoryError(
        f"SUMO day {day} (seed {seed}) of network {scenario.name} failed twice{where}, memory running out "
        f"in its worker (SUMO log {attempts[-1].log or 'none'})\n{SUMO_MEMORY_HINT}.\n"
        + "\n".join(f"attempt {i + 1}: {f.text}" for i, f in enumerate(attempts)))


def failed_twice(scenario: Scenario, day: int, seed: int, attempts: list[str],
                 where: str = "") -> SumoDayError:
    """The error for a day that failed on its retry too: network, day, seed and both attempts' logs."""
    return SumoDayError(
        f"SUMO day {day} (seed {seed}) of network {scenario.name} failed twice{where}.\n"
        + "\n".join(f"attempt {i + 1}: {f}" for i, f in enumerate(attempts))
    )


class Slot(Protocol):
    """One worker as the scheduler sees it; the scheduler sets `task`, `started` and `finished`."""

    index: int  # position in the backend's `slots`, kept by a restart
    task: int | None  # day index in the batch, None when idle
    started: float  # time.monotonic() when the day was handed over
    finished: float  # time.monotonic() when its last day came back (0: none yet)


KEPT_SCENARIOS = 16  # scenarios a worker keeps (a run with day-varying departures sends one a day)
V = TypeVar("V")


class KeptScenarios(Generic[V]):
    """The scenarios a worker holds, by scenario key, the oldest dropped beyond `KEPT_SCENARIOS`.
    The executor and its worker each keep one and add the same keys in the same order (the executor
    when it sends a scenario, the worker when it receives one), so the executor knows what the worker
    still has. `add` returns the keys it dropped."""

    def __init__(self) -> None:
        self.items: OrderedDict[str, V] = OrderedDict()

    def __contains__(self, key: object) -> bool:
        return key in self.items

    def __getitem__(self, key: str) -> V:
        return self.items[key]

    def add(self, key: str, value: V) -> list[str]:
        self.items[key] = value
        self.items.move_to_end(key)
        dropped = []
        while len(self.items) > KEPT_SCENARIOS:
            dropped.append(self.items.popitem(last=False)[0])
        return dropped


class DayJob(NamedTuple):
    """One day handed to a worker."""

    day: int  # index in the batch
    scenario: Scenario
    key: str  # scenario_key(scenario): workers keep each scenario they were sent under it
    choices: np.ndarray  # [N]
    seed: int
    is_cav: np.ndarray | None  # [N] or None: the Scenario's agent kinds
    next_seed: int  # seed to pre-load after the day (likely this worker's next day)


class Failed(NamedTuple):
    """A failed attempt: the reason and the worker's SUMO log tail, as the error will quote it, and
    where that log is (the restart warning names it, so the log can be found without the error)."""

    text: str
    log: str = ""
    memory: bool = False  # memory ran out: a MemoryError in the worker, or a SIGKILL without a result

    def reason(self) -> str:
        """The reason in one line: its first line, plus the exception's line when the worker raised."""
        head = self.text.split("\n--- SUMO log tail", 1)[0]
        lines = [ln.strip() for ln in head.splitlines() if ln.strip()] or ["(no reason given)"]
        first = lines[0]
        if first.endswith(":") and len(lines) > 1:  # "worker 0 raised:" + a traceback
            first = f"{first} {lines[-1]}"
        return first[:300]


S = TypeVar("S", bound=Slot)


class Workers(Protocol[S]):
    """What a backend supplies. `wait` returns the outcomes of the busy slots that finished,
    by slot index; it may return none (the scheduler then checks the day limit)."""

    @property
    def slots(self) -> list[S]: ...

    def submit(self, slot: S, job: DayJob) -> Failed | None: ...

    def wait(self, busy: list[S], timeout: float) -> dict[int, DayResult | Failed]: ...

    def overdue(self, slot: S) -> Failed: ...

    def restart(self, slot: S) -> None: ...


def schedule_days(workers: Workers[S], scenario: Scenario, choices: np.ndarray,
                  seeds: list[int] | np.ndarray, is_cav: np.ndarray | None, *, day_timeout_s: float,
                  where: str = "") -> list[DayResult]:
    """Run a batch (`DayExecutor.run_days`' arguments) on `workers`; results in batch order.
    `where` is added to the failed-twice message (e.g. " on Ray")."""
    batch = as_batch(choices, seeds, is_cav)
    check_batch(scenario, batch)  # bad input fails here, not twice in a worker
    return _Run(workers, scenario, batch, day_timeout_s, where).run()


class _Run(Generic[S]):
    """State of one `schedule_days` call."""

    def __init__(self, workers: Workers[S], scenario: Scenario, batch: DayBatch, day_timeout_s: float,
                 where: str) -> None:
        self.w = workers
        self.scenario, self.batch, self.key = scenario, batch, scenario_key(scenario)
        self.day_timeout_s, self.where = day_timeout_s, where
        self.todo = deque(range(len(batch.seeds)))
        self.results: list[DayResult | None] = [None] * len(batch.seeds)
        self.failures: dict[int, list[Failed]] = {}

    def run(self) -> list[DayResult]:
        try:
            while self.todo or any(s.task is not None for s in self.w.slots):
                self._dispatch()
                busy = [s for s in self.w.slots if s.task is not None]
                if busy:
                    self._collect(busy)
        except KeyboardInterrupt:
            raise  # the run is stopping: no restarts; closing the executor kills the busy workers
        except BaseException:
            for s in list(self.w.slots):  # abandon the days in flight, keep the executor usable
                if s.task is not None:
                    s.task = None
                    self.w.restart(s)
            raise
        done = [r for r in self.results if r is not None]
        assert len(done) == len(self.results)  # the queue drained: every day has its result
        return done

    def _dispatch(self) -> None:
        """Hand queued days to idle workers, the longest idle first: a worker pre-loads its next
        day after sending a result, so days asked for one at a time (the human phase) alternate
        between workers and find the network loaded."""
        seeds, n_slots = self.batch.seeds, len(self.w.slots)
        for s in sorted(self.w.slots, key=lambda s: s.finished):
            if s.task is not None or not self.todo:
                continue
            tid = self.todo.popleft()
            ahead = tid + n_slots  # likely this worker's next day: pre-load its seed
            job = DayJob(tid, self.scenario, self.key, self.batch.choices[tid], seeds[tid],
                         self.batch.cavs[tid], seeds[ahead] if ahead < len(seeds) else seeds[tid])
            s.task, s.started = tid, time.monotonic()  # busy from here: any exception restarts it
            failed = self.w.submit(s, job)
            if failed is not None:
                self._fail(s, failed)

    def _collect(self, busy: list[S]) -> None:
        """Wait for the first finished day or the nearest day limit; record or retry."""
        timeout = max(0.0, min(s.started + self.day_timeout_s - time.monotonic() for s in busy))
        outcomes = self.w.wait(busy, timeout)
        for s in busy:
            out = outcomes.get(s.index)
            if isinstance(out, Failed):
                self._fail(s, out)
            elif out is not None:
                assert s.task is not None
                self.results[s.task] = out
                s.task, s.finished = None, time.monotonic()
            elif time.monotonic() - s.started > self.day_timeout_s:
                self._fail(s, self.w.overdue(s))

    def _fail(self, s: S, failed: Failed) -> None:
        """Restart the worker; retry its day first, or raise if this was the day's second failure."""
        tid = s.task
        assert tid is not None
        s.task = None
        attempts = self.failures.setdefault(tid, [])
        attempts.append(failed)
        log.warning("SUMO %s; restarting it (day %d of the batch, seed %s, network %s%s: %s; SUMO log %s)",
                    failed.reason(), tid, self.batch.seeds[tid], self.scenario.name, self.where,
                    "retrying the day" if len(attempts) < 2 else "the day failed twice",
                    failed.log or "(none)")
        self.w.restart(s)
        if len(attempts) >= 2:
            for other in list(self.w.slots):  # abandon the days in flight, keep the executor usable
                if other.task is not None:
                    other.task = None
                    self.w.restart(other)
            seed = self.batch.seeds[tid]
            if any(f.memory for f in attempts):
                raise out_of_memory_twice(self.scenario, tid, seed, attempts, self.where)
            raise failed_twice(self.scenario, tid, seed, [f.text for f in attempts], self.where)
        self.todo.appendleft(tid)
