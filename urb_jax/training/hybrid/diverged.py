"""A learner that diverged stops its run: each round's losses (rounds.csv's sur_loss, sumo_loss) and
every seed's learner parameters are checked on the host after the round, before its checkpoint, so
no NaN policy is checkpointed, tested or reported (a NaN loss would otherwise pass through every
metric: NaN compares false with everything)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.core.errors import UrbJaxError

LOSS_KEYS = ("sur_loss", "sumo_loss")  # the learner's losses in a round's row


class DivergedError(UrbJaxError):
    """A learner's loss or parameters became NaN or infinite."""


@jax.jit
def finite_per_seed(tree: Any) -> jax.Array:
    """[S] bool: every float array of `tree` (leading seed axis S) finite for seed s."""
    leaves = [x for x in jax.tree_util.tree_leaves(tree) if jnp.issubdtype(x.dtype, jnp.inexact)]
    if not leaves:
        return jnp.ones((), bool)
    return jnp.stack([jnp.isfinite(x).reshape(x.shape[0], -1).all(1) for x in leaves]).all(0)


def check_learner(params: Any, rows: Sequence[dict[str, float]], r: int, seeds: Sequence[int]) -> None:
    """Raise DivergedError naming round r + 1 (rounds.csv's number), the seeds and what diverged
    when a seed's loss in `rows` (one per seed) or its learner `params` ([S, ...]) is not finite."""
    finite = np.broadcast_to(np.asarray(finite_per_seed(params)), (len(seeds),))
    bad = []
    for seed, row, ok in zip(seeds, rows, finite, strict=True):
        what = [f"{k} = {row[k]}" for k in LOSS_KEYS if k in row and not math.isfinite(row[k])]
        if not ok:
            what.append("its parameters hold NaN or infinite values")
        if what:
            bad.append(f"seed {seed}: {', '.join(what)}")
    if bad:
        raise DivergedError(
            f"the learner diverged in round {r + 1} ({'; '.join(bad)}); the run stops before that round's "
            "checkpoint, and no metrics are written. Fix: train with a smaller learning rate (--set "
            "alg.lr=...), a gradient clip (alg.max_grad_norm), or check the task's reward scale; then "
            "start the run again with --overwrite.")
