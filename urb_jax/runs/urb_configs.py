"""URB's config files in a run: which keys were given in URB's names and what they set.

A train run writes `config_aliases` into exp_config.json (task, env and algorithm config: each
file's URB aliases as given and as resolved, and the URB keys accepted without effect), so a run
started from URB's own files says exactly how urb-jax read them; and `overrides`, its `--set`
items as given and the typed value each set (`run_overrides`, `override_record`). `load_urb_file`
reads any file of URB's config/ folders as urb-jax would (tests and benchmarks/urb_configs.py).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from urb_jax.algorithms.registry import load_algo, load_urb_algo
from urb_jax.core.choices import TRAIN_SECTIONS
from urb_jax.core.configio import Loaded, Override, in_section, parse_overrides
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import load_env, load_task
from urb_jax.runs.request import TrainRequest
from urb_jax.training.hybrid.plan import load_hybrid

CONFIG_ALIASES_KEY = "config_aliases"
OVERRIDES_KEY = "overrides"


def run_overrides(given: Sequence[str], sections: tuple[str, ...] = TRAIN_SECTIONS) -> tuple[Override, ...]:
    """A run's --set items, as given, parsed."""
    return parse_overrides(given, sections)


def train_configs(req: TrainRequest) -> dict[str, Loaded[Any]]:
    """The task, env and algorithm configs of a train run, each with its --set items."""
    ov = run_overrides(req.overrides)
    return {"task": load_task(req.task_conf, in_section(ov, "task")),
            "env": load_env(req.env_conf, in_section(ov, "env")),
            "alg": load_algo(req.alg, req.alg_conf, in_section(ov, "alg"))}


def override_record(given: Sequence[str], loaded: Mapping[str, Loaded[Any]]) -> dict[str, Any]:
    """exp_config.json's `overrides`: the --set items as given, and per config the field each set
    with its typed value (URB's key names resolved)."""
    return {"given": list(given),
            "resolved": {kind: dict(lo.overridden) for kind, lo in loaded.items() if lo.overridden}}


def train_override_record(req: TrainRequest) -> dict[str, Any]:
    """`override_record` of a train run (task, env, algorithm and hybrid configs)."""
    loaded = {**train_configs(req), "hybrid": load_hybrid(req.hybrid_conf,
                                                          in_section(run_overrides(req.overrides), "hybrid"))}
    return override_record(req.overrides, loaded)


def config_aliases(req: TrainRequest) -> dict[str, Any]:
    """exp_config.json's `config_aliases`: per config, the file, URB's family, the aliases applied
    (URB key -> urb-jax key), the URB values given under them, and the keys ignored or derived."""
    return {kind: loaded.resolution.record() for kind, loaded in train_configs(req).items()}


def load_urb_file(path: str | Path) -> Loaded[Any]:
    """A file of URB's config/{algo_config/<alg>,env_config,task_config}/ as urb-jax reads it
    (a ConfigError naming the file and what urb-jax lacks when it refuses it)."""
    path = Path(path)
    if path.parent.name == "env_config":
        return load_env(str(path))
    if path.parent.name == "task_config":
        return load_task(str(path))
    if path.parent.parent.name == "algo_config":
        return load_urb_algo(path)
    raise ConfigError(f"{path}: not in URB's config layout (config/algo_config/<algorithm>/, "
                      "config/env_config/ or config/task_config/).")
