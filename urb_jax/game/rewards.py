"""CAV reward profiles (URB_REFERENCE §6): R_i = a*t_own + b*T_cav + c*T_human + d*T_all.

Travel times in minutes; group means over CAVs / humans / everyone (0 for an empty group).
Pure jax.numpy, so it runs inside jitted environments and on numpy SUMO days alike.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp

from urb_jax.core.errors import ConfigError

BEHAVIOURS: dict[str, tuple[float, float, float, float]] = {
    "selfish": (-1.0, 0.0, 0.0, 0.0),
    "competitive": (-2.0, 0.0, 1.0, 0.0),
    "collaborative": (-0.5, -0.5, 0.0, 0.0),
    "cooperative": (0.0, -1.0, 0.0, 0.0),
    "social": (-0.5, 0.0, 0.0, -0.5),
    "altruistic": (0.0, 0.0, 0.0, -1.0),
    "malicious": (0.0, 0.0, 1.0, 0.0),
    "collectivist": (-0.1, -0.9, 0.0, 0.0),
    "militant": (0.0, -2.0, 1.0, 0.0),
}


def behaviour_coefficients(behaviour: str | Sequence[float]) -> tuple[float, float, float, float]:
    """(own, CAV group, humans, everyone) weights for a named profile or a custom 4-tuple."""
    if isinstance(behaviour, str):
        if behaviour not in BEHAVIOURS:
            raise ConfigError(
                f"unknown av_behavior '{behaviour}'. Fix: use one of {', '.join(BEHAVIOURS)} "
                "or a list of 4 numbers [own, cav_group, humans, all]."
            )
        return BEHAVIOURS[behaviour]
    coeffs = tuple(float(x) for x in behaviour)
    if len(coeffs) != 4:
        raise ConfigError(f"custom av_behavior needs 4 numbers [own, cav_group, humans, all], got {coeffs}")
    return coeffs  # type: ignore[return-value]


def _masked_mean(x: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    count = mask.sum(axis=-1)
    total = jnp.where(mask, x, 0.0).sum(axis=-1)
    return jnp.where(count > 0, total / jnp.maximum(count, 1), 0.0)


def group_means(times: jnp.ndarray, is_cav: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """(mean over CAVs, mean over humans, mean over all) along the last axis."""
    is_cav = jnp.asarray(is_cav, dtype=bool)
    all_mask = jnp.ones_like(is_cav)
    return _masked_mean(times, is_cav), _masked_mean(times, ~is_cav), _masked_mean(times, all_mask)


def cav_rewards(
    times: jnp.ndarray, is_cav: jnp.ndarray, coefficients: Sequence[float]
) -> jnp.ndarray:
    """Reward of every agent as if it were a CAV (use it for CAVs); works batched [..., N]."""
    a, b, c, d = (float(v) for v in coefficients)
    t_cav, t_hum, t_all = group_means(times, is_cav)
    shared = b * t_cav + c * t_hum + d * t_all
    return a * times + shared[..., None]
