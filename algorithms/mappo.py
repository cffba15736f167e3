"""MAPPO (URB's `mappo_torchrl.py`): IPPO with a centralised critic.

The critic's input is `env.global_state(obs)` (every CAV's scaled observation, flattened
[C * D]); with shared parameters URB broadcasts its single value to every CAV, and so do we.
Everything else (actor, GAE, clipped loss, minibatches of whole days) is `algorithms.ippo`;
URB trains MAPPO with the cooperative reward, which the environment's reward coefficients set.
"""

from __future__ import annotations

from algorithms import ippo
from algorithms.common import PPOConfig
from urb_jax.env import RoutingEnv


def make_policy(config: PPOConfig, env: RoutingEnv):
    return ippo.make_policy(config, env, centralised=True)


def make_train(config: PPOConfig, env: RoutingEnv):
    return ippo.make_train(config, env, centralised=True)
