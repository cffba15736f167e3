"""Where networks and caches live; one place so every command agrees."""

from __future__ import annotations

import os
from pathlib import Path
from typing import cast

from urb_jax import networks

NETWORKS_ENV = "URB_JAX_NETWORKS"
CACHE_ENV = "URB_JAX_CACHE"


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
    """Route/scenario cache: $URB_JAX_CACHE, else ~/.cache/urb-jax."""
    env = os.environ.get(CACHE_ENV)
    root = Path(env).expanduser() if env else Path.home() / ".cache" / "urb-jax"
    root.mkdir(parents=True, exist_ok=True)
    return root
