"""One seed group's hybrid training: setup, start or resume, rounds, test.

A round is a surrogate leg (`surrogate_days_per_round` env-days of learner iterations), a SUMO
leg (P SUMO days played by the exploring policies, `sumo_updates` updates on them), a refit of
each seed's surrogate (mode hybrid) and a checkpoint. Every random choice of round r flows from
fold_in(k_rounds, r) and the checkpointed state, so a resumed group ends like an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.learner import Day
from urb_jax.algorithms.registry import load_algo_config
from urb_jax.city.demand import ABSENT
from urb_jax.city.scenario import Scenario
from urb_jax.core.choices import MODES
from urb_jax.core.configio import configs_dir
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.phase import enter_phase
from urb_jax.core.progress import Progress
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.demand import DepartureJitter, scenario_on_day
from urb_jax.game.env import EnvState, RoutingEnv
from urb_jax.game.humans import HumanState, aon_routes, init_humans
from urb_jax.game.mutation import draw_cavs, split_fleets
from urb_jax.reporting.drift import ERROR_COLUMN, late_day_error
from urb_jax.reporting.records import (
    PARTS_DIR,
    DayRecord,
    RecordsWriter,
    adopt_undigested_parts,
    damaged_parts,
)
from urb_jax.sumo_bridge import DayExecutor, DayResult
from urb_jax.sumo_bridge.memo import MemoExecutor
from urb_jax.surrogate import SumoSample, build_static, predict
from urb_jax.surrogate.calibrate import REFIT, FitConfig, Params, fit_with_bias, uncalibrated
from urb_jax.surrogate.model import Static
from urb_jax.training.checkpoints import (
    CKPT_DIR,
    RoundMeta,
    checkpoint_meta,
    damaged_files,
    kept_checkpoints,
    latest_checkpoint,
    restore_round,
    save_round,
    verified_checkpoint,
)
from urb_jax.training.human_phase import HumanPhase, calibrate
from urb_jax.training.hybrid.clock import (
    IterationClock,
    leg_chunk_len,
    needs_probe,
    probe_seconds,
    run_chunks,
)
from urb_jax.training.hybrid.diverged import check_learner
from urb_jax.training.hybrid.fns import ActFn, Runner, TrainerFns, build_fns, maps_seeds
from urb_jax.training.hybrid.memory import check_fits
from urb_jax.training.hybrid.plan import (
    AlgoConfig,
    HybridConfig,
    RoundPlan,
    kept_rounds,
    learner_for,
    plan_rounds,
    whole_rounds,
)
from urb_jax.training.protocol import PHASE_TEST, PHASE_TRAIN

Row = dict[str, float]  # one seed's rounds.csv row
log = logging.getLogger(__name__)


class GroupKeys(NamedTuple):
    """Each seed's root keys, split from PRNGKey(seed): [S, 2] each."""

    rounds: jax.Array
    test: jax.Array
    start: jax.Array


class TrainState(NamedTuple):
    """The arrays a round carries and checkpoints, each with a leading seed axis."""

    runner: Runner  # [S]
    real: EnvState  # the real humans [S, R]: P copies (frozen), or one population (adapting)
    params: Params  # each seed's surrogate [S]


@dataclass(frozen=True)
class Group:
    """What every step of a seed group's training reads; fixed after `setup_group`."""

    scn: Scenario
    cfg: HybridConfig
    mode: str
    seeds: list[int]
    env_seed: int
    folders: list[Path]
    S: int  # seeds
    P: int  # SUMO days per round and seed
    adapt: bool  # humans keep learning (task should_humans_adapt): one population per seed
    H: int  # human days
    E: int  # test days
    is_cav: np.ndarray  # [N]
    cav_index: np.ndarray  # [C]
    static: Static
    p0: Params  # the uncalibrated surrogate, no route bias
    plan: RoundPlan
    alg_config: AlgoConfig
    fns: TrainerFns
    keys: GroupKeys
    clock: IterationClock  # times the surrogate iterations, chunk by chunk
    probe: Callable[[], float] | None  # a big learner's one-environment iteration, seconds (clock)
    memory_note: str  # the learner's memory against what is available (printed with the probe's estimate)
    seed_map: bool  # the learner's pieces go over the seeds by lax.map, not vmap (fns.maps_seeds)
    depart_jitter: DepartureJitter | None  # departures varying day to day (RoutingEnv.depart_jitter)
    # departures or demand vary: day indices [...] -> each day's departure shifts [..., N] (the env's
    # own draw, RoutingEnv.day_shifts), with which SUMO days are kept; None: every day as scheduled
    day_shifts: Callable[[np.ndarray], np.ndarray] | None

    @property
    def R(self) -> int:  # noqa: N802 (the letter the shape comments use)
        """Real-human copies per seed: P (frozen humans, the P days side by side), or 1 (adapting
        humans: one population lives every day in order, as in URB)."""
        return 1 if self.adapt else self.P


@dataclass(frozen=True)
class TrainSummary:
    """One seed's run, for its exp_config.json and rounds.csv."""

    rounds: list[Row]
    human_days: int
    sumo_training_days: int
    n_rounds: int
    surrogate_days: int
    alg_config: dict[str, Any]
    seeds_together: int
    aon_same_humans: dict[str, float]
    seed_axis: str  # how the group's seeds shared the program: "vmap" or "map"
    surrogate_late_error: float | None  # hybrid: the surrogate's late day error (reporting.drift)


@dataclass(frozen=True)
class Stopped:
    """A group stopped after `rounds_done` rounds' checkpoint (`stop_after_round`: a kill, for tests)."""

    rounds_done: int


