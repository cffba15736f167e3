"""The human learning phase: simulate it, save it, or replay an earlier run's instead.

The human phase (H SUMO days, the learned human state, and for the hybrid trainer its calibration
days) depends only on the network, routes, env seed, human model and demand, not on the CAV
policy, so runs on the same network and seed can share it (`--human-phase-from EXP_ID`).

One replay mechanism serves both commands: `ReplayHumanPhase` is a `DayExecutor` around another;
its first `days` days are the SUMO days recorded by the earlier run, after checking that today's
human choices are exactly the recorded ones (so a replay can never silently differ from a fresh
simulation); later days go to the wrapped executor.
* `urb-jax baseline`: `load_replay` puts it in front of the run's SUMO executor.
* `urb-jax train`: every train run saves `human_phase.npz` (`save_human_phase`: learned human
  state + calibration days); `reuse_human_phase` replays the recorded human days through
  `train_humans`, checks the replayed human state against the saved one, and takes the
  calibration days from the file.

A run's own human phase is journaled (`journal`: the one day cache, on disk in the run's first
folder; behind the SUMO day store, the store itself), so a run stopped before its first checkpoint
resumes by simulating the phase again with every day already done read back (SUMO days are
deterministic: the same records). The journal goes when every folder of the run is done
(`urb_jax.runs.train.drop_journal`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from urb_jax.city.scenario import Scenario
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.progress import Progress
from urb_jax.game.config import TaskConfig
from urb_jax.game.humans import HumanState
from urb_jax.reporting.metrics import PRE_WINDOW
from urb_jax.reporting.records import (
    EMISSION_COLUMNS,
    DayRecord,
    damage_of,
    damaged_records,
    read_records,
    run_config,
    write_with_digest,
)
from urb_jax.sumo_bridge import ARRIVED, DayExecutor, DayResult, MemoExecutor
from urb_jax.sumo_bridge.batch import as_batch
from urb_jax.surrogate import build_static, init_params, predict
from urb_jax.surrogate.calibrate import FitConfig, Params, SumoSample, fit_with_bias
from urb_jax.surrogate.data import make_choices
from urb_jax.surrogate.model import Static
from urb_jax.training.hybrid.plan import HybridConfig
from urb_jax.training.protocol import train_humans, train_humans_on_model

HUMAN_FILE = "human_phase.npz"
JOURNAL_DIR = "human_days.journal"  # in the run's first folder
JOURNAL_KEY = "human_days_journal"  # exp_config.json: the folder that holds the journal
# exp_config keys that must agree for the human phase to be the same.
MUST_MATCH = ("network", "env_seed", "human_model", "human_alpha", "human_beta", "human_beta_randomness",
              "human_deterministic", "gamma_c", "gamma_u", "epsilon", "delta", "routerl_literal",
              "demand_scale", "demand_mode", "demand_jitter_s", "number_of_paths", "path_gen_beta",
              "num_samples", "num_agents")
# A train run's also: the phase's length and the calibration days it recorded.
# hybrid_emissions: the reused days' records must carry emissions exactly when this run's do
TRAIN_MUST_MATCH = (*MUST_MATCH, "human_learning_episodes", "hybrid_calib_human_days",
                    "hybrid_calib_varied_days", "human_surrogate_days", "hybrid_emissions")
SURROGATE_KEY = "human_surrogate_days"  # exp_config.json: leading human days run on the surrogate
# what a key missing from an older run's exp_config.json meant
ABSENT = {SURROGATE_KEY: 0, "hybrid_emissions": False}
# The record columns a replay returns (a DayResult's fields, `action` checked against today's choices).
FIELDS = ("action", "travel_time", "route_length", "speed", "duration", "time_loss", "depart_delay", "status")


@dataclass(frozen=True)
class HumanPhase:
    """What the shared human phase leaves behind (one per run, shared by every seed)."""

    humans: HumanState
    records: list[DayRecord]  # its SUMO days (days surrogate_days + 1 .. H)
    calib_choices: np.ndarray  # [D, N]
    calib_times: np.ndarray  # [D, N] minutes
    calib_arrived: np.ndarray  # [D, N]
    surrogate_days: int = 0  # leading human days run on the surrogate (not in `records`)
    switch_humans: HumanState | None = None  # the knowledge after them (None: no surrogate days)
    surrogate_means: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))  # [S] minutes


def surrogate_human_days(cfg: HybridConfig, human_days: int, calibrate: bool) -> int:
    """How many leading human days run on the surrogate: `human_surrogate_days`, leaving at least
    t_pre's window (the last PRE_WINDOW days) in SUMO; none without calibration (mode sumo) or
    without varied calibration days to fit the surrogate on."""
    if not calibrate or cfg.calib_varied_days == 0:
        return 0
    return max(0, min(cfg.human_surrogate_days, human_days - PRE_WINDOW))


def run_human_phase(scn: Scenario, task: TaskConfig, cfg: HybridConfig, executor: DayExecutor, env_seed: int,
                    bar: Progress, calibrate: bool = True) -> HumanPhase:
    """The `calib_varied_days` varied SUMO days (run together), then H days of human learning: the
    first `surrogate_human_days` on the surrogate fitted to the varied days, the rest in SUMO."""
    records: list[DayRecord] = []
    hp, H = task.human_params(), task.human_learning_episodes
    varied, varied_results = _varied_days(scn, cfg, executor, env_seed, bar) if calibrate else ([], [])
    S = surrogate_human_days(cfg, H, calibrate)
    switch, means = None, np.zeros(0, np.float32)
    if S:
        model = _human_model(scn, cfg, varied, varied_results)
        switch, means = train_humans_on_model(scn, hp, S, env_seed=env_seed, travel_times=model)
        bar.update(S, "human/surrogate")

    humans = train_humans(scn, hp, H, env_seed=env_seed, executor=executor, bar=bar, bar_label="human/SUMO",
                          sink=records.append, first_day=S + 1, humans=switch)
    tail = records[-cfg.calib_human_days:] if calibrate and cfg.calib_human_days > 0 else []
    choices = [r.choices for r in tail] + varied
    results = [r.result for r in tail] + varied_results
    if not choices:
        z = np.zeros((0, scn.n_agents))
        return HumanPhase(humans, records, z.astype(np.int32), z.astype(np.float32), z.astype(bool))
    return HumanPhase(humans, records, np.stack(choices).astype(np.int32),
                      np.stack([r.travel_time for r in results]).astype(np.float32),
                      np.stack([r.status == ARRIVED for r in results]), S, switch, means)


def calibrate(start: Params, static: Static, human: HumanPhase, cfg: HybridConfig) -> Params:
    """The surrogate fitted to the human phase's calibration days (`calib_steps` steps from `start`,
    then the route bias on the same days): what the hybrid trainer's round 0 trains on, and what an
    env for a policy trained outside urb-jax simulates (`urb_jax.interop.outside`)."""
    sample = SumoSample(human.calib_choices, human.calib_times, human.calib_arrived)
    return fit_with_bias(start, static, sample, FitConfig(steps=cfg.calib_steps), sample, cfg.bias_prior,
                         cfg.route_bias_removed)


def _varied_days(scn: Scenario, cfg: HybridConfig, executor: DayExecutor, env_seed: int, bar: Progress
                 ) -> tuple[list[np.ndarray], list[DayResult]]:
    """The calibration's varied SUMO days (free-flow, random, equilibrium-like, mixed choices)."""
    if cfg.calib_varied_days == 0:
        return [], []
    static = build_static(scn)
    varied, _ = make_choices(scn, static, init_params(static), cfg.calib_varied_days, seed=env_seed)
    results = executor.run_days(scn, varied, [env_seed] * len(varied))
    bar.update(len(varied), "calibration/SUMO")
    return list(varied), list(results)


