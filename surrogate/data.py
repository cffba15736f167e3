"""Varied joint actions for calibration and validation days.

Kinds, cycled: all free-flow (every agent on its fastest free-flow route), uniform random,
equilibrium-like (rounds of partial best response to the surrogate), and mixes/perturbations of
those (a random share of agents re-drawn at random).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.surrogate.model import Static, route_times_seconds

KINDS = ("free_flow", "random", "equilibrium", "mix", "perturbed")


def best_response_rounds(
    scn: Scenario, static: Static, params: dict, start: np.ndarray, rng: np.random.Generator,
    rounds: int = 6, switch: float = 0.3,
) -> np.ndarray:
    """Each round a random `switch` share of agents moves to its fastest route under the surrogate."""
    ch = start.copy()
    valid = scn.route_valid
    for _ in range(rounds):
        probs = np.eye(scn.k, dtype=np.float32)[ch][None]
        rt = np.asarray(route_times_seconds(params, static, jnp.asarray(probs)))[0]
        rt = np.where(valid, rt, np.inf)
        best = rt.argmin(axis=1)
        move = rng.random(scn.n_agents) < switch
        ch = np.where(move, best, ch)
    return ch


def random_choices(scn: Scenario, rng: np.random.Generator) -> np.ndarray:
    n_valid = scn.route_valid.sum(axis=1)
    return (rng.random(scn.n_agents) * n_valid).astype(np.int64)


def make_choices(
    scn: Scenario, static: Static, params: dict, n_days: int, seed: int,
) -> tuple[np.ndarray, list[str]]:
    """[n_days, N] joint actions of the kinds above (cycled) and the kind of each day."""
    rng = np.random.default_rng(seed)
    free = np.asarray(scn.fft).argmin(axis=1)
    days, kinds = [], []
    eq_cache: np.ndarray | None = None
    for d in range(n_days):
        kind = KINDS[d % len(KINDS)]
        if kind == "free_flow":
            ch = free if d == 0 else np.where(rng.random(scn.n_agents) < 0.05, random_choices(scn, rng), free)
        elif kind == "random":
            ch = random_choices(scn, rng)
        elif kind == "equilibrium":
            start = free if eq_cache is None else eq_cache
            eq_cache = best_response_rounds(scn, static, params, start, rng)
            ch = eq_cache
        elif kind == "mix":
            q = rng.uniform(0.2, 0.8)
            ch = np.where(rng.random(scn.n_agents) < q, random_choices(scn, rng), free)
        else:
            base = eq_cache if eq_cache is not None else free
            q = rng.uniform(0.05, 0.3)
            ch = np.where(rng.random(scn.n_agents) < q, random_choices(scn, rng), base)
        days.append(np.asarray(ch, dtype=np.int64))
        kinds.append(kind)
    return np.stack(days), kinds