def setup_group(scn: Scenario, task: TaskConfig, env_cfg: EnvConfig, alg: str, alg_config: AlgoConfig,
                cfg: HybridConfig, mode: str, seeds: list[int], env_seed: int, folders: list[Path],
                humans: HumanState | None) -> Group:
    """Mutation, the surrogate env, the learner fitted to the budget and its jitted pieces.
    `humans`: the human phase's; None for a resume (then a placeholder the checkpoint replaces)."""
    if mode not in MODES:
        raise ValueError(f"mode {mode!r}: use one of {MODES}")
    is_cav, static, env_kwargs, env = _group_env(scn, task, env_cfg, env_seed, humans, cfg)
    p0 = uncalibrated(static)
    given = alg_config  # the hint and the probe's learner start from it: fitting changes it
    plan = _plan(alg, given, env, cfg, mode)
    if humans is None:  # a resume (or a run's snapshots): the plan its checkpoints were trained to
        plan = resumed_plan(folders[0], plan, cfg.train_days)
    learner, alg_config = learner_for(alg, given, env, cfg, plan, mode)
    n_real = 1 if task.should_humans_adapt else cfg.sumo_days_per_round
    clock = IterationClock(plan.iters, plan.n_rounds, _slow_hint(alg, given), last_iters=plan.last_iters)
    shapes = jax.eval_shape(learner.init, jax.random.PRNGKey(0))  # one seed's runner, no memory
    probe = None
    if plan.iters and needs_probe(shapes.params):
        one, _ = learner_for(alg, given, env, dataclasses.replace(cfg, num_envs=1), plan, mode)
        probe = functools.partial(probe_seconds, one, jax.random.PRNGKey(0))
    memory_note = check_fits(shapes, len(seeds), f"{alg} on {scn.name}")
    seed_map = maps_seeds(cfg.seed_axis, shapes.params)
    fns = build_fns(env, env_kwargs, learner, static, cfg.sumo_days_per_round, plan.iters, n_real, seed_map)
    keys = jax.vmap(lambda s: jax.random.split(jax.random.PRNGKey(s), 3))(jnp.asarray(seeds))
    return Group(scn, cfg, mode, list(seeds), env_seed, list(folders), len(seeds), cfg.sumo_days_per_round,
                 task.should_humans_adapt, task.human_learning_episodes, task.test_eps, is_cav,
                 np.flatnonzero(is_cav), static, p0,
                 plan, alg_config, fns, GroupKeys(keys[:, 0], keys[:, 1], keys[:, 2]), clock, probe,
                 memory_note, seed_map, env.depart_jitter, _day_shifts(env))


def _day_shifts(env: RoutingEnv) -> Callable[[np.ndarray], np.ndarray] | None:
    """`env.day_shifts` over an array of day indices (None where nothing varies)."""
    if not env.varies_insertion:
        return None
    per_day = jax.jit(jax.vmap(env.day_shifts))
    return lambda days: np.asarray(per_day(jnp.asarray(days.reshape(-1)))).reshape(*days.shape, env.n_agents)


def _plan(alg: str, alg_config: AlgoConfig, env: RoutingEnv, cfg: HybridConfig, mode: str) -> RoundPlan:
    """The rounds the budget buys, from the learner's days per iteration on `env`."""
    return plan_rounds(cfg, mode, learner_for(alg, alg_config, env, cfg, None, mode)[0].days_per_iter)


def resumed_plan(folder: Path, plan: RoundPlan, train_days: int) -> RoundPlan:
    """The plan of the run whose checkpoints are in `folder` (a group's first), recomputed from the
    run's configs (`plan`) and checked against what its newest checkpoint recorded: a resume must
    finish the rounds the run started. A checkpoint from before the last round could be short (no
    `last_round` key) had whole rounds, the budget rounded up: its run keeps them. No checkpoint: `plan`."""
    meta = checkpoint_meta(folder)
    if meta is None:
        return plan
    last = meta.get("last_round")
    if last is None:  # whole rounds, as many as recorded (before `rounds_total`: as then planned)
        total = meta.get("rounds_total") or math.ceil(train_days / (plan.surrogate_days + plan.sumo_days))
        recorded = whole_rounds(plan, int(total))
        if recorded != plan:
            log.warning("this run was started by a version that trained whole rounds: it finishes as it "
                        "started, %s; a new run trains %s", budget_text(recorded, train_days),
                        budget_text(plan, train_days))
        return recorded
    recorded = plan._replace(n_rounds=int(meta["rounds_total"]), last_iters=int(last[0]),
                             last_sumo_days=int(last[1]))
    if recorded != plan:
        raise UrbJaxError(f"{folder}: the run's checkpoints were trained to "
                          f"{budget_text(recorded, train_days)}; its configs now plan "
                          f"{budget_text(plan, train_days)}. Fix: resume with the "
                          "version of urb-jax that started the run, or start it again with --overwrite.")
    return plan


def _group_env(scn: Scenario, task: TaskConfig, env_cfg: EnvConfig, env_seed: int, humans: HumanState | None,
               cfg: HybridConfig) -> tuple[np.ndarray, Static, dict[str, Any], RoutingEnv]:
    """(is_cav [N], static, env kwargs, the surrogate env, uncalibrated). `humans` None: a placeholder
    of the right shapes (a resume's checkpoint, or a dry run, replaces it)."""
    is_cav = draw_cavs(env_seed, scn.n_agents, task.ratio_machines, agent_id=scn.agent_id)
    # departures or demand that vary: the entries the shifts reach and SUMO's insertion slots
    varies = task.jitters_departures or task.varies_daily
    static = build_static(scn, cfg.surrogate_config, float(task.day_departure_jitter_s) if varies else None,
                          is_cav)
    env_kwargs = routing_env_kwargs(task, env_cfg, env_seed, is_cav)
    if humans is None:
        humans = init_humans(jax.random.PRNGKey(0), jnp.asarray(scn.fft), jnp.asarray(scn.route_valid),
                             task.human_params())
    env = surrogate_env(scn, is_cav, static, humans, uncalibrated(static), env_kwargs)
    return is_cav, static, env_kwargs, env


