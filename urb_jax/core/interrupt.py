"""Ctrl-C, the way a long run should take it: the first SIGINT stops the run (a KeyboardInterrupt
where the main thread is, turned into `InterruptedRunError` by the run, which names the resume command);
a second one, while the first is being handled, kills this process's children and exits at once.
SIGTERM (Slurm's scancel and time limit, systemd, kill) and SIGHUP (a closed terminal or SSH session)
are taken the same way (`STOP_SIGNALS`): the run stops cleanly with its resume line, and the process
exits with the shell's code for the signal, 128 + its number (130, 143, 129: `exit_code`).

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
# The signals that stop a run cleanly, and how the messages name them.
STOP_SIGNALS = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM", signal.SIGHUP: "SIGHUP"}


class InterruptedRunError(UrbJaxError):
    """The user pressed Ctrl-C; the message says what is kept and how to go on."""


class DiskFullError(UrbJaxError):
    """No space left on the device a run writes to."""


GRACE_S = 3.0  # after a first Ctrl-C, how long the main thread has to stop cleanly
_presses = 0
_received: int = signal.SIGINT  # the first stop signal received (Ctrl-C when the stop is in-process)
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


def stop_cause() -> str:
    """How the stop is named: 'Ctrl-C', 'SIGTERM' or 'SIGHUP' (the first stop signal received)."""
    return STOP_SIGNALS.get(signal.Signals(_received), "Ctrl-C")


def exit_code() -> int:
    """The exit code of a stopped run: 128 + the signal's number, as the shell reports a process the
    signal ended (so Slurm, systemd and scripts see what stopped it)."""
    return 128 + int(_received)


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
    os._exit(exit_code())


def leave_interrupted(message: str) -> NoReturn:
    """End the process after a handled stop signal: the message, children killed, exit code 128 +
    the signal's number (130 for Ctrl-C)."""
    on_stop(None)
    _hard_exit(message)
    raise AssertionError  # _hard_exit does not return


def _on_stop(signum: int, frame: FrameType | None) -> None:
    """The Python-level handler of every stop signal (runs in the main thread between bytecodes):
    a KeyboardInterrupt, which every layer already handles as a clean stop."""
    _note(signum)
    if _presses <= 1:
        raise KeyboardInterrupt
    _hard_exit("interrupted twice: exiting now.")


def _note(signum: int) -> None:
    """Remember the first stop signal (its name and exit code); SIGINT's is the default."""
    global _received
    if _presses == 0:
        _received = signum


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
        if sig not in STOP_SIGNALS:
            continue
        if _presses == 0:
            _note(sig)
        _presses += 1
        if _presses > 1:
            _hard_exit("interrupted twice: exiting now.")
        why = "" if sig == signal.SIGINT else f" on {stop_cause()}"
        with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone
            os.write(2, f"\nurb-jax: stopping{why} (Ctrl-C again to exit at once) ...\n".encode())
        force = threading.Timer(GRACE_S, _hard_exit, (f"stopped by {stop_cause()} (forced: the run was "
                                                      "inside a computation).",))
        force.daemon = True
        force.start()


@contextlib.contextmanager
def handle_interrupts() -> Iterator[None]:
    """Install the handling of Ctrl-C, SIGTERM and SIGHUP for the block (main thread only;
    elsewhere a no-op)."""
    global _presses, _received
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    previous = {sig: signal.signal(sig, _on_stop) for sig in STOP_SIGNALS}
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    _presses, _received = 0, signal.SIGINT
    threading.Thread(target=_watch, args=(read_fd,), daemon=True, name="urb-jax-ctrl-c").start()
    try:
        yield
    finally:
        signal.set_wakeup_fd(previous_fd)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        os.close(write_fd)


def ignore_stop_signals() -> None:
    """In a worker process (SUMO, route sampling): the parent takes Ctrl-C, SIGTERM and SIGHUP (a
    terminal, Slurm and systemd send them to every process of the job) and stops its workers itself."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


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