def _human_model(scn: Scenario, cfg: HybridConfig, choices: list[np.ndarray], results: list[DayResult]
                 ) -> Callable[[jnp.ndarray], jnp.ndarray]:
    """The surrogate fitted to the varied days, as the travel-time model of the humans' first days."""
    static = build_static(scn, cfg.surrogate_config)
    sample = SumoSample(np.stack(choices).astype(np.int32),
                        np.stack([r.travel_time for r in results]).astype(np.float32),
                        np.stack([r.status == ARRIVED for r in results]))
    params = fit_with_bias(init_params(static), static, sample, FitConfig(steps=cfg.calib_steps), sample,
                           cfg.bias_prior)
    return partial(predict, params, static)


def journal(executor: DayExecutor, folder: Path) -> MemoExecutor:
    """`executor` behind the one day cache, stored in folder/human_days.journal/: a stopped run
    starting again reads back the days it already ran, and a day that repeats one already run
    (converged deterministic humans: saint_arnoult, 66 of 208 days) is that SUMO day, read back.
    An executor already behind the day store (`sumo_bridge.memo.day_store`) is its own journal."""
    if isinstance(executor, MemoExecutor) and executor.stored:
        return executor
    return MemoExecutor(executor, store_dir=folder / JOURNAL_DIR)