def budget_plan(scn: Scenario, task: TaskConfig, env_cfg: EnvConfig, alg: str, alg_config: AlgoConfig,
                cfg: HybridConfig, mode: str, env_seed: int) -> RoundPlan:
    """The rounds `setup_group` would plan, without a human phase (for a dry run)."""
    return _plan(alg, alg_config, _group_env(scn, task, env_cfg, env_seed, None, cfg)[3], cfg, mode)


def budget_text(plan: RoundPlan, train_days: int) -> str:
    """The plan in words, with the total trained and the total asked, e.g. '9 rounds of 640 surrogate
    + 4 SUMO days and a last round of 192 + 4 = 5,992 training days (6,000 asked; a learner
    iteration collects 16 days, so 8 are left over)'; '... = 6,000 training days (as asked)' when it
    is exact."""
    full = plan.n_rounds if plan.is_whole else plan.n_rounds - 1
    each = f"{plan.surrogate_days:,} surrogate + {_days(plan.sumo_days, 'SUMO day')}"
    parts = [f"{full} round{'s' if full > 1 else ''} of {each}"] if full else []
    if not plan.is_whole:
        last = (f"{plan.surrogate_days_of(plan.n_rounds - 1):,} surrogate + "
                f"{_days(plan.last_sumo_days, 'SUMO day')}")
        parts.append(f"a last round of {last}" if full else f"1 round of {last}")
    total = plan.total_days
    text = f"{' and '.join(parts)} = {total:,} training days"
    if total == train_days:
        return f"{text} (as asked)"
    if plan.is_whole and total > train_days:  # a plan recorded by a version that trained whole rounds
        return f"{text} ({train_days:,} asked; rounds were whole, so the budget was rounded up)"
    return (f"{text} ({train_days:,} asked; a learner iteration collects {plan.iter_days:,} days, so "
            f"{train_days - total:,} are left over)")


def _days(n: int, what: str) -> str:
    """'1 SUMO day', '1,200 SUMO days': the budget line reads as a sentence."""
    return f"{n:,} {what}{'' if n == 1 else 's'}"


def _slow_hint(alg: str, alg_config: AlgoConfig) -> str:
    """What to do about a surrogate training that is slow on this machine: URB's own config (the
    TorchRL family's config1) has a hybrid-sized alternative; any other config, a smaller budget."""
    if ((configs_dir() / "algo" / alg / "hybrid.json").is_file()
            and alg_config == load_algo_config(alg, "config1")):
        return (f"URB's TorchRL configs are update-bound on a CPU (their update count grows with the "
                f"data): `--alg-conf hybrid` trains {alg} sized for the hybrid budget (docs/algorithms.md)")
    return "Fewer --train-days, a smaller config or a GPU would shorten it"


def routing_env_kwargs(task: TaskConfig, env_cfg: EnvConfig, env_seed: int,
                       is_cav: np.ndarray | None = None) -> dict[str, Any]:
    """`RoutingEnv` keywords from the task and env configs (the same for surrogate and SUMO days,
    so both see the same drivers on a day of the same index: `day_demand` from the env seed).
    A task with fleets needs the CAV draw `is_cav` [N] (its fleets are split from it)."""
    kwargs = dict(human_params=task.human_params(), reward_coefficients=task.reward_coefficients,
                  observation_type=env_cfg.observations, humans_adapt=task.should_humans_adapt,
                  reward_credit=task.reward_credit, marginal_cost_beta=task.marginal_cost_beta,
                  day_demand=task.day_demand(env_seed), depart_jitter=task.departure_jitter(env_seed))
    if task.fleets:
        if is_cav is None:
            raise ValueError("a task with fleets needs the CAV draw (is_cav) to split its fleets")
        kwargs |= dict(cav_fleet=split_fleets(env_seed, is_cav, task.fleet_shares),
                       fleet_coefficients=tuple(f.reward_coefficients for f in task.fleets))
    return kwargs


def surrogate_env(scn: Scenario, is_cav: np.ndarray, static: Static, humans: HumanState, params: Params,
                  env_kwargs: dict[str, Any]) -> RoutingEnv:
    """The env whose days the surrogate simulates under `params` (its default_params)."""
    def sur_fn(p: Params, choices: jnp.ndarray, shift: jnp.ndarray | None = None) -> jnp.ndarray:
        return predict(p, static, choices, shift)  # shift: the day's departures off schedule

    return RoutingEnv(scn, is_cav, sur_fn, human_init=humans, default_params=params, **env_kwargs)


