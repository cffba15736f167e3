"""The algorithm table: id -> how to build its learner and which typed config it reads.

The one place that knows every algorithm: the CLI's choices, config loading and the trainers
all look algorithms up here (mappo and vdn share their family's file). Each algorithm names the
URB config family it reads (`urb`: URB's folder under config/algo_config), so URB's own config
files load under URB's key names (`urb_jax.core.urb_keys`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from urb_jax.algorithms import ippo, ippo_star, iql, iql_star, mappo, qmix, vdn
from urb_jax.algorithms.configs import (
    BaselineConfig,
    IPPOStarConfig,
    IQLConfig,
    IQLStarConfig,
    MixerConfig,
    PPOConfig,
)
from urb_jax.algorithms.learner import Learner
from urb_jax.core.choices import ALGORITHM_URB_NAMES, URB_ALIASES
from urb_jax.core.configio import Loaded, Override, find_config, load_resolved
from urb_jax.core.errors import ConfigError
from urb_jax.core.urb_keys import ALGO_FAMILIES, algo_family
from urb_jax.game.env import RoutingEnv


class Algorithm(NamedTuple):
    make_learner: Callable[[Any, RoutingEnv], Learner]
    config_class: type
    urb: str  # URB's algorithm (its config/algo_config folder) whose configs this one reads


_LEARNERS: dict[str, tuple[Callable[[Any, RoutingEnv], Learner], type]] = {
    "iql": (iql.make_learner, IQLConfig),
    "ippo": (ippo.make_learner, PPOConfig),
    "mappo": (mappo.make_learner, PPOConfig),
    "qmix": (qmix.make_learner, MixerConfig),
    "vdn": (vdn.make_learner, MixerConfig),
    "iql_star": (iql_star.make_learner, IQLStarConfig),
    "ippo_star": (ippo_star.make_learner, IPPOStarConfig),
}
# The ids and their URB names are urb_jax.core.choices.ALGORITHM_URB_NAMES (the CLI's --alg choices,
# read without importing JAX), as is URB_ALIASES, URB's names accepted as --alg.
ALGORITHMS: dict[str, Algorithm] = {name: Algorithm(*_LEARNERS[name], urb)
                                    for name, urb in ALGORITHM_URB_NAMES.items()}


def canonical(name: str) -> str:
    """The urb-jax id of `name` (an id, or URB's name where it is unambiguous: `iql_torchrl` -> iql)."""
    if name in ALGORITHMS:
        return name
    if name in URB_ALIASES:
        return URB_ALIASES[name]
    raise ConfigError(f"unknown algorithm '{name}'. Fix: use one of {', '.join(ALGORITHMS)} "
                      f"(or URB's {', '.join(URB_ALIASES)}).")


def algorithm(name: str) -> Algorithm:
    return ALGORITHMS[canonical(name)]


def urb_algorithm(name: str) -> str:
    """URB's name of urb-jax algorithm `name`: its folder of config/algo_config and what
    exp_config.json's `algorithm` says, so URB's tools group and link our runs right."""
    return algorithm(name).urb


def load_algo_config(name: str, config: str = "config1", overrides: Sequence[Override] = ()) -> Any:
    """configs/algo/<name>/<config>.json (or a path) -> the algorithm's typed config."""
    return load_algo(name, config, overrides).config


def load_algo(name: str, config: str = "config1", overrides: Sequence[Override] = ()) -> Loaded[Any]:
    """The algorithm's typed config from our file or URB's (URB's key names; `overrides`: its
    --set items), with its resolution."""
    name = canonical(name)
    alg = ALGORITHMS[name]
    path = find_config("algo", config, subdir=name)
    check_urb_folder(path, name)
    return load_resolved(alg.config_class, path, ALGO_FAMILIES[alg.urb], overrides)


def for_urb(urb_name: str) -> str:
    """The urb-jax algorithm that reads URB algorithm `urb_name`'s configs (a ConfigError naming
    the URB feature for one urb-jax lacks)."""
    algo_family(urb_name)  # refuses URB algorithms we do not implement, by name
    ours = [name for name, alg in ALGORITHMS.items() if alg.urb == urb_name]
    if not ours:
        raise ConfigError(f"URB's '{urb_name}' configs are baseline configs: `urb-jax baseline --alg-conf` "
                          "reads them, not `urb-jax train`.")
    return ours[0]


def load_urb_algo(path: str | Path) -> Loaded[Any]:
    """A file of URB's config/algo_config/<URB algorithm>/, read by the urb-jax algorithm that runs
    that URB algorithm (or refused, naming the URB algorithm urb-jax lacks)."""
    folder = Path(path).resolve().parent.name
    if folder == "baseline":
        return load_baseline_config(str(path))
    try:
        name = for_urb(folder)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return load_algo(name, str(path))


def load_baseline_config(config: str, overrides: Sequence[Override] = ()) -> Loaded[BaselineConfig]:
    """URB's baseline algo config (config/algo_config/baseline/<name>.json, by path)."""
    path = find_config("algo", config, subdir="baseline")
    if path.resolve().parent.parent.name == "algo_config" and path.resolve().parent.name != "baseline":
        raise ConfigError(f"{path}: a config of URB's '{path.resolve().parent.name}', not of its "
                          "baselines (config/algo_config/baseline).")
    return load_resolved(BaselineConfig, path, ALGO_FAMILIES["baseline"], overrides)


def check_urb_folder(path: Path, name: str) -> None:
    """A file in URB's layout (config/algo_config/<URB algorithm>/) must be one of `name`'s URB
    algorithm: URB's bandit `iql` is our iql_star, its `iql_torchrl` our iql (docs/algorithms.md)."""
    if path.resolve().parent.parent.name != "algo_config":
        return
    folder, expected = path.resolve().parent.name, algorithm(name).urb
    if folder == expected:
        return
    try:
        ours = for_urb(folder)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    raise ConfigError(f"{path}: a config of URB's '{folder}', which urb-jax runs as --alg {ours}; "
                      f"--alg {name} reads URB's '{expected}' configs. Fix: pass --alg {ours}.")
