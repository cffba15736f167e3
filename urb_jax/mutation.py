"""Mutation: which humans become CAVs (URB_REFERENCE §5), drawn from the env seed."""

from __future__ import annotations

import numpy as np


def draw_cavs(env_seed: int, n_agents: int, share: float) -> np.ndarray:
    """[N] bool: int(N * share) agents, uniformly without replacement (positions in agent order).

    URB draws with Python's `random` after the human beta draws, so the exact set differs from a
    URB run with the same seed; the distribution is the same.
    """
    if not 0.0 <= share <= 1.0:
        from urb_jax.errors import ConfigError

        raise ConfigError(f"ratio_machines must be in [0, 1], got {share}")
    n_cav = int(n_agents * share)
    rng = np.random.default_rng([env_seed, 0x5EED])
    mask = np.zeros(n_agents, dtype=bool)
    mask[rng.choice(n_agents, size=n_cav, replace=False)] = True
    return mask
