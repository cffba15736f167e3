"""VDN (URB's `vdn_torchrl.py`): QMIX with Q_tot = sum of the CAVs' chosen Q values.

Same agent networks (Tanh, shared + OD embedding), team reward (mean CAV reward), replay of whole
days, soft target updates and epsilon schedule as `algorithms.qmix`; `mixing_embed_dim` is
ignored, as in URB.
"""

from __future__ import annotations

from urb_jax.algorithms import qmix
from urb_jax.algorithms.configs import MixerConfig
from urb_jax.algorithms.learner import Learner
from urb_jax.game.env import RoutingEnv


def make_policy(config: MixerConfig, env: RoutingEnv):
    return qmix.make_policy(config, env)


def make_learner(config: MixerConfig, env: RoutingEnv) -> Learner:
    return qmix.make_learner(config, env, mixer="vdn")


def make_train(config: MixerConfig, env: RoutingEnv):
    return qmix.make_train(config, env, mixer="vdn")
