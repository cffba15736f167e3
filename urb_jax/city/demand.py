"""Demand scaling for the sensitivity study (x0.5, x2, ...) as a Scenario transformation.

Scaling down samples agents without replacement; scaling up keeps every agent and adds copies
(whole duplicates, then a sample for the fractional part) whose departures are jittered by a
seeded uniform offset in [-jitter, +jitter] s (clipped to the demand window), so copies do not
all enter SUMO at the same second. Routes are per OD, so copies reuse their original's routes.
"""

from __future__ import annotations

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.errors import ConfigError

# A day's route choice for a driver who does not travel that day (the task's day_participation):
# no SUMO vehicle, no surrogate flow, not observed, no learning (urb_jax.game.demand).
ABSENT = -1


def scale_demand(
    scn: Scenario, scale: float, *, seed: int, mode: str = "auto", jitter_s: int = 60
) -> Scenario:
    """A new Scenario with round(N * scale) agents, sorted by departure; copies get new ids >= N."""
    if scale <= 0:
        raise ConfigError(f"demand_scale must be > 0, got {scale}")
    if scale == 1.0:
        return scn
    if mode == "auto":
        mode = "sample" if scale < 1.0 else "duplicate"
    n = scn.n_agents
    n_new = max(1, round(n * scale))
    rng = np.random.default_rng([seed, 0xD3A4D])
    if mode == "sample":
        replace = n_new > n
        src = np.sort(rng.choice(n, size=n_new, replace=replace))
        copy = np.zeros(n_new, dtype=bool)
        if replace:  # repeated draws are copies
            first = np.r_[True, src[1:] != src[:-1]]
            copy = ~first
    elif mode == "duplicate":
        if n_new < n:
            raise ConfigError(f"demand_mode 'duplicate' needs demand_scale >= 1, got {scale}")
        whole = n_new // n
        extra = rng.choice(n, size=n_new - whole * n, replace=False)
        src = np.concatenate([np.tile(np.arange(n), whole), extra])
        copy = np.arange(src.shape[0]) >= n
    else:
        raise ConfigError(f"demand_mode must be auto, sample or duplicate, got {mode!r}")
    depart = scn.agent_depart[src].astype(np.int64)
    lo, hi = int(scn.agent_depart.min()), int(scn.agent_depart.max())
    jitter = rng.integers(-jitter_s, jitter_s + 1, size=src.shape[0]) if jitter_s > 0 else 0
    depart = np.where(copy, np.clip(depart + jitter, lo, hi), depart)
    ids = scn.agent_id[src].astype(np.int64)
    ids = np.where(copy, int(scn.agent_id.max()) + 1 + np.cumsum(copy) - 1, ids)
    order = np.lexsort((ids, depart))
    src, depart, ids = src[order], depart[order], ids[order]
    return scn.with_agents(src, agent_id=ids.astype(scn.agent_id.dtype),
                           agent_depart=depart.astype(scn.agent_depart.dtype))
