"""Task and env configs (URB_REFERENCE §5, §11) as typed frozen dataclasses.

URB's keys are accepted as URB spells them (`urb_jax.core.urb_keys`: ENV_FAMILY, TASK_FAMILY); our
extensions (paper HLM terms, the RouteRL-literal switch, demand scaling, baseline training days)
have defaults that reproduce the paper's setting. Unknown keys and wrong types are errors naming the
file and key (`urb_jax.core.configio`); URB features we lack are refused by name.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from urb_jax.city.network import DAY_LIMIT_S
from urb_jax.city.routes import RouteParams
from urb_jax.core.choices import ALGORITHM_URB_NAMES, URB_ALIASES
from urb_jax.core.configio import Loaded, Override, find_config, from_dict, load_resolved
from urb_jax.core.errors import ConfigError
from urb_jax.core.ranges import DAYS, FRACTION, Range, above, between, check_ranges
from urb_jax.core.urb_keys import ENV_FAMILY, TASK_FAMILY
from urb_jax.game.demand import DayDemand, DepartureJitter
from urb_jax.game.humans import HumanParams
from urb_jax.game.observations import OBSERVATION_TYPES
from urb_jax.game.rewards import CREDITS, behaviour_coefficients

DEMAND_MODES = ("auto", "sample", "duplicate")
# URB's observation types (RouteRL routerl/environment/observations.py) urb-jax lacks, by feature.
_ETA = "URB's ETA observations (recent travel times of earlier same-OD agents, per route)"
_LIVE = "URB's live SUMO observations (per-route congestion read from the running simulation)"
_DETECTOR = "URB's detector observations (toy-network detector counts)"
MISSING_OBSERVATIONS = {
    "trip_info_eta": _ETA, "trip_info_eta_mask_norm": _ETA, "trip_info_eta_route_congestion": _LIVE,
    "route_congestion": _LIVE, "trip_info_eta_sumo": _LIVE,
    "previous_agents_plus_start_time_detector_data": _DETECTOR,
}


FLEET_SHARE_TOLERANCE = 1e-9  # the fleets' shares must add up to ratio_machines within this


@dataclass(frozen=True)
class FleetConfig:
    """One CAV fleet of a task with several (`TaskConfig.fleets`): its share of all drivers, its
    behaviour (its rewards' T_CAV term is its own fleet's mean) and its learner (an algorithm id
    and that algorithm's config id or path)."""

    name: str
    share: float
    alg: str
    av_behavior: str | tuple[float, ...] = "selfish"
    alg_conf: str = "config1"

    RANGES: ClassVar[dict[str, Range]] = {
        "share": above(0, 1, "a share of all drivers; the fleets' shares add up to ratio_machines"),
        "av_behavior": between(-1000, 1000, "reward weights"),
    }

    def __post_init__(self) -> None:
        if isinstance(self.av_behavior, list):
            object.__setattr__(self, "av_behavior", tuple(float(v) for v in self.av_behavior))
        check_ranges(self)
        if not self.name or not self.name.replace("_", "").isalnum():
            raise ConfigError(f"key 'name' = {self.name!r}. Fix: a fleet's name is letters, digits and _ "
                              "(it names its metric columns).")
        alg = URB_ALIASES.get(self.alg, self.alg)
        if alg not in ALGORITHM_URB_NAMES:
            raise ConfigError(f"key 'alg' = {self.alg!r} is no algorithm. Fix: use one of "
                              f"{', '.join(ALGORITHM_URB_NAMES)}.")
        object.__setattr__(self, "alg", alg)
        behaviour_coefficients(self.av_behavior)  # validates name / 4-tuple

    @property
    def reward_coefficients(self) -> tuple[float, float, float, float]:
        return behaviour_coefficients(self.av_behavior)


def _fleets(value: Any) -> tuple[FleetConfig, ...]:
    """The task's `fleets` list as FleetConfigs (each entry a dict of FleetConfig's keys)."""
    fleets = []
    for i, entry in enumerate(value):
        if isinstance(entry, FleetConfig):
            fleets.append(entry)
        elif isinstance(entry, dict):
            fleets.append(from_dict(FleetConfig, entry, f"key 'fleets' entry {i}"))
        else:
            raise ConfigError(f"key 'fleets' entry {i} is {entry!r}. Fix: each fleet is an object with keys "
                              "name, share, alg and optionally av_behavior, alg_conf.")
    return tuple(fleets)


@dataclass(frozen=True)
class TaskConfig:
    """What is simulated: CAV share, phases, CAV behaviour, human model, demand."""

    ratio_machines: float = 0.4
    human_learning_episodes: int = 200
    test_eps: int = 100
    should_humans_adapt: bool = False
    av_behavior: str | tuple[float, ...] = "selfish"
    human_model: str = "gawron"
    human_alpha: float = 0.2
    human_beta: float = -1.5
    human_beta_randomness: float = 0.1
    human_deterministic: bool = True
    # Extensions (defaults = the paper's HLM / URB's setting).
    gamma_c: float = 0.0
    gamma_u: float = 0.0
    epsilon: float = 0.0
    delta: float = 0.0
    routerl_literal: bool = False
    demand_scale: float = 1.0
    demand_mode: str = "auto"  # auto: sample when < 1, duplicate when > 1
    demand_jitter_s: int = 60  # +- seconds of jitter for added/duplicated departures
    training_eps: int = 200  # CAV training days for baselines (URB baseline algo config1)
    # "marginal": each CAV is paid its marginal effect on the behaviour's groups, from the calibrated
    # surrogate's derivative (game.rewards.credit_rewards; hybrid and surrogate modes). "group": URB.
    reward_credit: str = "group"
    # URB's marginal-cost tasks (config_marginal_*: marginal_cost_coefficient_beta): each CAV also pays
    # beta x the delay it adds to everyone else (game.rewards.marginal_cost_rewards); 0: none
    marginal_cost_beta: float = 0.0
    # Demand that varies day to day (game.demand): each driver travels on a given day after mutation
    # with this probability, drawn anew each day from the env seed; 1: URB's fixed demand
    day_participation: float = 1.0
    # Departure times that vary day to day (game.demand.DepartureJitter): after mutation each driver
    # leaves at its scheduled second plus a uniform offset in [-J, J] s, drawn anew each day from the
    # env seed; 0: URB's fixed departures
    day_departure_jitter_s: int = 0
    # Competing CAV fleets (game.mutation.split_fleets; docs/experiment.md, "Competing CAV fleets"):
    # two or more FleetConfigs whose shares add up to ratio_machines, each with its own behaviour and
    # learner; empty: one fleet, the task's av_behavior and the run's --alg (URB)
    fleets: tuple[Any, ...] = ()

    RANGES: ClassVar[dict[str, Range]] = {
        "ratio_machines": FRACTION, "human_learning_episodes": between(0, DAYS), "test_eps": between(0, DAYS),
        "training_eps": between(0, DAYS), "av_behavior": between(-1000, 1000, "reward weights"),
        "human_alpha": between(0, 100, "gawron, weighted: a share in [0, 1]; culo: a step"),
        "human_beta": between(-100, 100, "URB: -1.5"), "human_beta_randomness": between(0, 100),
        "gamma_c": between(0, 10, "relative"), "gamma_u": between(0, 10, "relative"),
        "epsilon": between(0, 10, "relative noise"), "delta": FRACTION,
        "demand_scale": above(0, 100, "agents x demand_scale vehicles a day; URB's tasks: 0.5 to 2"),
        "demand_jitter_s": between(0, DAY_LIMIT_S),
        "marginal_cost_beta": between(0, 1000, "URB: 0 to 5"),
        "day_participation": above(0, 1, "a driver's chance to travel on a day; 1: URB's fixed demand"),
        "day_departure_jitter_s": between(0, 3600, "+- seconds around each scheduled departure; 0: URB's"),
    }

    def __post_init__(self) -> None:
        if isinstance(self.av_behavior, list):
            object.__setattr__(self, "av_behavior", tuple(float(v) for v in self.av_behavior))
        check_ranges(self)
        if self.demand_mode not in DEMAND_MODES:
            raise ConfigError(f"key 'demand_mode' must be one of {DEMAND_MODES}, got {self.demand_mode!r}.")
        if self.reward_credit not in CREDITS:
            raise ConfigError(f"key 'reward_credit' must be one of {CREDITS}, got {self.reward_credit!r}.")
        behaviour_coefficients(self.av_behavior)  # validates name / 4-tuple
        self.human_params()  # validates the human model
        object.__setattr__(self, "fleets", _fleets(self.fleets))
        if self.fleets:
            self._check_fleets()

    def _check_fleets(self) -> None:
        """Fleets: at least two, distinct names, shares that add up to ratio_machines, and none of
        the options a fleet's learner cannot honour."""
        if len(self.fleets) < 2:
            raise ConfigError("key 'fleets' declares one fleet. Fix: one fleet is the task itself "
                              "(ratio_machines, av_behavior and the run's --alg); declare two or more, or "
                              "remove 'fleets'.")
        names = [f.name for f in self.fleets]
        if len(set(names)) < len(names):
            raise ConfigError(f"key 'fleets' names {names}. Fix: give each fleet its own name.")
        total = sum(f.share for f in self.fleets)
        if abs(total - self.ratio_machines) > FLEET_SHARE_TOLERANCE:
            raise ConfigError(f"key 'fleets': the shares add up to {total:g}, ratio_machines is "
                              f"{self.ratio_machines:g}. Fix: make the shares add up to ratio_machines "
                              "(at most 1).")
        refused = {"reward_credit": self.reward_credit != "group",
                   "marginal_cost_beta": self.marginal_cost_beta != 0, "day_participation": self.varies_daily}
        for key, on in refused.items():
            if on:
                raise ConfigError(f"key 'fleets' with key '{key}' = {getattr(self, key)!r}: fleets support "
                                  f"URB's group rewards and fixed demand only. Fix: remove '{key}' or "
                                  "'fleets'.")

    @property
    def fleet_shares(self) -> tuple[float, ...]:
        """Each fleet's share of all drivers (empty: one fleet, no `fleets`)."""
        return tuple(f.share for f in self.fleets)

    @property
    def surrogate_reward_keys(self) -> list[str]:
        """The keys whose rewards need the calibrated surrogate's derivative (none: URB's rewards)."""
        return [key for key, on in (("reward_credit", self.reward_credit == "marginal"),
                                    ("marginal_cost_beta", self.marginal_cost_beta != 0.0)) if on]

    @property
    def varies_daily(self) -> bool:
        """Demand varies day to day (`day_participation` < 1)."""
        return self.day_participation < 1.0

    def day_demand(self, env_seed: int) -> DayDemand | None:
        """Who travels each day after mutation under env seed `env_seed` (None: everyone, URB)."""
        return DayDemand(int(env_seed), self.day_participation) if self.varies_daily else None

    @property
    def jitters_departures(self) -> bool:
        """Departures vary day to day (`day_departure_jitter_s` > 0)."""
        return self.day_departure_jitter_s > 0

    def departure_jitter(self, env_seed: int) -> DepartureJitter | None:
        """When drivers leave each day after mutation under env seed `env_seed` (None: as scheduled, URB)."""
        if not self.jitters_departures:
            return None
        return DepartureJitter(int(env_seed), int(self.day_departure_jitter_s))

    @property
    def reward_coefficients(self) -> tuple[float, float, float, float]:
        return behaviour_coefficients(self.av_behavior)

    def human_params(self) -> HumanParams:
        return HumanParams(
            model=self.human_model, alpha=self.human_alpha, beta=self.human_beta,
            beta_randomness=self.human_beta_randomness, deterministic=self.human_deterministic,
            gamma_c=self.gamma_c, gamma_u=self.gamma_u, epsilon=self.epsilon, delta=self.delta,
            routerl_literal=self.routerl_literal,
        )


@dataclass(frozen=True)
class EnvConfig:
    """How the environment is built: observations, route generation, logging cadence."""

    observations: str = "previous_agents_plus_start_time"
    number_of_paths: int = 4
    path_gen_beta: float = -5.0
    num_samples: int = 10
    path_gen_workers: int = 3  # accepted for URB compatibility; we use min(cores, 4)
    save_every: int = 1  # we record every day; kept for URB compatibility
    smooth_by: int = 50  # plot smoothing window (days)
    plot_choices: str = "none"  # accepted, unused
    plot_every: int = 50  # accepted, unused
    use_clustered_routes: bool = False

    RANGES: ClassVar[dict[str, Range]] = {
        "number_of_paths": between(1, 64, "URB: 4"), "path_gen_beta": between(-1000, 1000, "URB: -5"),
        "num_samples": between(1, 100_000), "path_gen_workers": between(1, 1024),
        "save_every": between(1, DAYS), "smooth_by": between(-1, DAYS, "URB: -1, no smoothing"),
        "plot_every": between(1, DAYS),
    }

    def __post_init__(self) -> None:
        check_ranges(self)
        if self.observations in MISSING_OBSERVATIONS:
            raise ConfigError(
                f"key 'observations' = {self.observations!r}: {MISSING_OBSERVATIONS[self.observations]}, "
                f"which urb-jax does not implement (it has {', '.join(OBSERVATION_TYPES)}).")
        if self.observations not in OBSERVATION_TYPES:
            raise ConfigError(f"key 'observations' = {self.observations!r} is no observation type of URB's "
                              f"or urb-jax's. Fix: use one of {', '.join(OBSERVATION_TYPES)}.")
        if self.use_clustered_routes:
            raise ConfigError(
                "key 'use_clustered_routes' = true: URB's clustered route sets (pre-generated per network "
                "under networks/<net>/clustered_routes, read by URB's scripts/*_clusters.py), which urb-jax "
                "does not implement (its routes are JanuX's sampler, docs/networks.md).")

    def route_params(self) -> RouteParams:
        return RouteParams(number_of_paths=self.number_of_paths, beta=self.path_gen_beta,
                           num_samples=self.num_samples)


@dataclass(frozen=True)
class ExperimentConfig:
    """The merged view written to exp_config.json."""

    task: TaskConfig
    env: EnvConfig
    task_source: str = ""
    env_source: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


def load_task_config(name_or_path: str, overrides: Sequence[Override] = ()) -> tuple[TaskConfig, Path]:
    loaded = load_task(name_or_path, overrides)
    return loaded.config, loaded.path


def load_env_config(name_or_path: str, overrides: Sequence[Override] = ()) -> tuple[EnvConfig, Path]:
    loaded = load_env(name_or_path, overrides)
    return loaded.config, loaded.path


def load_task(name_or_path: str, overrides: Sequence[Override] = ()) -> Loaded[TaskConfig]:
    """A task config by id or path, in urb-jax's or URB's key names (`overrides`: its --set
    items), with its resolution."""
    return load_resolved(TaskConfig, find_config("task", name_or_path), TASK_FAMILY, overrides)


def load_env(name_or_path: str, overrides: Sequence[Override] = ()) -> Loaded[EnvConfig]:
    """An env config by id or path, in urb-jax's or URB's key names (`overrides`: its --set
    items), with its resolution."""
    return load_resolved(EnvConfig, find_config("env", name_or_path), ENV_FAMILY, overrides)


def task_from_dict(data: dict[str, Any], source: str = "<dict>") -> TaskConfig:
    return from_dict(TaskConfig, data, source)
