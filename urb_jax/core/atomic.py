"""The one way urb-jax writes a file: to a temporary name beside it, fsynced, then renamed.

A reader (or a resumed run) therefore sees the old file or the new one, never half of either,
also after a crash or a full disk. A JSON record that must not change behind the code's back (a
run's exp_config.json) carries the sha256 of its own content as one of its keys
(`write_json_digested`, `checked_json`): one file, one rename, so the digest is never out of step
with the file. Files get the mode open() gives (0666 less the process's umask:
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

from urb_jax.core.errors import UrbJaxError

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


JSON_DIGEST_KEY = "content_sha256"  # a digested JSON record's key: the sha256 of its other keys


def json_digest(obj: dict[str, Any]) -> str:
    """The sha256 of `obj` without JSON_DIGEST_KEY as canonical JSON (keys sorted, no spaces), taken
    from the values a reader gets back (numpy values and tuples as `write_json` writes them), so that
    the indentation and key order of the file do not matter, and every value does."""
    body = {k: v for k, v in obj.items() if k != JSON_DIGEST_KEY}
    plain = json.loads(json.dumps(body, default=_json_default))
    return hashlib.sha256(json.dumps(plain, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def write_json_digested(path: str | os.PathLike, obj: dict[str, Any]) -> None:
    """`write_json` of `obj` with its `json_digest` under JSON_DIGEST_KEY (the last key)."""
    body = {k: v for k, v in obj.items() if k != JSON_DIGEST_KEY}
    write_json(path, {**body, JSON_DIGEST_KEY: json_digest(body)})


def checked_json(path: Path, obj: dict[str, Any], fix: str) -> dict[str, Any]:
    """`obj` (read from `path`) without JSON_DIGEST_KEY, once its content matches that digest; a
    record without one (written before digests) as it is. A mismatch is a UrbJaxError naming the file,
    both digests and `fix` (what to do)."""
    recorded = obj.get(JSON_DIGEST_KEY)
    if recorded is None:
        return obj
    now = json_digest(obj)
    if now != recorded:
        raise UrbJaxError(f"{path}: its content does not match the sha256 recorded in it "
                          f"('{JSON_DIGEST_KEY}' {str(recorded)[:16]}..., the content now {now[:16]}...): "
                          "the file changed after "
                          f"urb-jax wrote it (damaged, or edited by hand). Fix: {fix}")
    return {k: v for k, v in obj.items() if k != JSON_DIGEST_KEY}
