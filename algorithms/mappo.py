"""MAPPO (URB's `mappo_torchrl.py`): IPPO with a centralised critic.

The critic's input is `env.global_state(obs)` (every CAV's scaled observation, flattened
[C * D]); with shared parameters URB broadcasts its single value to every CAV, and so do we.
With per-CAV parameters (`shared_parameters: false`) each CAV has its own value head on the
global state, so a selfish reward (task config1) gets a per-CAV baseline instead of one team
value (whose advantage would mostly be the CAV's own travel-time level).
Everything else (actor, GAE, clipped loss, minibatches of whole days) is `algorithms.ippo`;
URB trains MAPPO with the cooperative reward, which the environment's reward coefficients set.
"""

from __future__ import annotations

from urb_jax.algorithms import ippo
from urb_jax.algorithms.configs import PPOConfig
from urb_jax.algorithms.learner import Learner
from urb_jax.game.env import RoutingEnv


def make_policy(config: PPOConfig, env: RoutingEnv):
    return ippo.make_policy(config, env, centralised=True)


def make_learner(config: PPOConfig, env: RoutingEnv) -> Learner:
    return ippo.make_learner(config, env, centralised=True)


def make_train(config: PPOConfig, env: RoutingEnv):
    return ippo.make_train(config, env, centralised=True)
