"""What a user asks for: one typed, frozen request per kind of run, built once (by a command, a
suite file or a script) and passed whole to the run, the dry run and the suite.

A train run records its request in exp_config.json (`TrainRequest.record`, "train_args") and
`--resume` rebuilds it from there (`TrainRequest.from_record`), so the run that continues is the
run that started. Only what the run computes from is recorded; where the results go, whether they
replace older ones and how progress shows are this invocation's business.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from urb_jax.core.choices import DEFAULT_NETWORK, EXECUTORS, MODES
from urb_jax.core.errors import ConfigError
from urb_jax.core.paths import absolute_dir


def repeated_seed(seeds: Sequence[int]) -> int | None:
    """The smallest seed listed more than once, if any (each seed is one results folder)."""
    return min((s for s in set(seeds) if list(seeds).count(s) > 1), default=None)


def _seeds(seeds: Sequence[int]) -> tuple[int, ...]:
    """Distinct integer seeds, at least one (each seed is one results folder)."""
    out = tuple(seeds)
    if not out or not all(isinstance(s, int) and not isinstance(s, bool) for s in out):
        raise ConfigError(f"seeds {list(out)}: a run needs one or more integer seeds. "
                          "Fix: e.g. --seeds 0,1,2.")
    if repeated_seed(out) is not None:
        raise ConfigError(f"seeds {list(out)}: a seed is given twice (each seed is one results folder). "
                          "Fix: list each seed once.")
    return out


def _resolved_config(config: str) -> str:
    """A config given as a file path, made absolute (a `--resume` from another folder finds it); a
    config id as it is."""
    path = Path(config).expanduser()
    return str(path.resolve()) if path.suffix == ".json" and path.is_file() else config


DEFAULT_ALG = "iql"


def default_alg(task_conf: str) -> str:
    """The algorithm a train run of task `task_conf` gets without --alg: the task's first fleet's
    (a task with fleets, docs/experiment.md "Competing CAV fleets"), else iql."""
    from urb_jax.game.config import load_task_config  # the task config imports JAX

    try:
        task, _ = load_task_config(task_conf)
    except ConfigError:  # the run's own loading says what is wrong, with the --set items
        return DEFAULT_ALG
    return task.fleets[0].alg if task.fleets else DEFAULT_ALG


@dataclass(frozen=True)
class TrainRequest:
    """`urb-jax train`: an RL algorithm's URB experiment, trained by the hybrid loop."""

    # urb-jax id or URB's name (`iql_torchrl`); "": iql, or a task with fleets' first fleet's (resolved)
    alg: str = ""
    net: str | None = None  # network name or folder; None: the embedded default
    task_conf: str = "config1"  # config ids, or .json paths
    alg_conf: str = "config1"
    env_conf: str = "config1"
    hybrid_conf: str = "default"
    env_seed: int = 42  # routes, humans, mutation, SUMO
    seeds: tuple[int, ...] = (0,)  # training seeds: one results folder each, trained together
    mode: str = "hybrid"
    train_days: int | None = None  # None: the hybrid config's
    exp_id: str | None = None  # None: <alg>_<mode>_<net>_<task>[_s<seed>]
    networks_dir: str | None = None
    human_phase_from: str | None = None  # an earlier run whose human phase this one reuses
    drop_unroutable: bool = False
    overrides: tuple[str, ...] = ()  # --set SECTION.KEY=VALUE items, as given
    executor: str = "pool"
    ray_address: str | None = None
    log: str | None = None  # "tensorboard": each round also to results/<id>/tensorboard/
    results_dir: str = "results"
    overwrite: bool = False
    progress: bool = True
    day_store: bool = True  # SUMO days through the shared day store (sumo_bridge.memo.day_store)

    def __post_init__(self) -> None:
        object.__setattr__(self, "seeds", _seeds(self.seeds))
        object.__setattr__(self, "overrides", tuple(self.overrides or ()))
        if self.mode not in MODES:
            raise ConfigError(f"mode {self.mode!r}. Fix: use one of {', '.join(MODES)}.")
        if self.executor not in EXECUTORS:
            raise ConfigError(f"executor {self.executor!r}. Fix: use one of {', '.join(EXECUTORS)}.")
        if self.train_days is not None and self.train_days < 1:
            raise ConfigError(f"--train-days {self.train_days}: a run needs at least one training day. "
                              "Fix: pass --train-days 1 or more (6000 is the paper's budget).")

    def resolved(self) -> TrainRequest:
        """The request as a run records it: URB's algorithm names as urb-jax ids, the default
        network named, config files and the networks folder as absolute paths."""
        from urb_jax.algorithms.registry import canonical  # the registry imports every learner

        return dataclasses.replace(
            self, alg=canonical(self.alg or default_alg(self.task_conf)), net=self.net or DEFAULT_NETWORK,
            task_conf=_resolved_config(self.task_conf), alg_conf=_resolved_config(self.alg_conf),
            env_conf=_resolved_config(self.env_conf), hybrid_conf=_resolved_config(self.hybrid_conf),
            networks_dir=absolute_dir(self.networks_dir))

    def record(self, seed: int) -> dict[str, Any]:
        """exp_config.json's "train_args" of the run's folder for `seed`."""
        return {"alg": self.alg, "net": self.net, "task_conf": self.task_conf, "alg_conf": self.alg_conf,
                "env_conf": self.env_conf, "hybrid_conf": self.hybrid_conf, "env_seed": self.env_seed,
                "mode": self.mode, "networks_dir": self.networks_dir, "train_days": self.train_days,
                "executor": self.executor, "ray_address": self.ray_address,
                "drop_unroutable": self.drop_unroutable, "overrides": list(self.overrides), "log": self.log,
                "exp_id": self.exp_id, "seed": seed}

    @classmethod
    def from_record(cls, train_args: Mapping[str, Any], seeds: Sequence[int], **now: Any) -> TrainRequest:
        """The request a run recorded (runs from before a key get its default), for `seeds`, with
        this invocation's `now` (results_dir, progress, ...)."""
        known = {f.name for f in dataclasses.fields(cls)} - {"seeds"}
        given = {k: v for k, v in train_args.items() if k in known and v is not None}
        return cls(**{**given, "seeds": tuple(seeds), **now})


