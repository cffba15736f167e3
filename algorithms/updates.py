"""Update mechanics shared by the learners: the clipped Adam and one step of it, target-network
updates, URB's and PureJaxRL's update plans, GAE, and [T, B] day-array reshaping."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax


def clip_by_global_norm(max_norm: float) -> optax.GradientTransformation:
    """optax.clip_by_global_norm's rule (above `max_norm`, gradients / (norm / max_norm)) as one
    division by a scalar. optax's per-element select between g and g / norm * max_norm makes XLA
    write the clipped gradient out and read it back in each of Adam's passes; a scalar divisor
    fuses into them. On URB's QMIX hypernetwork (82 M parameters on Nemours) this, with
    `networks.kernel_layout_dot`, makes training about 3x faster on a CPU (docs/algorithms.md).
    The values are optax's up to float rounding (exactly, for max_norm 1, outside fusion)."""
    def update(updates: Any, state: Any, params: Any = None) -> tuple[Any, Any]:
        norm = optax.tree.norm(updates)
        divisor = jnp.where(norm < max_norm, 1.0, norm / max_norm)
        return jax.tree_util.tree_map(lambda g: g / divisor.astype(g.dtype), updates), state

    return optax.GradientTransformation(lambda params: optax.EmptyState(), update)


def clipped_adam(max_grad_norm: float, lr: float, *, fused_clip: bool = False
                 ) -> optax.GradientTransformation:
    """The learners' optimiser, as URB's TorchRL scripts: global-norm clip, then Adam. `fused_clip`
    (QMIX, whose hypernetwork makes the clip's memory traffic the cost of a step) uses the form
    above; the others keep optax's, so that their records stay byte-identical to earlier runs."""
    clip = clip_by_global_norm(max_grad_norm) if fused_clip else optax.clip_by_global_norm(max_grad_norm)
    return optax.chain(clip, optax.adam(lr))


def adam_step(tx: optax.GradientTransformation, loss_fn: Callable[..., Any], params: Any, opt_state: Any,
              *args: Any, has_aux: bool = False) -> tuple[tuple[Any, Any], Any]:
    """One optimiser step on `loss_fn(params, *args)`: ((params, opt_state), loss or (loss, aux))."""
    out, grads = jax.value_and_grad(loss_fn, has_aux=has_aux)(params, *args)
    updates, opt_state = tx.update(grads, opt_state, params)
    return (optax.apply_updates(params, updates), opt_state), out


def select_tree(pred: jnp.ndarray, on_true: Any, on_false: Any) -> Any:
    return jax.tree_util.tree_map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)


def polyak(target: Any, online: Any, keep: float) -> Any:
    """target <- keep * target + (1 - keep) * online."""
    return jax.tree_util.tree_map(lambda t, o: keep * t + (1.0 - keep) * o, target, online)


def minibatch_days(minibatch_size: int, n_cavs: int) -> int:
    return max(1, minibatch_size // max(n_cavs, 1))


def n_updates(num_epochs: int, days_collected: int, n_cavs: int, minibatch_size: int) -> int:
    """URB's Adam steps per iteration: num_epochs * floor(frames / minibatch), at least num_epochs."""
    return num_epochs * max(1, days_collected * n_cavs // max(minibatch_size, 1))


def update_plan(num_minibatches: int, minibatch_size: int, days: int, n_cavs: int,
                capacity_days: int | None = None) -> tuple[int, int]:
    """(Adam steps per epoch, whole days per minibatch) for an update on `days` collected days.

    num_minibatches == 0 (URB): `max(1, days * C // minibatch_size)` steps of
    `max(1, minibatch_size // C)` days, so B environments mean B times as many steps.
    num_minibatches > 0 (PureJaxRL): `num_minibatches` steps of `days // num_minibatches` days (at
    least 1; at most `capacity_days`, a replay buffer's size), so the step count is independent of B
    and the minibatch grows with it. Every epoch repeats the plan (num_epochs x steps in all)."""
    if num_minibatches <= 0:
        return n_updates(1, days, n_cavs, minibatch_size), minibatch_days(minibatch_size, n_cavs)
    mb = max(1, days // num_minibatches)
    if capacity_days is not None:
        mb = min(mb, capacity_days)
    return num_minibatches, mb


def gae(rewards: jnp.ndarray, values: jnp.ndarray, dones: jnp.ndarray, last_value: jnp.ndarray,
        gamma: float, lmbda: float) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Generalised advantage estimation over the leading (day) axis; a done day does not bootstrap.
    With URB's one-day episodes (every done true) it reduces to advantage = reward - value."""
    def body(carry: tuple[jnp.ndarray, jnp.ndarray], x: tuple[jnp.ndarray, ...]):
        adv, next_value = carry
        r, v, d = x
        not_done = 1.0 - d.astype(jnp.float32)
        delta = r + gamma * next_value * not_done - v
        adv = delta + gamma * lmbda * not_done * adv
        return (adv, v), adv

    _, advantages = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), (rewards, values, dones),
                                 reverse=True)
    return advantages, advantages + values


def flatten_days(tree: Any) -> Any:
    """[T, B, ...] -> [T*B, ...]."""
    return jax.tree_util.tree_map(lambda x: x.reshape(-1, *x.shape[2:]), tree)


def days_shape(days: Any) -> tuple[int, int]:
    """(T, B) of Day arrays [T, B, ...]."""
    leaf = jax.tree_util.tree_leaves(days)[0]
    return int(leaf.shape[0]), int(leaf.shape[1])
