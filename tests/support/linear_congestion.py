"""A linear congestion model on two shared routes, whose externalities are known by hand (the credit
and marginal-cost tests')."""

from __future__ import annotations

import jax.numpy as jnp

COST = jnp.asarray([1.0, 2.0])  # free-flow minutes of two routes every agent has
ALPHA = 0.1  # minutes each vehicle adds to its route
CONST = 0.5  # a route-independent part of every time (like the surrogate's insertion delay)


def linear_model(probs: jnp.ndarray) -> jnp.ndarray:
    """t_j = CONST + sum_k P_jk (COST_k + ALPHA * flow_k): linear congestion, shared routes."""
    flow = probs.sum(0)  # [K]
    return CONST + (probs * (COST + ALPHA * flow)[None]).sum(1)