def save_human_phase(folder: Path, human: HumanPhase) -> None:
    """human_phase.npz: the learned human state, the calibration days and, after surrogate human
    days, the knowledge they left (atomic, with its sha256 beside it: human_phase.npz.sha256)."""
    switch = {} if human.switch_humans is None else {
        f"switch_{k}": np.asarray(v) for k, v in human.switch_humans._asdict().items()}
    arrays = dict(calib_choices=human.calib_choices, calib_times=human.calib_times,
                  calib_arrived=human.calib_arrived, surrogate_means=human.surrogate_means, **switch,
                  **{f"humans_{k}": np.asarray(v) for k, v in human.humans._asdict().items()})
    write_with_digest(folder / HUMAN_FILE, lambda tmp: _savez(tmp, arrays))


def _savez(path: Path, arrays: dict[str, Any]) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def check_source_files(source: Path) -> None:
    """The files a reuse of `source`'s human phase reads (its records, its human_phase.npz) match
    their digests (files from before digests: as they are); else a UrbJaxError naming the first."""
    bad = damaged_records(source)
    npz = source / HUMAN_FILE
    if npz.is_file() and (why := damage_of(npz)) is not None:
        bad.append(f"{npz}: {why}")
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise UrbJaxError(f"{bad[0]}{more}: the human phase of {source.name} cannot be reused from damaged "
                          "files. Fix: restore the file from a backup, reuse another run, or drop "
                          "--human-phase-from (the run then simulates its own human phase).")


def saved_calibration_days(folder: Path) -> SumoSample:
    """The calibration days a train run's human phase saved (none: an empty sample, e.g. a baseline
    run or a `--mode sumo` run, which calibrates nothing)."""
    path = folder / HUMAN_FILE
    if not path.is_file():
        return SumoSample(np.zeros((0, 0), np.int32), np.zeros((0, 0), np.float32), np.zeros((0, 0), bool))
    z = np.load(path)
    return SumoSample(z["calib_choices"].astype(np.int32), z["calib_times"].astype(np.float32),
                      z["calib_arrived"].astype(bool))