class HybridTrainer:
    """Trains a seed group: `start` (fresh) or `resume`, `run_round` per round, then `test`.

    Holds the group's moving parts: the arrays (`state`), each seed's SUMO days so far (`samples`,
    what the surrogate refits on; kept in mode hybrid only, so a `--mode sumo` checkpoint does not
    grow with its thousands of SUMO days), rounds.csv rows and the SUMO training days done."""

    def __init__(self, g: Group, executor: DayExecutor, writers: list[RecordsWriter], bar: Progress,
                 elapsed: Callable[[], float]) -> None:
        self.g, self.executor, self.writers, self.bar = g, executor, writers, bar
        self.elapsed = elapsed  # the group's wall seconds so far, for its checkpoints
        self.tag = f"[{g.S} seeds] " if g.S > 1 else ""
        self.state: TrainState
        self.samples: list[SumoSample] = []
        self.rounds_logs: list[list[Row]] = [[] for _ in g.seeds]
        self.sumo_done = 0
        self.programs: dict[Any, Any] = {}  # the surrogate leg's compiled chunk programs

    # ---- start, resume, checkpoint
    def fresh_state(self) -> TrainState:
        runner, real = self.g.fns.fresh_runner_real(self.g.keys.start)
        return TrainState(runner, real, _stack([self.g.p0] * self.g.S))

    def start(self, human: HumanPhase) -> int:
        """Records the human phase, calibrates the surrogate on its calibration days (the same for
        every seed), puts the trained humans in every real env and checkpoints round 0."""
        g = self.g
        enter_phase("the start of training (calibration, round 0's checkpoint)")
        state = self.fresh_state()
        for writer in self.writers:
            writer.truncate(0)  # a run restarted before its first checkpoint writes its parts again
            for rec in human.records:
                writer.add(rec)
        sample0 = SumoSample(human.calib_choices, human.calib_times, human.calib_arrived)
        if g.mode != "sumo" and len(sample0):
            state = state._replace(params=_stack([calibrate(g.p0, g.static, human, g.cfg)] * g.S))
        real = state.real._replace(humans=jax.tree_util.tree_map(
            lambda x: jnp.broadcast_to(x, (g.S, g.R, *x.shape)), human.humans))
        self.state = state._replace(real=real)
        self.samples = [sample0] * g.S
        for writer in self.writers:
            writer.flush()
        self.checkpoint(0)
        self.set_params()
        return 0

    def resume(self) -> int:
        """The group's newest checkpoint whose records are intact; every seed's record parts written
        after it are dropped. Every part a checkpoint counts is checked against its digest before
        any round runs (`intact_checkpoint`)."""
        enter_phase("the resume (restoring the checkpoint)")
        found = verified_checkpoint(self.g.folders[0])
        if found is None:
            raise RuntimeError(f"{self.g.folders[0]}: no checkpoint to resume from")
        newest = json.loads((found[1] / "meta.json").read_text())
        for folder in self.g.folders:
            if n := adopt_undigested_parts(folder):
                log.warning("%s: %d record parts from before record digests; their digests are written "
                            "now and checked from here on", folder, n)
        meta = self.restore(intact_checkpoint(self.g.folders, found[0], newest["record_parts"]))
        for writer, parts in zip(self.writers, meta.record_parts, strict=True):
            writer.truncate(parts)
        return meta.rounds_done

    def restore(self, rounds_done: int | None = None) -> RoundMeta:
        """The group's state from its checkpoint after `rounds_done` rounds (None: the newest)."""
        shapes = jax.eval_shape(self.fresh_state)._asdict()  # no fresh state beside the restored one
        state, self.samples, meta = restore_round(self.g.folders[0], shapes, self.g.seeds, rounds_done)
        self.state = TrainState(**state)
        self.rounds_logs, self.sumo_done = meta.rounds, meta.sumo_days
        if (self.g.day_shifts is not None and self.g.mode == "hybrid" and self.sumo_done
                and any(sample.shift is None for sample in self.samples)):
            raise UrbJaxError(f"{self.g.folders[0]}: its checkpoint's SUMO days have no departure shifts (a "
                              "version whose surrogate kept the scheduled insertion order), so its refits "
                              "cannot go on. Fix: resume with the version of urb-jax that started the run, "
                              "or start it again with --overwrite.")
        self.set_params()
        return meta

    def checkpoint(self, rounds_done: int) -> None:
        g = self.g
        meta = RoundMeta(rounds_done, self.sumo_done, list(g.seeds), [f.name for f in g.folders],
                         [w.n_parts for w in self.writers], self.rounds_logs, g.plan.n_rounds,
                         round(self.elapsed(), 2), [g.plan.last_iters, g.plan.last_sumo_days])
        save_round(g.folders[0], self.state._asdict(), self.samples, meta, kept_rounds(g.cfg, g.plan))

    def set_params(self) -> None:
        """The training envs of every seed's runner get the seed's current surrogate parameters."""
        s = self.state
        # [S, ...]; collect gives each env a copy. A copy here too: the rounds donate the runner,
        # and the surrogate's own parameters (s.params) must outlive it.
        runner = s.runner._replace(env_params=jax.tree_util.tree_map(jnp.copy, s.params))
        self.state = s._replace(runner=runner)

    # ---- a round
    def run_round(self, r: int) -> None:
        g = self.g
        rk = g.fns.round_keys(g.keys.rounds, r)  # [S, 4, 2]
        k_sur, k_act, k_step, k_upd = rk[:, 0], rk[:, 1], rk[:, 2], rk[:, 3]
        rows: list[Row] = [{"round": r + 1} for _ in g.seeds]
        g.clock.start_round(r)
        where = f"round {r + 1} of {g.plan.n_rounds}"
        if g.plan.iters_of(r):
            enter_phase(f"{where}: the surrogate leg")
            self.surrogate_leg(k_sur, rows, g.plan.iters_of(r))
        elif g.plan.iters:  # a short last round with no whole iteration left: says so in rounds.csv
            for row in rows:
                row["surrogate_days"] = 0
        if g.plan.sumo_days_of(r):
            enter_phase(f"{where}: the SUMO leg (SUMO days, updates, refit)")
            self.sumo_leg(r, k_act, k_step, k_upd, rows, g.plan.sumo_days_of(r))
        enter_phase(f"{where}: the checkpoint")
        check_learner(self.state.runner.params, rows, r, g.seeds)  # a diverged learner: no checkpoint
        for log, row in zip(self.rounds_logs, rows, strict=True):
            log.append(row)
        for writer in self.writers:
            writer.flush()
        self.checkpoint(r + 1)

    def surrogate_leg(self, k_sur: jax.Array, rows: list[Row], n_iters: int) -> None:
        """The round's `n_iters` learner iterations on the surrogate envs (chunks of one vmapped
        lax.scan). A short last round takes the first n_iters of a full round's keys."""
        g, days = self.g, n_iters * self.g.plan.iter_days
        t0 = time.perf_counter()
        keys = g.fns.iter_keys(k_sur)  # [S, iters, 2]
        if n_iters < keys.shape[1]:
            keys = keys[:, :n_iters]
        chunk = leg_chunk_len(n_iters, g.plan.iters, g.plan.last_iters)
        if g.adapt:  # adapting humans: the population lives the round's days too
            pop = jax.tree_util.tree_map(lambda x: x[:, 0], self.state.real)
            (runner, pop), m = run_chunks(g.fns.sur_round_adapt, (self.state.runner, pop), keys, g.clock,
                                          self.programs, chunk)
            real = jax.tree_util.tree_map(lambda x: x[:, None], pop)  # [S, 1]
            self.state = self.state._replace(runner=runner, real=real)
        else:
            (runner,), m = run_chunks(g.fns.sur_round, (self.state.runner,), keys, g.clock, self.programs,
                                      chunk)
            self.state = self.state._replace(runner=runner)
        m = {k: v.reshape(g.S, -1).mean(1) for k, v in m.items()}
        dt = time.perf_counter() - t0
        for i, row in enumerate(rows):
            row |= {"surrogate_days": days, "surrogate_s": dt,
                    "sur_time_cav": float(m["time_cav"][i]), "sur_time_hdv": float(m["time_human"][i])}
            if "loss" in m:  # the learner's training loss, mean over the round's updates
                row["sur_loss"] = float(m["loss"][i])
            if "population_time_human" in m:
                row |= {"population_time_cav": float(m["population_time_cav"][i]),
                        "population_time_hdv": float(m["population_time_human"][i])}
        self.bar.update(g.S * days, self.tag + "train/surrogate", sur_days_s=g.S * days / dt,
                        sur_tCAV=float(m["time_cav"].mean()), sur_tHDV=float(m["time_human"].mean()))

    def sumo_leg(self, r: int, k_act: jax.Array, k_step: jax.Array, k_upd: jax.Array,
                 rows: list[Row], p: int) -> None:
        """p <= P SUMO days per seed (p < P: a short last round) played by the exploring policies,
        updates on them, their records, then (mode hybrid) the refit."""
        g = self.g
        t0 = time.perf_counter()
        choices, results, times, days, loss, day_index = self.play_sumo_days(k_act, k_step, k_upd, p)
        shift = None if g.day_shifts is None else g.day_shifts(day_index)  # [S, p, N]
        pred = np.asarray(g.fns.predict_days(  # before the refit
            self.state.params, jnp.asarray(choices), None if shift is None else jnp.asarray(shift)))
        for i in range(g.S):
            res_i = results[i * p:(i + 1) * p]
            if g.mode == "hybrid":  # only the refit reads them: other modes' checkpoints stay bounded
                self.samples[i] = self.samples[i] + SumoSample.from_days(
                    choices[i], res_i, None if shift is None else shift[i])
            record_days(self.writers[i], g.H + self.sumo_done, PHASE_TRAIN, choices[i], g.is_cav, res_i,
                        _take(days, i), g.cav_index)
        self.sumo_done += p
        if g.mode == "hybrid":
            self.refit(r)
        dt = time.perf_counter() - t0
        for i, row in enumerate(rows):
            row |= sumo_row(times[i], pred[i], p, dt, g.is_cav, g.cav_index)
            if loss is not None:  # the loss of the updates on these SUMO days
                row["sumo_loss"] = float(loss[i])
        self.bar.update(g.S * p, self.tag + "train/SUMO", sumo_days_s=g.S * p / dt,
                        sumo_tCAV=float(np.mean([row["sumo_time_cav"] for row in rows])),
                        sumo_tHDV=float(np.mean([row["sumo_time_hdv"] for row in rows])))

    def play_sumo_days(self, k_act: jax.Array, k_step: jax.Array, k_upd: jax.Array, p: int
                       ) -> tuple[np.ndarray, list[DayResult], np.ndarray, Day, np.ndarray | None,
                                  np.ndarray]:
        """(choices [S, p, N], SUMO results [S * p] seed-major, times [S, p, N], days [S, 1, p, ...],
        the updates' mean loss [S] or None, each day's index [S, p]) for p <= P days a seed: the
        real humans advance by SUMO's times, then `sumo_updates` updates. Frozen humans: the S x p
        days go to the executor as one batch (p < P: the first p of the P copies play, the others
        stay as they were); adapting
        humans: the population lives the p days in order, S days (one per seed) at a time. Day d
        has the keys it has in a full round."""
        g, s = self.g, self.state
        R = g.R
        keys_act, keys_step = g.fns.split_p(k_act), g.fns.split_p(k_step)  # [S, P, 2]
        real, parts = s.real, []
        for c in range(0, p, R):
            b = min(R, p - c)  # days played of the R copies
            before = real
            choices, results, times, real, days, day_index = self.sumo_days(
                g.fns.act_explore, keys_act[:, c:c + R], keys_step[:, c:c + R], real, b, self.executor)
            if b < R:  # only the copies that played a day moved on
                real = jax.tree_util.tree_map(lambda new, old, b=b: jnp.concatenate(
                    [new[:, :b], old[:, b:]], axis=1), real, before)
                times = times[:, :b]
                days = jax.tree_util.tree_map(lambda x, b=b: x[:, :, :b], days)
            parts.append((choices, results, times, days, day_index))
        choices = np.concatenate([x[0] for x in parts], axis=1)
        results = [res for i in range(g.S) for x in parts
                   for res in x[1][i * x[0].shape[1]:(i + 1) * x[0].shape[1]]]
        times = np.concatenate([x[2] for x in parts], axis=1)
        days = jax.tree_util.tree_map(lambda *x: jnp.concatenate(x, axis=2), *[x[3] for x in parts])
        runner, losses = s.runner, []
        for u in range(g.cfg.sumo_updates):
            runner, m = g.fns.update(runner, days, jax.vmap(lambda k, u=u: jax.random.fold_in(k, u))(k_upd))
            if "loss" in m:
                losses.append(np.asarray(m["loss"]).reshape(g.S, -1).mean(1))
        self.state = s._replace(runner=runner, real=real)
        day_index = np.concatenate([x[4] for x in parts], axis=1)
        return choices, results, times, days, np.mean(losses, axis=0) if losses else None, day_index

    def sumo_days(self, act: ActFn, k_act: jax.Array, k_step: jax.Array, real: EnvState, b: int,
                  executor: DayExecutor
                  ) -> tuple[np.ndarray, list[DayResult], np.ndarray, EnvState, Day, np.ndarray]:
        """The one SUMO leg of training and test days: the policies act (`act`, exploring or greedy)
        on keys [S, r, 2]; the first b <= r days of every seed run on `executor` as one batch of
        S x b; the real days step on SUMO's times (days past b repeat the first: their humans are
        frozen). Returns (choices [S, b, N], results [S * b] seed-major, times [S, r, N], real, days,
        the played days' indices [S, b])."""
        g, s = self.g, self.state
        n, r = g.scn.n_agents, k_act.shape[1]
        choices: jax.Array | np.ndarray  # the jitted act's, then numpy (np.asarray)
        obs, actions, choices = act(s.runner, k_act, real)
        choices = np.asarray(choices)[:, :b]  # [S, b, N]
        day_index = np.asarray(real.day).reshape(g.S, -1)[:, :b]  # [S, b]
        results = self.run_on_days(executor, choices.reshape(g.S * b, n), day_index.reshape(-1))
        times = np.zeros((g.S, r, n), np.float32)
        times[:, :b] = np.stack([res.travel_time for res in results]).reshape(g.S, b, n)
        times[:, b:] = times[:, :1]
        real, days = g.fns.sumo_step(k_step, real, obs, actions, jnp.asarray(times), s.params)
        return choices, results, times, real, days, day_index

    def run_on_days(self, executor: DayExecutor, choices: np.ndarray, days: np.ndarray) -> list[DayResult]:
        """SUMO days of `choices` [B, N] in order, row i on day index `days[i]` (its real copy's
        `state.day`): one batch, or, where departures vary day to day, one batch per day index."""
        g = self.g
        if g.depart_jitter is None:
            return executor.run_days(g.scn, choices, [g.env_seed] * len(choices), is_cav=g.is_cav)
        results: list[DayResult | None] = [None] * len(choices)
        for day in np.unique(days):
            rows = np.flatnonzero(days == day)
            scn = scenario_on_day(g.scn, g.depart_jitter, int(day))
            for i, res in zip(rows, executor.run_days(scn, choices[rows], [g.env_seed] * len(rows),
                                                       is_cav=g.is_cav), strict=True):
                results[i] = res
        done = [res for res in results if res is not None]
        assert len(done) == len(results)  # every row's day index is one of the batches'
        return done

    def refit(self, r: int) -> None:
        """Each seed refits its surrogate on `refit_days` of its SUMO days (a fixed-size sample drawn
        from default_rng([seed, r]), so the jitted fit never recompiles)."""
        g = self.g
        refit_cfg = dataclasses.replace(REFIT, steps=g.cfg.refit_steps)
        new_params = []
        for i, seed in enumerate(g.seeds):
            sample = self.samples[i]
            rng = np.random.default_rng([seed, r, 0xF17])
            pick = rng.choice(len(sample), size=g.cfg.refit_days, replace=len(sample) < g.cfg.refit_days)
            new_params.append(self.fit(_take(self.state.params, i), sample.days(pick), refit_cfg, sample))
        self.state = self.state._replace(params=_stack(new_params))
        self.set_params()

    def fit(self, start: Params, sub: SumoSample, fit_cfg: FitConfig, full: SumoSample) -> Params:
        """Gradient fit of the smooth model on `sub`, then the per-route residual on all SUMO days."""
        g = self.g
        return fit_with_bias(start, g.static, sub, fit_cfg, full, g.cfg.bias_prior, g.cfg.route_bias_removed)

    # ---- test
    def test(self) -> dict[str, float]:
        """`test_eps` SUMO days of the frozen greedy policies, S x R at a time (frozen humans: P days
        side by side; adapting humans: in order, learning as in URB's test phase; a repeated day runs
        once with `reuse_identical_test_days`), then the AON reference day."""
        g = self.g
        executor = MemoExecutor(self.executor) if g.cfg.reuse_identical_test_days else self.executor
        first_test_choices, first_day = None, int(np.asarray(self.state.real.day).reshape(-1)[0])
        for start_day in range(0, g.E, g.R):
            choices = self.test_days(start_day, executor)
            if start_day == 0:
                first_test_choices = choices[0, 0]
        if first_test_choices is None:
            return {}
        scn = scenario_on_day(g.scn, g.depart_jitter, first_day)
        return aon_same_humans(scn, first_test_choices, g.is_cav, executor, g.env_seed)

    def test_days(self, start_day: int, executor: DayExecutor) -> np.ndarray:
        """Test days start_day + 1 .. + b (b <= R) of every seed; returns their choices [S, b, N]."""
        g, s = self.g, self.state
        b = min(g.R, g.E - start_day)
        kt = jax.vmap(lambda k, d=start_day: jax.random.split(jax.random.fold_in(k, d)))(g.keys.test)
        choices, results, times, real, days, _ = self.sumo_days(
            g.fns.act_greedy, g.fns.split_p(kt[:, 0])[:, :g.R], g.fns.split_p(kt[:, 1])[:, :g.R], s.real, b,
            executor)
        self.state = s._replace(real=real)
        for i in range(g.S):
            days_i = jax.tree_util.tree_map(lambda x, b=b, i=i: x[i, :, :b], days)
            record_days(self.writers[i], g.H + g.plan.total_sumo_days + start_day, PHASE_TEST,
                        choices[i], g.is_cav, results[i * b:(i + 1) * b], days_i, g.cav_index)
        self.bar.update(g.S * b, self.tag + "test/SUMO", sumo_tCAV=float(
            times[:, :b][..., g.cav_index].mean()) if g.cav_index.size else 0.0)
        return choices

    def summaries(self, aon: dict[str, float]) -> list[TrainSummary]:
        g, plan = self.g, self.g.plan
        return [TrainSummary(log, g.H, plan.total_sumo_days, plan.n_rounds,
                             plan.total_surrogate_days, dataclasses.asdict(g.alg_config), g.S, aon,
                             "map" if g.seed_map else "vmap",
                             late_day_error([row.get(ERROR_COLUMN, math.nan) for row in log])
                             if g.mode == "hybrid" else None)
                for log in self.rounds_logs]


