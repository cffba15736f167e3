"""URB's config key names, mapped onto urb-jax's: the one table and the one resolver.

URB's scripts merge the algo, env and task JSON files into script globals
(`globals()[key] = value` in URB's scripts/*.py), so a URB config is a bag of names that one
script reads. urb-jax reads the same files into typed configs whose fields sometimes carry other
names. A file is therefore read in the dialect of one URB config family (a folder of URB's
`config/`): its aliases are renamed, keys that cannot change a result are dropped, keys of URB
features urb-jax lacks are refused, and what was done is recorded (`Resolution`), so a run can
write both what it was given and what it used. URB sources are cited as COeXISTENCE-PROJECT/URB
at commit 321d15c (docs/experiment.md, "URB's configs as written").
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from urb_jax.core.errors import ConfigError


def _layers(data: Mapping[str, Any]) -> int | None:
    """URB's `num_hidden` for the `widths` given (scripts/iql.py, Network asserts
    len(widths) == num_hidden + 1); None when no widths are given."""
    widths = data.get("widths")
    return len(widths) - 1 if isinstance(widths, list | tuple) else None


@dataclass(frozen=True)
class Derived:
    """A URB key whose value follows from other keys: accepted when it agrees, refused if not."""

    rule: str  # how URB derives it, for the error
    value: Callable[[Mapping[str, Any]], Any]  # the value it must have (None: nothing to check)


@dataclass(frozen=True)
class Family:
    """How one URB config family (a folder of URB's config/) maps onto one urb-jax config class."""

    name: str  # URB's folder, e.g. "iql_torchrl", "task_config"
    script: str  # URB's file that reads these keys, for errors and docs
    aliases: Mapping[str, str] = field(default_factory=dict)  # URB key -> urb-jax field
    ignored: Mapping[str, str] = field(default_factory=dict)  # URB key -> why it changes nothing
    refused: Mapping[str, str] = field(default_factory=dict)  # URB key -> URB feature urb-jax lacks
    derived: Mapping[str, Derived] = field(default_factory=dict)
    # Keys URB's script reads with no default (a NameError in URB without them); checked only in
    # files written with URB's names (any alias present), so our own configs keep their defaults.
    required: tuple[str, ...] = ()


@dataclass(frozen=True)
class Resolution:
    """What one config file gave and what urb-jax made of it (exp_config.json `config_aliases`)."""

    source: str
    family: str
    aliases: dict[str, str]  # URB key given -> urb-jax key it set
    given: dict[str, Any]  # URB key given -> its value, for every alias, ignored or derived key
    ignored: dict[str, str]  # URB key given -> why it changes nothing
    derived: dict[str, str]  # URB key given -> the rule it was checked against

    def record(self) -> dict[str, Any]:
        return {"file": self.source, "urb_family": self.family, "aliases": self.aliases,
                "given": self.given, "ignored": self.ignored, "derived": self.derived}


def resolve(data: Mapping[str, Any], family: Family | None, source: str) -> tuple[dict[str, Any], Resolution]:
    """`data` in urb-jax's names (URB aliases renamed, ignored and derived keys dropped) and the
    record of it. Refused keys, two keys meaning one field with different values, a derived key
    that disagrees, and a URB file missing a key URB's script needs are ConfigErrors naming
    `source` and the key; unknown keys are left for `configio.from_dict` to refuse."""
    if family is None:
        return dict(data), Resolution(source, "urb-jax", {}, {}, {}, {})
    _refuse(data, family, source)
    out, aliases = _rename(data, family, source)
    ignored = {k: family.ignored[k] for k in data if k in family.ignored}
    derived = {k: family.derived[k].rule for k in data if k in family.derived}
    for key in (*ignored, *derived):
        out.pop(key, None)
    _check_derived(data, out, family, source)
    if aliases:
        _check_required(data, family, source)
    given = {k: data[k] for k in (*aliases, *ignored, *derived)}
    return out, Resolution(source, family.name, aliases, given, ignored, derived)


def _refuse(data: Mapping[str, Any], family: Family, source: str) -> None:
    by_feature: dict[str, list[str]] = {}
    for key in data:
        if key in family.refused:
            by_feature.setdefault(family.refused[key], []).append(f"'{key}' = {data[key]!r}")
    if by_feature:
        why = "; ".join(f"key(s) {_some(keys)}: {feature}" for feature, keys in by_feature.items())
        raise ConfigError(f"{source}: {why}. urb-jax does not implement this URB feature, so it will "
                          "not run this config (docs/experiment.md, \"URB's configs as written\").")


def _some(keys: list[str], shown: int = 3) -> str:
    more = f" and {len(keys) - shown} more" if len(keys) > shown else ""
    return ", ".join(keys[:shown]) + more


def _rename(data: Mapping[str, Any], family: Family, source: str) -> tuple[dict[str, Any], dict[str, str]]:
    """URB's names -> ours; two given keys that set one field must agree."""
    out: dict[str, Any] = {}
    origin: dict[str, str] = {}
    aliases: dict[str, str] = {}
    for key, value in data.items():
        target = family.aliases.get(key, key)
        if target in out and out[target] != value:
            raise ConfigError(
                f"{source}: keys '{origin[target]}' = {out[target]!r} and '{key}' = {value!r} both set "
                f"urb-jax's '{target}', which has one value for both. Fix: give them the same value.")
        out[target], origin[target] = value, key
        if target != key:
            aliases[key] = target
    return out, aliases


def _check_derived(data: Mapping[str, Any], resolved: Mapping[str, Any], family: Family, source: str) -> None:
    for key, rule in family.derived.items():
        if key not in data:
            continue
        expected = rule.value(resolved)
        if expected is not None and data[key] != expected:
            raise ConfigError(f"{source}: key '{key}' = {data[key]!r} disagrees with {rule.rule} "
                              f"(= {expected!r}); URB's {family.script} stops on it too. "
                              "Fix: make them agree.")


def _check_required(data: Mapping[str, Any], family: Family, source: str) -> None:
    missing = [k for k in family.required if k not in data and family.aliases.get(k, k) not in data]
    if missing:
        keys = ", ".join(f"'{k}'" for k in missing)
        raise ConfigError(f"{source}: missing key(s) {keys}, which URB's {family.script} reads with no "
                          "default (URB stops with a NameError), so urb-jax will not guess them. "
                          "Fix: add them to the file.")


# --- The table (docs/experiment.md, "URB's configs as written", lists it with its reasons). ---

_TORCHRL_COMMON = ("agent_frames_per_batch", "n_iters", "num_epochs", "minibatch_size", "lr",
                   "max_grad_norm", "gamma", "od_embedding_dim", "share_params_agent")
_POLICY_NET = {"policy_network_depth": "mlp_depth", "policy_network_num_cells": "mlp_cells",
               "share_params_agent": "shared_parameters"}
_PPO = {**_POLICY_NET, "critic_network_depth": "critic_depth",
        "critic_network_num_cells": "critic_cells", "share_params_critic": "shared_parameters"}
_PPO_KEYS = (*_TORCHRL_COMMON, "clip_epsilon", "lmbda", "entropy_eps", "normalize_advantage",
             "policy_network_depth", "policy_network_num_cells", "critic_network_depth",
             "critic_network_num_cells", "share_params_critic")
_MIXER = {"eps_greedy_init": "eps_init", "eps_greedy_end": "eps_end",
          "share_params_agent": "shared_parameters"}
_MIXER_KEYS = (*_TORCHRL_COMMON, "memory_size", "tau", "mlp_depth", "mlp_cells", "eps_greedy_init",
               "eps_greedy_end", "mixing_embed_dim", "exploration_fraction")
_NUM_HIDDEN = {"num_hidden": Derived("len(widths) - 1", _layers)}
_BANDIT = {"training_eps": "num_episodes"}

ALGO_FAMILIES: dict[str, Family] = {
    "iql_torchrl": Family(
        "iql_torchrl", "scripts/iql_torchrl.py", aliases={**_POLICY_NET, "eps": "target_eps"},
        ignored={"tau": "read by no line of scripts/iql_torchrl.py (its target update is "
                        "SoftUpdate(loss_module, eps=eps))"},
        required=(*_TORCHRL_COMMON, "memory_size", "eps", "eps_init", "eps_end", "exploration_fraction",
                  "policy_network_depth", "policy_network_num_cells")),
    "ippo_torchrl": Family("ippo_torchrl", "scripts/ippo_torchrl.py", aliases=_PPO, required=_PPO_KEYS),
    "mappo_torchrl": Family("mappo_torchrl", "scripts/mappo_torchrl.py", aliases=_PPO, required=_PPO_KEYS),
    "qmix_torchrl": Family("qmix_torchrl", "scripts/qmix_torchrl.py", aliases=_MIXER, required=_MIXER_KEYS),
    "vdn_torchrl": Family("vdn_torchrl", "scripts/vdn_torchrl.py", aliases=_MIXER, required=_MIXER_KEYS),
    "iql": Family("iql", "scripts/iql.py", aliases=_BANDIT, derived=_NUM_HIDDEN,
                  required=("training_eps", "eps_init", "eps_decay", "eps_min", "buffer_size", "batch_size",
                            "lr", "num_epochs", "num_hidden", "widths", "update_every")),
    "ippo": Family("ippo", "scripts/ippo.py", aliases=_BANDIT, derived=_NUM_HIDDEN,
                   required=("training_eps", "batch_size", "update_every", "lr", "num_epochs", "num_hidden",
                             "widths", "clip_eps", "normalize_advantage", "entropy_coef")),
    "baseline": Family("baseline", "scripts/baselines.py", required=("training_eps",)),
}

# URB algorithms (folders of config/algo_config) urb-jax does not implement, and what they are.
UNIMPLEMENTED_ALGORITHMS: dict[str, str] = {
    "greedy": "URB's centralised greedy baseline (scripts/greedy.py)",
    "centralized": "URB's centralised recurrent PPO controller (scripts/centralized_controller.py)",
    "centralized_dqn": "URB's centralised DQN controller (scripts/centralized_dqn.py)",
    "feudal_hrl": "URB's feudal hierarchical RL over route clusters (scripts/feudal_hrl.py)",
    "hyp_ippo": "URB's hypernetwork IPPO (scripts/hyp_ippo.py)",
    "pact1": "PACT-1 (config/algo_config/pact1; URB ships no script that reads it)",
    "iql_tabular": "URB's tabular IQL (scripts/iql_tabular.py)",
    "reinforce_tabular": "URB's tabular REINFORCE (scripts/reinforce_tabular.py)",
}

_ASSIGNMENT = "URB's assignment-sampling experiments (scripts/asgn_simulations.py)"
_ASSIGNMENT_KEYS = (
    "greedy_num_samples", "greedy_num_candidates", "num_tasks_greedy", "random_num_samples",
    "num_tasks_random", "balanced_num_samples", "num_tasks_balanced", "dirichlet_num_samples",
    "dirichlet_alpha", "num_tasks_dirichlet", "grid_num_samples", "num_tasks_grid", "hex_num_samples",
    "num_tasks_hex", "save_data_every", "save_joint_actions_every")

TASK_FAMILY = Family(
    "task_config", "scripts/*.py (task keys)",
    aliases={"marginal_cost_coefficient_beta": "marginal_cost_beta"},  # the config_marginal_* tasks
    refused=dict.fromkeys(_ASSIGNMENT_KEYS, _ASSIGNMENT))

# `observation_type` is what URB's *_clusters scripts read first, falling back to `observations`
# (e.g. scripts/mappo_clusters.py: params.get("observation_type", params.get("observations", ...))).
ENV_FAMILY = Family("env_config", "scripts/*.py (env keys)", aliases={"observation_type": "observations"})


def algo_family(name: str) -> Family:
    """The URB algorithm family `name` (a folder of URB's config/algo_config)."""
    if name in UNIMPLEMENTED_ALGORITHMS:
        raise ConfigError(f"URB algorithm '{name}' is {UNIMPLEMENTED_ALGORITHMS[name]}, which urb-jax "
                          "does not implement.")
    if name not in ALGO_FAMILIES:
        raise ConfigError(f"'{name}' is not a URB algorithm urb-jax knows. Fix: use one of "
                          f"{', '.join(ALGO_FAMILIES)}.")
    return ALGO_FAMILIES[name]
