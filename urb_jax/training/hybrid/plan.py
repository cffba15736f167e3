"""The hybrid trainer's budget: its config, how many rounds of what size, and the learner fitted to it."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

from urb_jax.algorithms.configs import IPPOStarConfig, IQLConfig, IQLStarConfig, MixerConfig, PPOConfig
from urb_jax.algorithms.fleets import FleetsAlgoConfig, fleet_env, fleet_updates_per_iter, make_fleets_learner
from urb_jax.algorithms.learner import Learner
from urb_jax.algorithms.registry import algorithm
from urb_jax.core.configio import Loaded, Override, find_config, load_resolved
from urb_jax.core.errors import ConfigError
from urb_jax.core.ranges import DAYS, ENVS, STEPS, WORKERS, Range, above, between, check_ranges
from urb_jax.game.env import RoutingEnv
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.surrogate.calibrate import ROUTE_BIAS_PRIOR_DAYS
from urb_jax.surrogate.model import MODELS as SURROGATE_MODELS
from urb_jax.surrogate.model import SurrogateConfig

SEED_AXES = ("auto", "vmap", "map")  # how a group's seeds share one program (hybrid/fns.py)
# The config of any algorithm of urb_jax.algorithms.registry.ALGORITHMS.
AlgoConfig = IQLConfig | PPOConfig | MixerConfig | IQLStarConfig | IPPOStarConfig | FleetsAlgoConfig


@dataclass(frozen=True)
class HybridConfig:
    """Round sizes and budget (configs/hybrid/*.json)."""

    train_days: int = 1000  # URB-equivalent training days (surrogate env-days + SUMO days)
    num_envs: int = 16  # parallel surrogate envs (replaces the algorithm's num_envs)
    surrogate_days_per_round: int = 640  # surrogate env-days per round (rounded to whole iterations)
    sumo_days_per_round: int = 4  # P
    sumo_updates: int = 1  # updates on each round's SUMO days
    sumo_workers: int = 2
    calib_human_days: int = 50
    calib_varied_days: int = 8
    calib_steps: int = 600
    # Leading human days on the surrogate fitted to the varied calibration days (modes hybrid and
    # surrogate); the rest, at least the last 50 (t_pre's days), are SUMO days. 0: all in SUMO (URB).
    human_surrogate_days: int = 0
    refit_days: int = 32
    refit_steps: int = 150
    day_timeout_s: float = 600.0
    max_vmapped_seeds: int = 8  # seeds trained together in one program; longer seed lists train in groups
    # vmap, map (lax.map: one seed after another inside the program), or auto: map for a learner
    # above fns.MAP_SEEDS_PARAMS parameters, where vmap is 2-3x slower a seed (hybrid/fns.py)
    seed_axis: str = "auto"
    route_bias: bool = True  # correct the surrogate by SUMO's mean residual per (agent, route) driven
    route_bias_prior_days: float = ROUTE_BIAS_PRIOR_DAYS  # shrinkage: residual x count / (count + prior days)
    # the residual also counts the days a driver was removed as stuck, at the time the metrics charge
    # (surrogate.calibrate.route_bias); off: arrivals only. Matters where SUMO's days jam (gargenville)
    route_bias_removed: bool = False
    reuse_identical_test_days: bool = True  # SUMO is deterministic: a repeated test day runs once
    # Training days after which the round checkpoint is kept rather than replaced by the next one:
    # snapshots of the learning curve, each evaluable later on the run's SUMO test days (a day count
    # between rounds keeps the first round that reaches it; 0 keeps the start, the human phase's end).
    keep_checkpoints_at: tuple[int, ...] = ()
    # SUMO's emission device on every SUMO day (SumoConfig.emissions): records get co2_g and fuel_mg,
    # the metric files the emission totals (docs/metrics.md, "Emissions"). Off: a day costs ~10% less.
    emissions: bool = False
    # The surrogate the learners train on: "bpr" (time-dependent BPR) or "queue" (BPR plus
    # departure-ordered point queues with spill-back; docs/surrogate.md has both and their fidelity)
    surrogate_model: str = "bpr"

    RANGES: ClassVar[dict[str, Range]] = {
        "train_days": between(1, DAYS), "num_envs": between(1, ENVS),
        "surrogate_days_per_round": between(0, DAYS), "sumo_days_per_round": between(0, 100_000),
        "sumo_updates": between(0, 10_000), "sumo_workers": between(1, WORKERS),
        "calib_human_days": between(0, 100_000), "calib_varied_days": between(0, 100_000),
        "calib_steps": between(0, STEPS), "human_surrogate_days": between(0, DAYS),
        "refit_days": between(1, 100_000), "refit_steps": between(0, STEPS),
        "day_timeout_s": above(0, 7 * 86_400, "a week"), "max_vmapped_seeds": between(1, WORKERS),
        "route_bias_prior_days": between(0, DAYS), "keep_checkpoints_at": between(0, DAYS),
    }

    def __post_init__(self) -> None:
        """Budgets and round sizes that cannot run are refused before any SUMO day."""
        check_ranges(self)
        if self.surrogate_days_per_round + self.sumo_days_per_round < 1:
            raise ConfigError("keys 'surrogate_days_per_round' and 'sumo_days_per_round' are both 0: a round "
                              "would train on nothing. Fix: make one of them positive.")
        if self.surrogate_model not in SURROGATE_MODELS:
            raise ConfigError(f"key 'surrogate_model' is {self.surrogate_model!r}. Fix: use one of "
                              f"{', '.join(SURROGATE_MODELS)}.")
        if self.seed_axis not in SEED_AXES:
            raise ConfigError(f"key 'seed_axis' is {self.seed_axis!r}. Fix: use one of "
                              f"{', '.join(SEED_AXES)}.")

    @property
    def sumo_config(self) -> SumoConfig:
        """The SumoConfig this run's SUMO days run with (the day store keys on it)."""
        return SumoConfig(emissions=self.emissions)

    @property
    def surrogate_config(self) -> SurrogateConfig:
        """The structure of the surrogate this run trains on."""
        return SurrogateConfig(model=self.surrogate_model)

    @property
    def bias_prior(self) -> float | None:
        """The route-residual shrinkage where the surrogate corrects by it (`route_bias`), else None."""
        return self.route_bias_prior_days if self.route_bias else None


def load_hybrid_config(name: str = "default", overrides: Sequence[Override] = ()
                       ) -> tuple[HybridConfig, Path]:
    loaded = load_hybrid(name, overrides)
    return loaded.config, loaded.path


def load_hybrid(name: str = "default", overrides: Sequence[Override] = ()) -> Loaded[HybridConfig]:
    """configs/hybrid/<name>.json (or a path) with its --set items."""
    return load_resolved(HybridConfig, find_config("hybrid", name), None, overrides)


class RoundPlan(NamedTuple):
    """The rounds `train_days` buys: full rounds while they fit, then a last round of what is left.

    The paper trains exactly `train_days`, and a learner must never get more experience than the
    paper's, so the last round is cut short (fewer SUMO days, fewer or no surrogate iterations)
    rather than the budget rounded up to whole rounds. Rounds are counted from 0 here."""

    n_rounds: int
    iters: int  # learner iterations on the surrogate per full round
    surrogate_days: int  # surrogate env-days per full round
    sumo_days: int  # SUMO training days per full round (per seed)
    last_iters: int  # the last round's learner iterations (== iters when the budget divides)
    last_sumo_days: int  # the last round's SUMO days (== sumo_days when the budget divides)
    iter_days: int  # env-days one learner iteration collects (days_per_iter x num_envs); 0: mode sumo

    def iters_of(self, r: int) -> int:
        """Round r's learner iterations on the surrogate."""
        return self.last_iters if r == self.n_rounds - 1 else self.iters

    def sumo_days_of(self, r: int) -> int:
        """Round r's SUMO training days (per seed)."""
        return self.last_sumo_days if r == self.n_rounds - 1 else self.sumo_days

    def surrogate_days_of(self, r: int) -> int:
        """Round r's surrogate env-days."""
        return self.iters_of(r) * self.iter_days

    def days_through(self, r: int) -> int:
        """Training days (surrogate + SUMO) of the first r rounds: where round r starts."""
        full = min(r, self.n_rounds - 1)
        last = self.last_iters * self.iter_days + self.last_sumo_days if r >= self.n_rounds else 0
        return full * (self.surrogate_days + self.sumo_days) + last

    def sumo_days_through(self, r: int) -> int:
        """SUMO training days (per seed) of the first r rounds."""
        return min(r, self.n_rounds - 1) * self.sumo_days + (self.last_sumo_days if r >= self.n_rounds else 0)

    @property
    def total_iters(self) -> int:
        """Learner iterations on the surrogate over the whole training."""
        return (self.n_rounds - 1) * self.iters + self.last_iters

    @property
    def total_surrogate_days(self) -> int:
        return self.total_iters * self.iter_days

    @property
    def total_sumo_days(self) -> int:
        return self.sumo_days_through(self.n_rounds)

    @property
    def total_days(self) -> int:
        """The training days the run trains (surrogate env-days + SUMO days, per seed)."""
        return self.days_through(self.n_rounds)

    @property
    def is_whole(self) -> bool:
        """Every round is a full round (the budget is a whole number of rounds)."""
        return (self.last_iters, self.last_sumo_days) == (self.iters, self.sumo_days)


def iters_per_round(cfg: HybridConfig, days_per_iter: int, mode: str) -> int:
    """Learner iterations on the surrogate per round (each collects days_per_iter x num_envs days)."""
    if mode == "sumo":
        return 0
    return max(1, round(cfg.surrogate_days_per_round / (days_per_iter * cfg.num_envs)))


def plan_rounds(cfg: HybridConfig, mode: str, days_per_iter: int) -> RoundPlan:
    """Rounds of surrogate iterations and SUMO days that spend `train_days` and no more: full rounds
    while they fit, then a last round of min(SUMO days a round, what is left) SUMO days and as many
    whole iterations as fit in the rest. The total is `train_days` where an iteration's size lets
    it, else the largest total below it (short by less than one iteration)."""
    iters = iters_per_round(cfg, days_per_iter, mode)
    iter_days = days_per_iter * cfg.num_envs if iters else 0
    sur = iters * iter_days
    sumo = cfg.sumo_days_per_round if mode != "surrogate" else 0
    if sur + sumo == 0:
        raise ConfigError(f"mode {mode} with key 'sumo_days_per_round' 0: a round would train on nothing. "
                          "Fix: make sumo_days_per_round positive, or use --mode hybrid.")
    full, left = divmod(cfg.train_days, sur + sumo)
    last_sumo = min(sumo, left)
    last_iters = (left - last_sumo) // iter_days if iter_days else 0
    if last_iters or last_sumo:
        return RoundPlan(full + 1, iters, sur, sumo, last_iters, last_sumo, iter_days)
    if full == 0:
        raise ConfigError(f"train_days {cfg.train_days:,} buys no learner iteration (one collects "
                          f"{iter_days:,} days: {days_per_iter} days in each of {cfg.num_envs} envs) and no "
                          f"SUMO day. Fix: --train-days {iter_days} or more, or fewer num_envs.")
    return RoundPlan(full, iters, sur, sumo, iters, sumo, iter_days)


def whole_rounds(plan: RoundPlan, n_rounds: int) -> RoundPlan:
    """`plan`'s full rounds, `n_rounds` of them: the plan of a run checkpointed before the last round
    could be short (the budget was rounded up to whole rounds), which its resume keeps."""
    return plan._replace(n_rounds=n_rounds, last_iters=plan.iters, last_sumo_days=plan.sumo_days)


def kept_rounds(cfg: HybridConfig, plan: RoundPlan) -> frozenset[int]:
    """The rounds whose checkpoints `keep_checkpoints_at` keeps: the first to reach each day count."""
    return frozenset(min((r for r in range(plan.n_rounds + 1) if plan.days_through(r) >= d),
                         default=plan.n_rounds) for d in cfg.keep_checkpoints_at)


def learner_for(alg: str, alg_config: AlgoConfig, env: RoutingEnv, cfg: HybridConfig, plan: RoundPlan | None,
                mode: str) -> tuple[Learner, AlgoConfig]:
    """The algorithm's learner with num_envs and schedule lengths fitted to the hybrid budget:
    epsilon schedules (linear over n_iters, or IQL*'s per-update decay) end where URB's end, over the
    iterations and updates `plan` trains (its short last round included). `plan` None: one round
    of one iteration (the learner's size only, e.g. its days per iteration, before the plan)."""
    if isinstance(alg_config, FleetsAlgoConfig):  # each fleet's learner fitted alike, on its view
        specs = [(a, c, fleet_env(env, f)) for f, (a, c) in enumerate(zip(alg_config.algs, alg_config.configs,
                                                                           strict=True))]
        _, per_iter = fleet_updates_per_iter([learner_for(a, c, v, cfg, None, mode)[0].days_per_iter
                                              for a, c, v in specs])
        # fleet f updates per_iter[f] times an iteration: its schedules span that many more updates
        fitted = [learner_for(a, c, v, cfg, None if plan is None else plan._replace(
                      iters=plan.iters * k, last_iters=plan.last_iters * k), mode)
                  for (a, c, v), k in zip(specs, per_iter, strict=True)]
        learner = make_fleets_learner(env, [lr for lr, _ in fitted], alg_config.names, cfg.num_envs)
        return learner, dataclasses.replace(alg_config, configs=tuple(c for _, c in fitted))
    fields = {f.name for f in dataclasses.fields(alg_config)}
    by_name: Any = alg_config  # the fields read below are checked by name (`fields`), not by type
    upd: dict[str, Any] = {"num_envs": cfg.num_envs}
    n_rounds, total_iters = (1, 1) if plan is None else (plan.n_rounds, plan.total_iters)
    # a round's SUMO updates, every round (a short last round has at least one SUMO day); counted
    # with sumo_days_per_round 0 too, as before, so such a run's schedules are unchanged
    sumo_updates = n_rounds * (cfg.sumo_updates if mode != "surrogate" else 0)
    if "agent_frames_per_batch" in fields:  # TorchRL family: epsilon schedules span n_iters iterations
        per_iter = by_name.agent_frames_per_batch
        upd["n_iters"] = max(1, math.ceil((total_iters * per_iter + sumo_updates) / per_iter))
    if "eps_decay" in fields:  # IQL*: URB decays once per update over num_episodes updates
        updates = max(1, total_iters + sumo_updates)
        upd["eps_decay"] = float(by_name.eps_decay ** (by_name.num_episodes / updates))
    alg_config = dataclasses.replace(alg_config, **upd)
    return algorithm(alg).make_learner(alg_config, env), alg_config