def train_group(
    *, scn: Scenario, task: TaskConfig, env_cfg: EnvConfig, alg: str, alg_config: AlgoConfig,
    cfg: HybridConfig, mode: str, seeds: list[int], env_seed: int, folders: list[Path],
    executor: DayExecutor, human: HumanPhase | None, elapsed: Callable[[], float], progress: bool = True,
    stop_after_round: int | None = None, on_round: Callable[[list[Row]], None] | None = None,
) -> list[TrainSummary] | Stopped:
    """Train S seeds together, seed s in `folders[s]` (fresh when `human` is given, else resumed from
    the group checkpoint in `folders[0]`); returns one summary per seed.

    Every learner function is vmapped over a leading seed axis (runner [S], real humans [S, P],
    surrogate parameters [S]); each round's S x P SUMO days go to the executor in one batch, and
    the test days likewise. Each seed refits its own surrogate on its own SUMO days (a loop over
    seeds outside the jitted training). `stop_after_round` simulates a kill (tests). `on_round`
    gets each round's rounds.csv rows (one per seed) once it is checkpointed; a resumed group
    passes it the restored rounds first, so it sees every round in order (e.g. TensorBoard).
    `elapsed()`: the group's wall seconds so far, earlier processes' included, kept in each checkpoint."""
    g = setup_group(scn, task, env_cfg, alg, alg_config, cfg, mode, seeds, env_seed, folders,
                    human.humans if human is not None else None)
    writers = [RecordsWriter(f, scn.agent_id, scn.agent_od, scn.agent_depart, flush_every=10**9,
                             emissions=cfg.emissions) for f in folders]
    plan = g.plan
    bar = Progress(g.S * (g.H + plan.total_days + g.E), progress)
    g.clock.note = bar.note
    found = None if human is not None else latest_checkpoint(folders[0])  # None: resume() says why
    first = 0 if found is None else found[0]
    if first < plan.n_rounds:
        bar.note(f"budget: {budget_text(plan, cfg.train_days)}")
    if g.probe is not None and first < plan.n_rounds:  # a big learner: its memory and cost up front,
        bar.note(g.memory_note)  # the probe run before the group's state exists (hybrid/memory.py)
        g.clock.start_round(first)
        g.clock.before_training(g.probe() * g.S * cfg.num_envs, g.S * cfg.num_envs)
    trainer = HybridTrainer(g, executor, writers, bar, elapsed)
    start = trainer.start(human) if human is not None else trainer.resume()
    bar.skip(g.S * (g.H + plan.days_through(start)), trainer.tag + ("resume" if human is None else "human"))
    if on_round is not None:  # a resumed group's restored rounds first
        for r in range(start):
            on_round([log[r] for log in trainer.rounds_logs])
    for r in range(start, plan.n_rounds):
        trainer.run_round(r)
        if on_round is not None:
            on_round([log[r] for log in trainer.rounds_logs])
        bar.milestone()  # a line per round, even with --no-progress
        if stop_after_round is not None and r + 1 >= stop_after_round:
            bar.close()
            return Stopped(r + 1)
    enter_phase("the test days")
    aon = trainer.test()
    bar.close()
    enter_phase("the records' merge")
    for writer in writers:
        writer.close()
    return trainer.summaries(aon)


