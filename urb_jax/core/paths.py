"""Where networks and caches live; one place so every command agrees."""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path
from typing import cast

from urb_jax import networks
from urb_jax.core.errors import UrbJaxError

NETWORKS_ENV = "URB_JAX_NETWORKS"
CACHE_ENV = "URB_JAX_CACHE"
DAY_STORE_ENV = "URB_JAX_DAY_STORE_GB"  # the SUMO day store's cap in GB; 0 (or off) turns the store off
DAY_STORE_GB = 2.0  # its default


def embedded_networks_dir() -> Path:
    """The networks shipped inside the package (the embedded default lives here)."""
    return Path(networks.__file__).resolve().parent


def absolute_dir(folder: str | os.PathLike | None) -> str | None:
    """A folder flag made absolute (None stays None): what the search path reads, and what a run
    records so that a `--resume` from another working folder finds the same folder."""
    return None if not folder else str(Path(folder).expanduser().resolve())


def networks_search_path(networks_dir: str | os.PathLike | None = None) -> list[Path]:
    """Search order: explicit flag, then $URB_JAX_NETWORKS (os.pathsep-separated), then embedded."""
    path: list[Path] = []
    if networks_dir:
        path.append(Path(cast(str, absolute_dir(networks_dir))))  # not None: networks_dir is set
    env = os.environ.get(NETWORKS_ENV, "")
    for part in env.split(os.pathsep):
        if part.strip():
            path.append(Path(part).expanduser().resolve())
    path.append(embedded_networks_dir())
    seen: set[Path] = set()
    unique = []
    for p in path:
        if p not in seen:
            seen.add(p)
            unique.append(p)
    return unique


def cache_dir() -> Path:
    """Route/scenario cache: $URB_JAX_CACHE, else ~/.cache/urb-jax; created and writable, else a
    UrbJaxError naming the folder and the fix (an empty HOME is refused: it is no home folder, and
    Path.home() would make it the filesystem root)."""
    env = os.environ.get(CACHE_ENV, "").strip()
    if env:
        return writable_dir(Path(env).expanduser(), f"urb-jax's cache folder (${CACHE_ENV})",
                            f"set {CACHE_ENV} to a folder you can write to")
    if "HOME" in os.environ and not os.environ["HOME"].strip():
        raise UrbJaxError("HOME is set but empty, so urb-jax has no home folder for its cache "
                          f"(~/.cache/urb-jax). Fix: set HOME to your home folder, or {CACHE_ENV} to a "
                          "folder for urb-jax's caches.")
    return writable_dir(Path.home() / ".cache" / "urb-jax", "urb-jax's cache folder (~/.cache/urb-jax)",
                        f"make it writable, or set {CACHE_ENV} to a folder you can write to")


def day_store_bytes() -> int:
    """The SUMO day store's cap in bytes: $URB_JAX_DAY_STORE_GB gigabytes (default 2; 0 or off: no
    store); a value that is not a number of gigabytes >= 0 is a UrbJaxError naming the variable and
    the fix."""
    text = os.environ.get(DAY_STORE_ENV, "").strip()
    if not text:
        return int(DAY_STORE_GB * 1e9)
    if text.lower() in ("off", "no", "false", "none"):
        return 0
    try:
        gb = float(text)
    except ValueError:
        gb = float("nan")
    if not gb >= 0 or gb == float("inf"):
        raise UrbJaxError(f"{DAY_STORE_ENV}={text!r}: not a size in gigabytes. Fix: set {DAY_STORE_ENV} "
                          f"to the SUMO day store's cap in GB, e.g. {DAY_STORE_GB:g} (0 or off turns the "
                          "store off), or unset it for the default.")
    return int(gb * 1e9)


_writable: set[Path] = set()  # folders writable_dir has checked in this process


def writable_dir(path: Path, what: str, fix: str) -> Path:
    """`path`, created with its parents, after a probe file shows it can be written; else a
    UrbJaxError naming `what`, the path, the OS's reason (a file in the way, read-only, no
    permission) and `fix`. Checked once per process."""
    if path in _writable:
        return path
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise UrbJaxError(f"{path}: {what} cannot be created or written ({os_reason(exc, path)}). "
                          f"Fix: {fix}.") from None
    _writable.add(path)
    return path


def os_reason(exc: OSError, path: Path) -> str:
    """Why the OS refused a folder, in words: a file in the way, a read-only filesystem, ..."""
    if isinstance(exc, FileExistsError | NotADirectoryError) or (path.exists() and not path.is_dir()):
        blocker = next((p for p in (path, *path.parents) if p.exists() and not p.is_dir()), None)
        return f"a file is in the way: {blocker}" if blocker is not None else exc.strerror or str(exc)
    if exc.errno == errno.EROFS:
        return "the filesystem is read-only"
    return exc.strerror or str(exc)
