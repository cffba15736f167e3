"""Fixed CAV policies for comparison (URB_REFERENCE §9), in the algorithms' policy signature
`policy(key, obs[C, D]) -> actions[C]`, usable inside `collect`/`evaluate` and on SUMO days.

* aon: the minimum free-flow route (URB FFT, destination edge excluded), constant;
* random: uniform over each CAV's valid routes, every day.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.networks import take_agents
from urb_jax.algorithms.policy import NEG, Policy
from urb_jax.game.env import RoutingEnv


def aon_policy(env: RoutingEnv) -> Policy:
    fft = env.scenario.fft[env.cav_index]
    choice = jnp.asarray(np.argmin(np.where(env.action_mask, fft, np.inf), axis=1), dtype=jnp.int32)
    return lambda key, obs, idx=None: take_agents(choice, idx)


def random_policy(env: RoutingEnv) -> Policy:
    logits = jnp.where(jnp.asarray(env.action_mask), 0.0, NEG)
    return lambda key, obs, idx=None: jax.random.categorical(key, take_agents(logits, idx), axis=-1).astype(
        jnp.int32)


BASELINES = {"aon": aon_policy, "random": random_policy}
