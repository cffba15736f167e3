"""The run's log, results/<id>/run.log: every WARNING (or worse) that urb-jax logs while a run is
under way, such as a SUMO worker restarted after a crash or a damaged cache entry rebuilt, so that
what happened to a run stays with its results and not only in a terminal's scrollback.

Only urb-jax's own loggers (`urb_jax.*`) are collected; the same records still reach stderr through
the root logger (the CLI's `logging.basicConfig`), once each. The file is created by the first
warning: a run without one has no run.log.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import ParamSpec, TypeVar

RUN_LOG = "run.log"
FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
_ACTIVE: list[RunLogHandler] = []  # innermost last: the run whose folder `log_run_to` names

P = ParamSpec("P")
R = TypeVar("R")


class RunLogHandler(logging.Handler):
    """Appends records to `<folder>/run.log`. Records from before the folder is known are kept and
    written first: a train run loads its scenario (and may rebuild its cache) before it creates
    its results folder."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.setFormatter(logging.Formatter(FORMAT))
        self.path: Path | None = None
        self.pending: list[str] = []

    def open(self, folder: str | os.PathLike) -> None:
        """Write to `folder`/run.log from now on, starting with the records kept so far."""
        with self.lock or contextlib.nullcontext():
            self.path = Path(folder) / RUN_LOG
            lines, self.pending = self.pending, []
            self._append(lines)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            line = self.format(record)
            if self.path is None:
                self.pending.append(line)
            else:
                self._append([line])
        except Exception:  # a full disk must not end the run: logging reports it on stderr
            self.handleError(record)

    def _append(self, lines: list[str]) -> None:
        if lines and self.path is not None:
            with open(self.path, "a", encoding="utf-8") as fh:
                fh.write("".join(f"{ln}\n" for ln in lines))


@contextlib.contextmanager
def run_log() -> Iterator[RunLogHandler]:
    """Collect urb-jax's warnings for a run's log while the block runs (`log_run_to` names the
    folder). Where no logging is configured, Python's default stderr output is kept."""
    logger = logging.getLogger("urb_jax")
    handler = RunLogHandler()
    # A handler of ours would switch off logging.lastResort (stderr when nothing is configured).
    stderr = logging.lastResort if not logging.getLogger().handlers else None
    logger.addHandler(handler)
    if stderr is not None:
        logger.addHandler(stderr)
    _ACTIVE.append(handler)
    try:
        yield handler
    finally:
        _ACTIVE.remove(handler)
        logger.removeHandler(handler)
        if stderr is not None:
            logger.removeHandler(stderr)


def with_run_log(fn: Callable[P, R]) -> Callable[P, R]:
    """Run `fn` (a run: train, resume, baseline) inside `run_log()`."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with run_log():
            return fn(*args, **kwargs)

    return wrapper


def log_run_to(folder: str | os.PathLike) -> None:
    """The current run's results folder is known: its run.log gets the warnings from here on
    (and those logged before). Outside `run_log()` nothing happens."""
    if _ACTIVE:
        _ACTIVE[-1].open(folder)
