"""The one way urb-jax writes a file: to a temporary name beside it, fsynced, then renamed.

A reader (or a resumed run) therefore sees the old file or the new one, never half of either,
also after a crash or a full disk. Files get the mode open() gives (0666 less the process's umask:
0644 under the usual 022), like the files other libraries write into the same folders (plots,
orbax checkpoints, logs); mkstemp's 0600 would leave records and caches unreadable to the people
who can read the rest.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

MODE = 0o666  # less the umask, as open() does


def umask() -> int:
    """The process's umask, read from /proc where Linux offers it: os.umask can only read it by
    setting it, which races with threads creating files (orbax writes checkpoints in threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, mode: int = MODE) -> Iterator[Path]:
    """Yields a temporary path beside `path` to write to; on a clean exit it is fsynced, given
    `mode` less the umask, and renamed onto `path`; on an exception removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, mode & ~umask())
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode())


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Indented JSON; numpy scalars and arrays, and tuples, as plain JSON values."""
    write_text(path, json.dumps(obj, indent=2, default=_json_default) + "\n")


def write_npz(path: str | os.PathLike, **arrays: Any) -> None:
    """np.savez of `arrays` (uncompressed)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, tuple):
        return list(o)
    return str(o)


def file_sha256(path: Path) -> str:
    """The sha256 of a file's bytes, read in 1 MiB chunks (checkpoints and records may be large)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()
