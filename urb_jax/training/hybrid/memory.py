"""Will the learner fit in memory? Said before training, not found out by the kernel's OOM killer.

URB's QMIX config1 on ingolstadt_custom (414 CAVs) has a mixer of about 164 M parameters (its
hypernetwork grows as CAVs squared); with target, Adam moments and five seeds under vmap the run
grew past 21 GB during setup and the kernel killed it, on a machine whose other jobs
it could as well have killed. The learner's state is known from shapes alone (`jax.eval_shape` of
its init), so the run compares it, with room for the update's gradients and temporaries, to the
memory available where the learner lives (a GPU's own memory, else this machine's), and refuses
with the fix when it does not fit.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np

from urb_jax.core.errors import UrbJaxError

# The training's peak over its state: the update's gradients and intermediates come on top of the
# state (params, target, optimizer moments, replay buffer), and the round's learner runs donate the
# old state to the new (hybrid/fns.py). Measured on URB's QMIX config1, saint_arnoult Scenario 2,
# 2 seeds, 1.44 GB of state (`python benchmarks/learner_memory.py`): the resident set
# rose over the process's own by 3.08 x the state (a fresh run, to round 1) and 2.91 x (resumed),
# both peaks in the surrogate iterations; 4.18 x and 3.72 x before the donation. 3.5 leaves room.
PEAK_OVER_STATE = 3.5
GB = 1024**3


def tree_size(tree: Any) -> int:
    """Elements of a pytree of arrays or shapes (`jax.ShapeDtypeStruct`)."""
    return sum(int(np.prod(x.shape)) for x in jax.tree_util.tree_leaves(tree))


def tree_bytes(tree: Any) -> int:
    """Bytes of a pytree of arrays or shapes (`jax.ShapeDtypeStruct`)."""
    return sum(int(np.prod(x.shape)) * np.dtype(x.dtype).itemsize for x in jax.tree_util.tree_leaves(tree))


def accelerator_stats() -> dict[str, int] | None:
    """The default device's memory counters where it has its own memory (a GPU: JAX's
    `memory_stats`, with bytes_limit and bytes_in_use), else None (a CPU: the learner lives in the
    machine's memory)."""
    stats = jax.devices()[0].memory_stats()
    return stats if stats and "bytes_limit" in stats else None


def memory_place() -> str:
    """Where the learner's state lives, for the messages."""
    return "this machine" if accelerator_stats() is None else f"the {jax.devices()[0].device_kind}"


def available_bytes() -> int:
    """Memory a new allocation of the learner can have now: the accelerator's free memory where it
    has its own (bytes_limit - bytes_in_use), else this machine's (Linux: MemAvailable), else its
    free pages."""
    stats = accelerator_stats()
    if stats is not None:
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_fits(state: Any, seeds: int, what: str, available: int | None = None) -> str:
    """Refuse (UrbJaxError, exit 2) a training whose `seeds` learner states (`state`: one seed's
    runner, shapes or arrays) would not fit in the `available` bytes (default: what the learner's
    device has now) with PEAK_OVER_STATE room. Returns the line that says it fits (a big learner's
    run prints it). The clock's probe (one environment, one seed) runs before the group's state
    exists, so one seed's room covers it."""
    state_bytes = tree_bytes(state)
    per_seed = state_bytes * PEAK_OVER_STATE
    need = per_seed * seeds
    available = available_bytes() if available is None else available
    place = memory_place()
    if need <= available:
        return (f"memory: the learner's state is {state_bytes / GB:.2f} GB a seed, "
                f"{state_bytes * seeds / GB:.2f} GB for {seeds} seed(s); about {need / GB:.1f} GB at "
                f"the peak, {available / GB:.1f} GB available on {place}")
    fit = int(available // per_seed)
    fix = (f"--set hybrid.max_vmapped_seeds={fit} (trains {fit} seed(s) at a time), " if 0 < fit < seeds
           else "")
    raise UrbJaxError(f"{what}: the learner's state is {state_bytes / GB:.1f} GB a seed, about "
                      f"{need / GB:.1f} GB at its peak for {seeds} seed(s) trained together, and {place} "
                      f"has {available / GB:.1f} GB available. Fix: {fix}a smaller algorithm config "
                      f"(e.g. --alg-conf hybrid), or a machine with more memory; the human phase is kept "
                      f"(--human-phase-from reuses it).")


def program_bytes(compiled: Any) -> int | None:
    """Bytes a compiled program allocates when it runs, over its arguments: its temporaries and the
    outputs not written over donated inputs (XLA's `memory_analysis`); None where the backend does
    not say."""
    try:
        stats = compiled.memory_analysis()
    except (AttributeError, NotImplementedError, RuntimeError):
        return None
    if stats is None:
        return None
    new = int(stats.temp_size_in_bytes) + int(stats.output_size_in_bytes) - int(stats.alias_size_in_bytes)
    return max(0, new)


def check_program_fits(compiled: Any, what: str, available: int | None = None) -> None:
    """Refuse (UrbJaxError, exit 2) to run a compiled program that would allocate more than the
    memory available now. The state check (`check_fits`) sees only the learner's state; a learner's
    transient batch can be far bigger (IPPO on URB's frames: every CAV's row in every CAV's frame,
    tens of GB for five vmapped seeds on St. Arnoult), and XLA knows its size once it has compiled."""
    need = program_bytes(compiled)
    available = available_bytes() if available is None else available
    if need is None or need <= available:
        return
    raise UrbJaxError(f"{what}: its compiled program needs about {need / GB:.1f} GB of temporaries and "
                      f"{memory_place()} has {available / GB:.1f} GB available. Fix: train the seeds one "
                      "after another inside the program (--set hybrid.seed_axis=map: the temporaries of "
                      "one seed), fewer seeds at a time (--set hybrid.max_vmapped_seeds=K) or fewer "
                      "environments (--set hybrid.num_envs=B); the human phase is kept (--resume, or "
                      "--human-phase-from).")