class ReplayHumanPhase:
    """A `DayExecutor` whose first days are the recorded days `first_day`..`days` of an earlier run;
    later days run on `inner` (closed with it)."""

    def __init__(self, records: pd.DataFrame, agent_id: np.ndarray, days: int, inner: DayExecutor,
                 first_day: int = 1) -> None:
        self.days = days
        self.inner = inner
        self.calls = first_day - 1
        rec = records[records["day"] <= days]
        have = sorted(rec["day"].unique())
        if have != list(range(first_day, days + 1)):
            raise UrbJaxError(f"human phase replay needs days {first_day}..{days}; the source run has "
                              f"{len(have)} of them.")
        self._wide = {f: rec.pivot(index="day", columns="agent", values=f).reindex(columns=agent_id)
                      for f in rec.columns if f not in ("day", "agent")}  # FIELDS and any emissions
        if self._wide["action"].isna().any().any():
            raise UrbJaxError("human phase replay: the source run's agents differ from this scenario's.")

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        batch = as_batch(choices, seeds, is_cav)
        n_replayed = max(0, min(len(batch.seeds), self.days - self.calls))
        days = [self._replayed(c, s, m) for c, s, m in zip(batch.choices[:n_replayed], batch.seeds,
                                                            batch.cavs, strict=False)]
        if n_replayed < len(batch.seeds):
            rest = batch.cavs[n_replayed:]
            masks = None if rest[0] is None else np.stack(cast("list[np.ndarray]", rest))
            days += self.inner.run_days(scenario, batch.choices[n_replayed:], batch.seeds[n_replayed:], masks)
            self.calls += len(batch.seeds) - n_replayed
        return days

    def close(self) -> None:
        self.inner.close()

    def _replayed(self, choices: np.ndarray, seed: int, is_cav: np.ndarray | None) -> DayResult:
        self.calls += 1
        d = self.calls
        if is_cav is not None and np.asarray(is_cav).any():
            raise UrbJaxError(f"human phase replay: day {d} has CAVs.")
        row = {f: wide.loc[d].to_numpy() for f, wide in self._wide.items()}
        recorded = row["action"].astype(np.int64)
        if not np.array_equal(np.asarray(choices, np.int64), recorded):
            bad = int((np.asarray(choices) != recorded).sum())
            raise UrbJaxError(f"human phase replay: on day {d}, {bad} human choices differ from the source.")
        return _day_result(row, seed)


def _day_result(row: dict[str, np.ndarray], seed: int) -> DayResult:
    """A recorded day's columns as the DayResult SUMO returned (the summary statistics recomputed)."""
    arrived = row["status"] == ARRIVED
    f64 = {f: row[f].astype(np.float64) for f in FIELDS if f not in ("action", "status")}
    return DayResult(
        travel_time=f64["travel_time"], duration=f64["duration"], route_length=f64["route_length"],
        mean_speed=f64["speed"], time_loss=f64["time_loss"], depart_delay=f64["depart_delay"],
        status=row["status"].astype(np.int8), seed=seed,
        stat_mean_speed=_mean(f64["speed"], arrived),
        stat_mean_route_length=_mean(f64["route_length"], arrived),
        stat_mean_duration=_mean(f64["duration"], arrived),
        teleports=0, n_removed=int((~arrived).sum()), sim_end_time=float("nan"), wall_time=0.0,
        **{c: row[c].astype(np.float64) for c in EMISSION_COLUMNS if c in row},
    )


def _mean(x: np.ndarray, mask: np.ndarray) -> float:
    return float(np.nanmean(x[mask])) if mask.any() else float("nan")


def _checked_source(source: Path, config: dict[str, Any], keys: tuple[str, ...]) -> dict[str, Any]:
    """The source run's exp_config, after checking that `keys` agree with this run's `config` and that
    the files the reuse reads match their digests (`check_source_files`)."""
    cfg_path = source / "exp_config.json"
    if not cfg_path.is_file():
        raise UrbJaxError(f"{cfg_path}: not found. Fix: --human-phase-from takes the experiment id of an "
                          "earlier run in --results-dir.")
    src = run_config(source)  # checked against its digest
    diff = [f"{k} (source {src.get(k, ABSENT.get(k))!r}, this run {config.get(k)!r})" for k in keys
            if src.get(k, ABSENT.get(k)) != config.get(k)]
    if diff:
        raise UrbJaxError(f"{cfg_path}: its human phase differs from this run's: {'; '.join(diff)}. "
                          "Fix: reuse a run with the same network, configs and env seed, or drop "
                          "--human-phase-from.")
    check_source_files(source)
    return src


def _replay(source: Path, agent_id: np.ndarray, days: int, inner: DayExecutor, first_day: int = 1,
            emissions: bool = False) -> ReplayHumanPhase:
    """The replay of `source`'s days; `emissions`: with their CO2 and fuel (the source recorded them)."""
    columns = ["day", "agent", *FIELDS, *(EMISSION_COLUMNS if emissions else ())]
    return ReplayHumanPhase(read_records(source, columns=columns), agent_id, days, inner, first_day)


