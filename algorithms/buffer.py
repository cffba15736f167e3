"""A jitted ring replay buffer over pytrees (FIFO, uniform sampling without replacement)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp


class Buffer(NamedTuple):
    data: Any  # pytree, every leaf [capacity, ...]
    pos: jnp.ndarray
    size: jnp.ndarray


def buffer_init(example: Any, capacity: int) -> Buffer:
    data = jax.tree_util.tree_map(
        lambda x: jnp.zeros((capacity, *jnp.shape(x)), jnp.asarray(x).dtype), example)
    return Buffer(data, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))


def buffer_add(buf: Buffer, batch: Any) -> Buffer:
    """Append a batch (leading axis n) FIFO; if n > capacity only the newest `capacity` stay."""
    cap = jax.tree_util.tree_leaves(buf.data)[0].shape[0]
    n = jax.tree_util.tree_leaves(batch)[0].shape[0]
    if n > cap:
        batch = jax.tree_util.tree_map(lambda x: x[n - cap:], batch)
        n = cap
    idx = (buf.pos + jnp.arange(n)) % cap
    data = jax.tree_util.tree_map(lambda d, x: d.at[idx].set(x), buf.data, batch)
    return Buffer(data, (buf.pos + n) % cap, jnp.minimum(buf.size + n, cap))


def buffer_sample(buf: Buffer, key: jax.Array, n: int) -> Any:
    """n distinct stored entries, uniformly (no replacement, as TorchRL's sampler); valid once
    `buf.size >= n`."""
    cap = jax.tree_util.tree_leaves(buf.data)[0].shape[0]
    scores = jnp.where(jnp.arange(cap) < buf.size, jax.random.uniform(key, (cap,)), -1.0)
    _, idx = jax.lax.top_k(scores, n)
    return jax.tree_util.tree_map(lambda d: d[idx], buf.data)
