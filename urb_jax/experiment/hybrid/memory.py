"""Will the learner fit in memory? Said before training, not found out by the kernel's OOM killer.

URB's QMIX config1 on ingolstadt_custom (414 CAVs) has a mixer of about 164 M parameters (its
hypernetwork grows as CAVs squared); with target, Adam moments and five seeds under vmap the run
grew past 21 GB during setup and the kernel killed it (session 15), on a machine whose other jobs
it could as well have killed. The learner's state is known from shapes alone (`jax.eval_shape` of
its init), so the run compares it, with room for the update's gradients and temporaries, to the
memory this machine has available, and refuses with the fix when it does not fit.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np

from urb_jax.core.errors import UrbJaxError

# The training's peak over its state: gradients, the update's intermediates and the compiled
# programs' buffers come on top of the state (params, target, optimizer moments, replay buffer).
# Measured on URB's QMIX config1 (session 15): resident memory grew by about 1.8 x the state
# (Scenario 2, 5 seeds: 3.6 GB of state, 9.6 GB resident; nemours, 1 seed: 1.2 GB, 5.3 GB), and
# ingolstadt_custom (5 seeds and the probe: 14.9 GB of state) was killed at 21.7 GB, still growing.
PEAK_OVER_STATE = 2.0
GB = 1024**3


def tree_size(tree: Any) -> int:
    """Elements of a pytree of arrays or shapes (`jax.ShapeDtypeStruct`)."""
    return sum(int(np.prod(x.shape)) for x in jax.tree_util.tree_leaves(tree))


def tree_bytes(tree: Any) -> int:
    """Bytes of a pytree of arrays or shapes (`jax.ShapeDtypeStruct`)."""
    return sum(int(np.prod(x.shape)) * np.dtype(x.dtype).itemsize for x in jax.tree_util.tree_leaves(tree))


def available_bytes() -> int:
    """Memory this machine can give a new allocation now (Linux: MemAvailable), else its free pages."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_fits(state: Any, seeds: int, extra: int, what: str, available: int | None = None) -> None:
    """Refuse (UrbJaxError, exit 2) a training whose `seeds` learner states (`state`: one seed's
    runner, shapes or arrays) plus `extra` more (the clock's one-environment probe) would not fit
    in the `available` bytes (default: this machine's, now) with PEAK_OVER_STATE room."""
    per_seed = tree_bytes(state) * PEAK_OVER_STATE
    need = per_seed * (seeds + extra)
    available = available_bytes() if available is None else available
    if need <= available:
        return
    fit = int(available // per_seed) - extra
    fix = (f"--set hybrid.max_vmapped_seeds={fit} (trains {fit} seed(s) at a time), " if 0 < fit < seeds
           else "")
    raise UrbJaxError(f"{what}: the learner's state is {tree_bytes(state) / GB:.1f} GB a seed, about "
                      f"{need / GB:.1f} GB at its peak for {seeds} seed(s) trained together, and this "
                      f"machine has {available / GB:.1f} GB available. Fix: {fix}a smaller algorithm config "
                      f"(e.g. --alg-conf hybrid), or a machine with more memory; the human phase is kept "
                      f"(--human-phase-from reuses it).")