def check_group_records(folders: Sequence[Path]) -> None:
    """A seed group's records as its resume will find them, checked now: a multi-group `--resume`
    checks every unfinished group before it trains the first, so a group whose records would be
    refused is refused before the groups ahead of it train (a group that can fall back is left to
    its own start, which says so)."""
    found = verified_checkpoint(folders[0])
    if found is None:
        return
    newest = json.loads((found[1] / "meta.json").read_text())
    for folder in folders:
        adopt_undigested_parts(folder)
    intact_checkpoint(folders, found[0], newest["record_parts"], quiet=True)


def intact_checkpoint(folders: Sequence[Path], newest: int, newest_parts: Sequence[int],
                      quiet: bool = False) -> int:
    """The rounds done of the newest kept checkpoint, at most `newest`, whose record parts are all
    intact in every seed's folder (`records.damaged_parts`). A damaged or missing part is named (a
    warning: run.log) and a checkpoint from before it is used, its later parts written again; none
    left is a UrbJaxError that names the files and says what to do."""
    bad = [damaged_parts(f, n) for f, n in zip(folders, newest_parts, strict=True)]
    if not any(bad):
        return newest
    first_bad = [b[0][0] if b else n for b, n in zip(bad, newest_parts, strict=True)]
    named = "; ".join(why for b in bad for _, why in b)
    for rounds_done in reversed(kept_checkpoints(folders[0])):
        ckpt = folders[0] / CKPT_DIR / f"round_{rounds_done:05d}"
        if rounds_done >= newest:
            continue
        try:
            meta = json.loads((ckpt / "meta.json").read_text())
        except ValueError:
            continue
        if damaged_files(ckpt, meta):
            continue
        if all(n <= f for n, f in zip(meta["record_parts"], first_bad, strict=True)):
            if not quiet:
                log.warning("damaged records (%s): resuming from the checkpoint after round %d, whose "
                            "records are intact; the days after it are run again", named, rounds_done)
            return rounds_done
    raise UrbJaxError(
        f"{folders[0]}: damaged records ({named}); no kept checkpoint comes before them, so the run cannot "
        "go on from its records. Fix: start the run again with the same command and --overwrite (or "
        f"restore {PARTS_DIR}/ from a backup and --resume).")


