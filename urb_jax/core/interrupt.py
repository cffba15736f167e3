"""Ctrl-C, the way a long run should take it: the first SIGINT stops the run (a KeyboardInterrupt
where the main thread is, turned into `InterruptedRunError` by the run, which names the resume command);
a second one, while the first is being handled, kills this process's children and exits at once.

Also the one place that recognises a full disk in an exception (`no_space`), since orbax, pyarrow
and numpy each wrap the OS error differently.
"""

from __future__ import annotations

import contextlib
import errno
import multiprocessing
import os
import signal
import sys
from collections.abc import Iterator
from pathlib import Path
from types import FrameType

from urb_jax.core.errors import UrbJaxError

EXIT_INTERRUPTED = 130  # the shell's code for a process ended by SIGINT


class InterruptedRunError(UrbJaxError):
    """The user pressed Ctrl-C; the message says what is kept and how to go on."""


class DiskFullError(UrbJaxError):
    """No space left on the device a run writes to."""


_presses = 0


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    global _presses
    _presses += 1
    if _presses == 1:
        print("\nurb-jax: stopping (Ctrl-C again to exit at once) ...", file=sys.stderr, flush=True)
        raise KeyboardInterrupt
    print("urb-jax: interrupted twice: exiting now.", file=sys.stderr, flush=True)
    for child in multiprocessing.active_children():  # SUMO workers: never left behind
        with contextlib.suppress(OSError):
            os.kill(child.pid, signal.SIGKILL)  # type: ignore[arg-type]
    os._exit(EXIT_INTERRUPTED)


@contextlib.contextmanager
def handle_interrupts() -> Iterator[None]:
    """Install the two-press SIGINT handler for the block (main thread only; elsewhere a no-op)."""
    global _presses
    try:
        previous = signal.signal(signal.SIGINT, _on_sigint)
    except ValueError:  # not the main thread
        yield
        return
    _presses = 0
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def no_space(exc: BaseException) -> bool:
    """Whether `exc` (or anything in its cause/context chain) is the OS saying the disk is full."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        if "No space left on device" in str(e) or "Disk quota exceeded" in str(e):
            return True
        e = e.__cause__ or e.__context__
    return False


def disk_full(where: Path, kept: str) -> DiskFullError:
    """The error for a full disk under `where`; `kept` says what is still usable and how to go on."""
    return DiskFullError(f"no space left on device in {where.resolve()}. {kept}")