def load_replay(source: Path, config: dict[str, Any], agent_id: np.ndarray, days: int,
                inner: DayExecutor) -> ReplayHumanPhase:
    """`inner` behind a replay of `source`'s first `days` days, after checking it ran the same
    human phase (`urb-jax baseline --human-phase-from`)."""
    check_replayable(source, config, days)
    return _replay(source, agent_id, days, inner)


def check_replayable(source: Path, config: dict[str, Any], days: int) -> None:
    """Raise UrbJaxError unless `source` ran the human phase `config` asks for, `days` days of it
    all in SUMO (what a baseline replays)."""
    src = _checked_source(source, config, MUST_MATCH)
    if int(src.get("human_learning_episodes", -1)) < days:
        raise UrbJaxError(f"{source / 'exp_config.json'}: it has fewer than {days} human days.")
    if int(src.get(SURROGATE_KEY, 0)):
        raise UrbJaxError(f"{source / 'exp_config.json'}: its first {src[SURROGATE_KEY]} human days ran on "
                          "the surrogate, a baseline's run in SUMO. Fix: reuse a run whose hybrid config "
                          "has human_surrogate_days 0 (or a --mode sumo run), or drop --human-phase-from.")


def reuse_human_phase(source: Path, config: dict[str, Any], scn: Scenario, task: TaskConfig,
                      cfg: HybridConfig, env_seed: int, calibrate: bool = True) -> HumanPhase:
    """The HumanPhase of the earlier train run in `source`, after checking that its inputs match
    `config` (this run's exp_config keys); raises UrbJaxError naming the mismatch otherwise."""
    src = _checked_source(source, config, TRAIN_MUST_MATCH)
    path = source / HUMAN_FILE
    if not path.is_file():
        raise UrbJaxError(f"{path}: not found (only `urb-jax train` runs save their human phase). "
                          "Fix: pick a train run, or drop --human-phase-from.")
    z = np.load(path)
    calib = _calibration_days(z, path, cfg, calibrate)
    S = int(src.get(SURROGATE_KEY, 0))
    switch = _saved_humans(z, "switch") if S else None
    replay = _replay(source, scn.agent_id, task.human_learning_episodes, _NoMoreDays(), first_day=S + 1,
                     emissions=cfg.emissions)
    records: list[DayRecord] = []
    humans = train_humans(scn, task.human_params(), task.human_learning_episodes, env_seed=env_seed,
                          executor=replay, sink=records.append, first_day=S + 1, humans=switch)
    saved = _saved_humans(z, "humans")
    same = jax.tree_util.tree_map(lambda a, b: bool(np.array_equal(np.asarray(a), np.asarray(b),
                                                                   equal_nan=True)), humans, saved)
    if not all(jax.tree_util.tree_leaves(same)):
        raise UrbJaxError(f"{path}: replaying the recorded human days does not give the saved human "
                          "state (different code or human model?). Fix: drop --human-phase-from.")
    means = z["surrogate_means"] if "surrogate_means" in z.files else np.zeros(0, np.float32)
    return HumanPhase(humans, records, *calib, S, switch, means)


def _saved_humans(z: np.lib.npyio.NpzFile, prefix: str) -> HumanState:
    return HumanState(**{k: jnp.asarray(z[f"{prefix}_{k}"]) for k in HumanState._fields})


def _calibration_days(z: np.lib.npyio.NpzFile, path: Path, cfg: HybridConfig, calibrate: bool
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(choices, times, arrived) of the saved calibration days this run uses (none without calibration)."""
    calib = (z["calib_choices"], z["calib_times"], z["calib_arrived"])
    want = (cfg.calib_human_days + cfg.calib_varied_days) if calibrate else 0
    if len(calib[0]) < want:
        raise UrbJaxError(f"{path}: mode (the source recorded {len(calib[0])} calibration days, this run "
                          f"needs {want}; a --mode sumo run records none). Fix: reuse a hybrid or "
                          "surrogate run.")
    return calib if calibrate else (calib[0][:0], calib[1][:0], calib[2][:0])


class _NoMoreDays:
    """The executor behind a train run's replay: the source's human phase has every day it needs."""

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        raise UrbJaxError("human phase replay: asked for more days than the source's human phase.")

    def close(self) -> None:
        pass
