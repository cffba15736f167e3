"""SUMO's own output: where a process sends it (a log file) and how an error quotes it back."""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def redirect_fds(path: str | os.PathLike | None) -> Iterator[None]:
    """Send this process's C-level stdout/stderr (SUMO's messages) to `path`, appending."""
    if path is None:
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for f in (fd, *saved):
            os.close(f)


def log_tail(path: str | os.PathLike, chars: int = 3000) -> str:
    """The last `chars` of a worker's SUMO log, quoted in failure messages."""
    try:
        text = Path(path).read_text(errors="replace")
    except OSError:
        return "(no SUMO log)"
    return text[-chars:].strip() or "(SUMO wrote nothing)"


def log_folder(log_dir: str | os.PathLike | None, prefix: str
               ) -> tuple[Path, tempfile.TemporaryDirectory[str] | None]:
    """Where an executor's workers log: `log_dir` (created), or a temporary folder the executor
    removes on close (returned as well)."""
    if log_dir:
        path = Path(log_dir)
        path.mkdir(parents=True, exist_ok=True)
        return path, None
    tmp = tempfile.TemporaryDirectory(prefix=prefix)
    return Path(tmp.name), tmp
