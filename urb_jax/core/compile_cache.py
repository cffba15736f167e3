"""JAX's persistent compilation cache under the urb-jax cache dir, so compilation is paid once.

Every process (and every `--resume`) would otherwise compile the same programs again: on
saint_arnoult that was 28% of a run. JAX keys each entry by the program, the compile options and
the jax/XLA versions, so a warm entry is the same executable a cold compile would give (records
are byte-identical, tested). Opt out with URB_JAX_COMPILE_CACHE=off (or point it at another
directory); a cache dir the user already gave JAX (JAX_COMPILATION_CACHE_DIR) is left as it is.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, cast

import jax
from jax.experimental.compilation_cache import compilation_cache

from urb_jax.core.paths import CACHE_ENV, cache_dir, writable_dir

COMPILE_CACHE_ENV = "URB_JAX_COMPILE_CACHE"
OFF_VALUES = ("0", "off", "false", "no", "none")
# JAX's defaults store only compiles over 1 s; most of urb-jax's take 0.05-1 s each and there are
# 100+ per run, so every compile is stored (an entry is tens of kB; reading one is ~1 ms).
MIN_COMPILE_TIME_S = 0.0
MIN_ENTRY_SIZE_BYTES = -1  # -1: no size floor (JAX's own setting for "store everything")


def compile_cache_path() -> Path | None:
    """Where urb-jax keeps compiled programs: $URB_JAX_COMPILE_CACHE, else <cache_dir()>/jax;
    None when the variable opts out."""
    value = os.environ.get(COMPILE_CACHE_ENV, "").strip()
    if value.lower() in OFF_VALUES:
        return None
    return Path(value).expanduser() if value else cache_dir() / "jax"


def enable_compile_cache() -> Path | None:
    """Turn the persistent cache on (idempotent; call it before the first compile so that every
    compile is cached); returns the directory in use, None when opted out. A cache directory the
    user gave JAX itself wins over urb-jax's and its settings are left alone. A folder that cannot
    be created or written is a UrbJaxError naming it and the fix."""
    current = cast(Any, jax.config).jax_compilation_cache_dir
    if current and current not in _OWNED:
        return Path(current)
    path = compile_cache_path()
    if path is None:
        _use(None)
        return None
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", MIN_ENTRY_SIZE_BYTES)
    path = path.resolve()
    if current != str(path):
        writable_dir(path, f"the compilation cache (${COMPILE_CACHE_ENV}, else <{CACHE_ENV} or "
                     "~/.cache/urb-jax>/jax)", f"set {COMPILE_CACHE_ENV} to a folder you can write to, "
                     f"or {COMPILE_CACHE_ENV}=off")
        _use(str(path))
    return path


def disable_compile_cache() -> None:
    """No persistent cache from here on in this process (the opt-out; tests); a cache directory
    the user gave JAX itself stays."""
    if cast(Any, jax.config).jax_compilation_cache_dir in _OWNED:
        _use(None)


_OWNED: set[str] = set()  # cache dirs set here (a user's own JAX setting is never replaced)


def _use(path: str | None) -> None:
    """Point JAX's cache at `path` (None: off); JAX opens its cache once, so it is re-opened."""
    if cast(Any, jax.config).jax_compilation_cache_dir == path:
        return
    compilation_cache.set_cache_dir(path)
    compilation_cache.reset_cache()
    if path is not None:
        _OWNED.add(path)
