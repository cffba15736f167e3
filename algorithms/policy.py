"""Acting: invalid-route masking, epsilon-greedy over valid routes, exploration schedules. Every
learner and baseline exposes the game's `Policy` signature (`urb_jax.game.rollout`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from urb_jax.algorithms.networks import take_agents
from urb_jax.game.rollout import Policy

NEG = -1e9


def masked(logits: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    """Invalid routes (padding repeats for ODs with fewer than K routes) get -1e9."""
    return jnp.where(mask, logits, NEG)


def eps_greedy(key: jax.Array, q: jnp.ndarray, mask: jnp.ndarray, eps: float | jnp.ndarray) -> jnp.ndarray:
    """[..., K] values -> actions; with probability eps a uniform valid route, drawn for every
    entry of the values' leading axes (the mask broadcasts to them)."""
    k_rand, k_explore = jax.random.split(key)
    greedy = jnp.argmax(masked(q, mask), axis=-1)
    rand = jax.random.categorical(k_rand, jnp.broadcast_to(jnp.where(mask, 0.0, NEG), q.shape), axis=-1)
    explore = jax.random.uniform(k_explore, greedy.shape) < eps
    return jnp.where(explore, rand, greedy).astype(jnp.int32)


def eps_greedy_policy(apply: Callable[..., jnp.ndarray], mask: jnp.ndarray) -> Callable[..., Policy]:
    """(params, eps) -> policy(key, obs[n, D], idx=None) -> actions[n]: epsilon-greedy over valid
    routes (eps=0: the greedy test policy) for any Q network `apply(params, obs, idx)`."""

    def policy_for(params: Any, eps: float | jnp.ndarray = 0.0) -> Policy:
        def policy(key: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
            return eps_greedy(key, apply(params, obs, idx), take_agents(mask, idx), eps)

        return policy

    return policy_for


def linear_schedule(start: float, end: float, steps: float) -> Callable[[jnp.ndarray], jnp.ndarray]:
    def schedule(t: jnp.ndarray) -> jnp.ndarray:
        frac = jnp.clip(t / max(steps, 1.0), 0.0, 1.0)
        return start + frac * (end - start)

    return schedule


def entropy(logits: jnp.ndarray) -> jnp.ndarray:
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -(jnp.exp(logp) * logp).sum(-1)