def checkpoint_test_phase(g: Group, rounds_done: int, executor: DayExecutor, writers: list[RecordsWriter],
                    progress: bool = False) -> tuple[RoundMeta, dict[str, float]]:
    """The test phase of the group's policies as its checkpoint after `rounds_done` rounds left them
    (a learning-curve snapshot): the run's own test days and keys, recorded to `writers` (one per
    seed); returns (the checkpoint's meta, the AON day on the same humans)."""
    bar = Progress(g.S * g.E, progress)
    trainer = HybridTrainer(g, executor, writers, bar, lambda: 0.0)
    meta = trainer.restore(rounds_done)
    aon = trainer.test()
    bar.close()
    return meta, aon


def aon_same_humans(scn: Scenario, choices: np.ndarray, is_cav: np.ndarray, executor: DayExecutor,
                    env_seed: int) -> dict[str, float]:
    """One SUMO day: `choices`' humans, the CAVs on their minimum free-flow route.

    The quality bar is "t_CAV at or below AON's", and with frozen deterministic humans (task
    config1, Scenario 1) this day *is* URB's AON baseline on the same test humans (with stochastic
    humans, AON on the first test day's human draw), so each run reports
    it next to its own t_CAV (exp_config.json) at the cost of one SUMO day. Not a run day: it is
    not in the records or in any metric."""
    mixed = np.where(is_cav, aon_routes(scn.fft, scn.route_valid), choices)
    res = executor.run_days(scn, mixed[None], [env_seed], is_cav=is_cav)[0]
    return {"t_CAV": _group_mean(res.travel_time[is_cav]), "t_HDV": _group_mean(res.travel_time[~is_cav]),
            # the published tables' measure (urb_jax.metrics.DURATION_COLUMNS)
            "t_CAV_duration": _group_mean(res.duration[is_cav], np.nanmean) / 60}


