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


def buffer_init_columns(example: Any, capacity: int, n_columns: int) -> Buffer:
    """A buffer of `n_columns` independent FIFO rings side by side (leaves [capacity, n_columns,
    ...], `pos` and `size` [n_columns]): column c holds only what `buffer_add_where` kept for it,
    e.g. one CAV's samples of the days it travelled (`example`: one entry, leaves [n_columns, ...])."""
    data = jax.tree_util.tree_map(
        lambda x: jnp.zeros((capacity, *jnp.shape(x)), jnp.asarray(x).dtype), example)
    return Buffer(data, jnp.zeros((n_columns,), jnp.int32), jnp.zeros((n_columns,), jnp.int32))


def buffer_add_where(buf: Buffer, batch: Any, keep: jnp.ndarray) -> Buffer:
    """Append to each column of a `buffer_init_columns` buffer its rows of `batch` (leaves [n,
    n_columns, ...]) where `keep` [n, n_columns] is True, in order, FIFO per column: a column that
    keeps more than `capacity` rows keeps its newest `capacity`; a column that keeps none is as it was."""
    cap = jax.tree_util.tree_leaves(buf.data)[0].shape[0]

    def column(data: Any, pos: jnp.ndarray, size: jnp.ndarray, rows: Any, kept: jnp.ndarray
               ) -> tuple[Any, jnp.ndarray, jnp.ndarray]:
        rank = jnp.cumsum(kept.astype(jnp.int32)) - 1  # the row's place among the kept rows
        total = kept.sum(dtype=jnp.int32)
        idx = jnp.where(kept & (rank >= total - cap), (pos + rank) % cap, cap)  # cap: out of range, dropped
        data = jax.tree_util.tree_map(lambda d, x: d.at[idx].set(x, mode="drop"), data, rows)
        return data, (pos + total) % cap, jnp.minimum(size + total, cap)

    data, pos, size = jax.vmap(column, in_axes=(1, 0, 0, 1, 1), out_axes=(1, 0, 0))(
        buf.data, buf.pos, buf.size, batch, keep)
    return Buffer(data, pos, size)