@dataclass(frozen=True)
class ResumeRequest:
    """`urb-jax train --resume`: continue a recorded train run; what may differ from its start."""

    exp_id: str
    results_dir: str = "results"
    networks_dir: str | None = None  # where the network is now (default: where it was)
    executor: str | None = None  # None: the recorded one
    ray_address: str | None = None
    overrides: tuple[str, ...] = ()  # must be the recorded ones, if given
    log: str | None = None  # None: the recorded logger
    progress: bool = True
    day_store: bool = True  # SUMO days through the shared day store (not recorded: days are the same)

    def __post_init__(self) -> None:
        object.__setattr__(self, "overrides", tuple(self.overrides or ()))


@dataclass(frozen=True)
class BaselineRequest:
    """`urb-jax baseline`: URB's experiment with a fixed CAV policy, every day in SUMO."""

    model: str = "aon"  # aon, random or human (`algorithms.baselines`)
    net: str | None = None
    task_conf: str = "config1"
    env_conf: str = "config1"
    alg_conf: str | None = None  # URB's baseline algo config: its training_eps sets the CAV days
    env_seed: int = 42
    exp_id: str | None = None  # None: <model>_<net>_<task>_s<env seed>
    networks_dir: str | None = None
    human_phase_from: str | None = None  # replay this run's human days instead of simulating them
    drop_unroutable: bool = False
    overrides: tuple[str, ...] = ()  # --set items of the task, env and alg configs
    results_dir: str = "results"
    overwrite: bool = False
    progress: bool = True
    day_store: bool = True  # SUMO days through the shared day store (sumo_bridge.memo.day_store)

    def __post_init__(self) -> None:
        object.__setattr__(self, "overrides", tuple(self.overrides or ()))


# The fields a suite file may give each kind of run: the rest are the suite's own.
NOT_FROM_SUITE_FILES = frozenset({"exp_id", "results_dir", "progress", "overwrite", "day_store"})


def request_fields(cls: type[TrainRequest] | type[BaselineRequest]) -> frozenset[str]:
    """The names a suite file's run may set for a request of `cls`."""
    return frozenset(f.name for f in dataclasses.fields(cls)) - NOT_FROM_SUITE_FILES
