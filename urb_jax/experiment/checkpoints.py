"""Checkpoints: pytrees saved with orbax (the hybrid trainer's round checkpoints build on these)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax


def save_checkpoint(path: str | Path, tree: Any) -> Path:
    """Save a pytree with orbax at an absolute path; waits for the async save to finish."""
    import orbax.checkpoint as ocp

    path = Path(path).expanduser().resolve()
    ckptr = ocp.StandardCheckpointer()
    ckptr.save(path, tree, force=True)
    ckptr.wait_until_finished()
    return path


def restore_checkpoint(path: str | Path, target: Any) -> Any:
    """Restore a pytree saved by save_checkpoint; `target` gives structure, shapes and dtypes."""
    import orbax.checkpoint as ocp

    path = Path(path).expanduser().resolve()
    abstract = jax.tree_util.tree_map(ocp.utils.to_shape_dtype_struct, target)
    return ocp.StandardCheckpointer().restore(path, abstract)
