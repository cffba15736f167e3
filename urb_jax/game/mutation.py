"""Mutation: which humans become CAVs (URB_REFERENCE §5), drawn from the env seed.

URB's draw is reproduced exactly, because which agents become CAVs decides t_CAV and the win rate
more than any policy does (a 40% draw's own pre-mutation mean spans about ±0.15 min on St. Arnoult).
RouteRL seeds Python's `random` with the env seed, draws one `random.uniform` per human for its
beta (agents.csv order), then picks the CAVs with sequential `random.choice` + `remove` over the
humans in agents.csv order. With env seed 42 this gives the CAVs whose pre-mutation mean matches
the paper's AON t_CAV (St. Arnoult 3.048 vs 3.01, Provins 2.786 vs 2.76), which no other draw does.
"""

from __future__ import annotations

import random

import numpy as np

from urb_jax.core.errors import ConfigError

METHODS = ("urb", "numpy")


def draw_cavs(env_seed: int, n_agents: int, share: float, agent_id: np.ndarray | None = None,
              method: str = "urb") -> np.ndarray:
    """[N] bool mask over agent positions: int(N * share) agents become CAVs.

    `agent_id[i]` is the URB id of position i (agents.csv ids are their row numbers in every URB
    network, so ascending id = agents.csv order); None means positions are already in csv order.
    `method="numpy"` is the old independent uniform draw (same distribution, different set).
    """
    if not 0.0 <= share <= 1.0:
        raise ConfigError(f"ratio_machines must be in [0, 1], got {share}")
    if method not in METHODS:
        raise ConfigError(f"CAV draw method {method!r}: use one of {METHODS}")
    n_cav = int(n_agents * share)
    mask = np.zeros(n_agents, dtype=bool)
    if method == "numpy":
        rng = np.random.default_rng([env_seed, 0x5EED])
        mask[rng.choice(n_agents, size=n_cav, replace=False)] = True
        return mask
    csv_order = np.arange(n_agents) if agent_id is None else np.argsort(np.asarray(agent_id), kind="stable")
    rng_py = random.Random(env_seed)
    for _ in range(n_agents):  # every human's beta: random.uniform consumes one random() each
        rng_py.random()
    pool = [int(p) for p in csv_order]
    for _ in range(n_cav):
        pick = rng_py.choice(pool)
        pool.remove(pick)
        mask[pick] = True
    return mask


FLEET_SALT = 0xF1EE7  # the fleet split's stream of the env seed (apart from every other draw)
HUMAN = -1  # split_fleets' entry of a human


def split_fleets(env_seed: int, is_cav: np.ndarray, shares: tuple[float, ...]) -> np.ndarray:
    """[N] int: each agent's fleet (0 .. F-1), HUMAN (-1) for a human. The CAVs of the task's draw
    (`draw_cavs` at the sum of the shares, so the fleets together are exactly the one-fleet task's
    CAVs) are shuffled by default_rng([env_seed, FLEET_SALT]) and cut in order: fleet f takes
    the CAVs from round(C * s_<f / s) to round(C * s_<=f / s), with s_<f the shares before f and s
    their sum (the last fleet ends at C)."""
    is_cav = np.asarray(is_cav, dtype=bool)
    cavs = np.flatnonzero(is_cav)
    total = float(sum(shares))
    cuts = [round(len(cavs) * float(sum(shares[:f])) / total) for f in range(len(shares))] + [len(cavs)]
    order = np.random.default_rng([env_seed, FLEET_SALT]).permutation(cavs)
    fleet = np.full(is_cav.shape, HUMAN, np.int32)
    for f in range(len(shares)):
        fleet[order[cuts[f]:cuts[f + 1]]] = f
    return fleet