def _group_mean(x: np.ndarray, reduce: Callable[[np.ndarray], Any] = np.mean) -> float:
    """A group's mean time, NaN for a group nobody is in (no humans under full autonomy)."""
    return float(reduce(x)) if x.size else float("nan")


def record_days(writer: RecordsWriter, first_day_minus1: int, phase: str, choices: np.ndarray,
                is_cav: np.ndarray, results: Sequence[DayResult], days: Day, cav_index: np.ndarray) -> None:
    """One seed's SUMO days as DayRecords: humans' reward is -time, CAVs' the env's (days [1, P, ...])."""
    obs = np.asarray(days.obs[0])  # [P, C, D]
    rewards = np.asarray(days.reward[0])
    for p, res in enumerate(results):
        times = np.asarray(res.travel_time, dtype=np.float64)
        rew = -times.copy()
        rew[cav_index] = rewards[p]
        rew[choices[p] == ABSENT] = np.nan  # stayed home (day_participation): no trip, no reward
        obs_all = np.full((choices.shape[1], obs.shape[-1]), np.nan, np.float32)
        obs_all[cav_index] = obs[p]
        writer.add(DayRecord(first_day_minus1 + p + 1, phase, choices[p], is_cav, res, rew, obs_all, True))


def sumo_row(t: np.ndarray, pred: np.ndarray, P: int, dt: float, is_cav: np.ndarray,
             cav_index: np.ndarray) -> Row:
    """A seed's rounds.csv SUMO columns from its SUMO times t and the surrogate's prediction pred [P, N],
    over the drivers who travelled (t is NaN for a driver at home; nanmean is mean where none is)."""
    pred_went = np.where(np.isnan(t), np.nan, pred)
    day_error = np.nanmean(pred_went, 1) - np.nanmean(t, 1)  # [P]
    return {"sumo_days": P, "sumo_s": dt, "sumo_time_cav": _group_mean(t[:, cav_index], np.nanmean),
            "sumo_time_hdv": _group_mean(t[:, ~is_cav], np.nanmean),
            ERROR_COLUMN: float(day_error.mean() / np.nanmean(t)),
            "surrogate_mape": float(np.nanmean(np.abs(pred_went - t) / t))}


def _stack(trees: list[Any]) -> Any:
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *trees)


def _take(tree: Any, s: int) -> Any:
    return jax.tree_util.tree_map(lambda x: x[s], tree)
