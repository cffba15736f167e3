"""VDN (URB's `vdn_torchrl.py`): QMIX with Q_tot = sum of the CAVs' chosen Q values.

Same agent networks (Tanh, shared + OD embedding), team reward (mean CAV reward), replay of whole
days, soft target updates and epsilon schedule as `algorithms.qmix`; `mixing_embed_dim` is
ignored, as in URB.
"""

from __future__ import annotations

from algorithms import qmix
from algorithms.common import MixerConfig
from urb_jax.env import RoutingEnv


def make_policy(config: MixerConfig, env: RoutingEnv):
    return qmix.make_policy(config, env)


def make_train(config: MixerConfig, env: RoutingEnv):
    return qmix.make_train(config, env, mixer="vdn")
