"""The algorithm table: id -> how to build its learner and which typed config it reads.

The one place that knows every algorithm: the CLI's choices, config loading and the trainers
all look algorithms up here (URB's names; mappo and vdn share their family's file).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

from urb_jax.algorithms import ippo, ippo_star, iql, iql_star, mappo, qmix, vdn
from urb_jax.algorithms.configs import IPPOStarConfig, IQLConfig, IQLStarConfig, MixerConfig, PPOConfig
from urb_jax.algorithms.learner import Learner
from urb_jax.core.configio import find_config, load_json
from urb_jax.core.errors import ConfigError
from urb_jax.game.env import RoutingEnv


class Algorithm(NamedTuple):
    make_learner: Callable[[Any, RoutingEnv], Learner]
    config_class: type


ALGORITHMS: dict[str, Algorithm] = {
    "iql": Algorithm(iql.make_learner, IQLConfig),
    "ippo": Algorithm(ippo.make_learner, PPOConfig),
    "mappo": Algorithm(mappo.make_learner, PPOConfig),
    "qmix": Algorithm(qmix.make_learner, MixerConfig),
    "vdn": Algorithm(vdn.make_learner, MixerConfig),
    "iql_star": Algorithm(iql_star.make_learner, IQLStarConfig),
    "ippo_star": Algorithm(ippo_star.make_learner, IPPOStarConfig),
}


def algorithm(name: str) -> Algorithm:
    if name not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm '{name}'. Fix: use one of {', '.join(ALGORITHMS)}.")
    return ALGORITHMS[name]


def load_algo_config(name: str, config: str = "config1") -> Any:
    """configs/algo/<name>/<config>.json (or a path) -> the algorithm's typed config."""
    return load_json(algorithm(name).config_class, find_config("algo", config, subdir=name))
