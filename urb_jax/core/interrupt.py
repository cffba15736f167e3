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
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType
from typing import NoReturn

from urb_jax.core.errors import UrbJaxError

EXIT_INTERRUPTED = 130  # the shell's code for a process ended by SIGINT


class InterruptedRunError(UrbJaxError):
    """The user pressed Ctrl-C; the message says what is kept and how to go on."""


class DiskFullError(UrbJaxError):
    """No space left on the device a run writes to."""


GRACE_S = 3.0  # after a first Ctrl-C, how long the main thread has to stop cleanly
_presses = 0
_stop_message: Callable[[], str] | None = None


_exit_hooks: list[Callable[[], object]] = []


def on_stop(message: Callable[[], str] | None) -> None:
    """What a forced stop prints (the run's resume line); None: a plain line."""
    global _stop_message
    _stop_message = message


def at_hard_exit(hook: Callable[[], object]) -> None:
    """`hook` runs when a stop leaves without teardown (`_hard_exit`), where atexit handlers do
    not: small bookkeeping only (e.g. a run folder's lock owner), its errors ignored."""
    _exit_hooks.append(hook)


def _hard_exit(why: str) -> NoReturn:
    """Leave now, as a kill would (a run resumes from any instant): children first, no teardown
    (an XLA computation may still be in flight, and interpreter teardown around it can crash)."""
    text = why
    if _stop_message is not None:
        with contextlib.suppress(Exception):
            text = f"{why} {_stop_message()}"
    with contextlib.suppress(Exception):
        os.write(2, f"urb-jax: {text}\n".encode())
    for hook in _exit_hooks:
        with contextlib.suppress(Exception):
            hook()
    for child in multiprocessing.active_children():  # SUMO workers: never left behind
        with contextlib.suppress(OSError):
            os.kill(child.pid, signal.SIGKILL)  # type: ignore[arg-type]
    os._exit(EXIT_INTERRUPTED)


def leave_interrupted(message: str) -> NoReturn:
    """End the process after a handled Ctrl-C: the message, children killed, exit code 130."""
    on_stop(None)
    _hard_exit(message)
    raise AssertionError  # _hard_exit does not return


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    """The Python-level handler (runs in the main thread between bytecodes)."""
    if _presses <= 1:
        raise KeyboardInterrupt
    _hard_exit("interrupted twice: exiting now.")


def _watch(read_fd: int) -> None:
    """Sees each SIGINT as the C handler writes it, even while the main thread is inside a long
    jitted call where no Python handler can run: says so at once, exits on a second press, and
    after GRACE_S forces the stop the main thread could not make."""
    with os.fdopen(read_fd, "rb", buffering=0) as pipe:  # closed once the block ends (EOF)
        while data := pipe.read(64):
            _count_presses(data)


def _count_presses(data: bytes) -> None:
    global _presses
    for sig in data:
        if sig != signal.SIGINT:
            continue
        _presses += 1
        if _presses > 1:
            _hard_exit("interrupted twice: exiting now.")
        os.write(2, b"\nurb-jax: stopping (Ctrl-C again to exit at once) ...\n")
        force = threading.Timer(GRACE_S, _hard_exit, ("stopped by Ctrl-C (forced: the run was inside "
                                                      "a computation).",))
        force.daemon = True
        force.start()


@contextlib.contextmanager
def handle_interrupts() -> Iterator[None]:
    """Install the Ctrl-C handling for the block (main thread only; elsewhere a no-op)."""
    global _presses
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    previous = signal.signal(signal.SIGINT, _on_sigint)
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    _presses = 0
    threading.Thread(target=_watch, args=(read_fd,), daemon=True, name="urb-jax-ctrl-c").start()
    try:
        yield
    finally:
        signal.set_wakeup_fd(previous_fd)
        signal.signal(signal.SIGINT, previous)
        os.close(write_fd)


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
