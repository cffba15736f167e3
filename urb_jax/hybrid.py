"""The hybrid trainer: URB's experiment with CAV training split between a calibrated surrogate
(jitted, many envs) and SUMO days that fine-tune the policies and refit the surrogate.

Phases (one results folder per training seed, URB layout):
1. human learning: H SUMO days (`urb_jax.experiment.train_humans`, t_pre = last 50);
2. mutation (`draw_cavs`), surrogate calibration on the last `calib_human_days` human days plus
   `calib_varied_days` SUMO days of varied joint actions (not experiment days, not in records);
3. rounds: `surrogate_days_per_round` env-days of learner iterations on the surrogate (mode
   hybrid/surrogate), then
   `sumo_days_per_round` P SUMO days in parallel (mode hybrid/sumo) played by the current
   exploring policies (CAVs act in departure order on the real humans' choices), then
   `sumo_updates` updates on those days, then (hybrid) a refit on `refit_days` days drawn from
   every SUMO day so far; a checkpoint ends each round;
4. test: `test_eps` SUMO days with frozen (greedy) policies.

Budget: `train_days` URB-equivalent training days = surrogate env-days + SUMO training days.
Records hold SUMO days only (column sumo=True); surrogate days are summarised per round in
`rounds.csv`, so every metric and t_train come from SUMO days. Every random choice of round r
flows from fold_in(PRNGKey(seed), r) and the checkpointed state, so `--resume` after a kill
reproduces an uninterrupted run.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from algorithms.common import (
    Day,
    Learner,
    act_by_levels,
    dependency_levels,
    restore_checkpoint,
    save_checkpoint,
)
from urb_jax.config import EnvConfig, TaskConfig
from urb_jax.env import RoutingEnv
from urb_jax.experiment import PHASE_TEST, PHASE_TRAIN, DayRecord, train_humans
from urb_jax.humans import HumanState
from urb_jax.scenario import Scenario

MODES = ("hybrid", "sumo", "surrogate")
ALGORITHMS = ("iql", "ippo", "mappo", "qmix", "vdn", "iql_star", "ippo_star")
CKPT_DIR = "checkpoints"


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
    refit_days: int = 32
    refit_steps: int = 150
    day_timeout_s: float = 600.0


def load_hybrid_config(name: str = "default") -> tuple[HybridConfig, Path]:
    from urb_jax.configio import find_config, load_json

    path = find_config("hybrid", name)
    return load_json(HybridConfig, path), path


@dataclass
class HumanPhase:
    """What the shared human phase leaves behind (one per run, shared by every seed)."""

    humans: HumanState
    records: list[DayRecord]
    calib_choices: np.ndarray  # [D, N]
    calib_times: np.ndarray  # [D, N] minutes
    calib_arrived: np.ndarray  # [D, N]


def run_human_phase(scn: Scenario, task: TaskConfig, cfg: HybridConfig, executor: Any, env_seed: int,
                    on_day: Callable[[str, int], None] | None = None, calibrate: bool = True) -> HumanPhase:
    """H SUMO days of human learning, then `calib_varied_days` varied SUMO days for calibration."""
    from sumo_bridge.types import ARRIVED
    from surrogate import build_static, init_params
    from surrogate.data import make_choices

    records: list[DayRecord] = []

    def simulate(day: int, phase: str, choices: np.ndarray, is_cav: np.ndarray) -> Any:
        res = executor.run_days(scn, choices[None], [env_seed])[0]
        if on_day:
            on_day(phase, 1)
        return res

    humans = train_humans(scn, task.human_params(), task.human_learning_episodes, env_seed=env_seed,
                          simulate=simulate, sink=records.append)
    tail = records[-cfg.calib_human_days:] if calibrate and cfg.calib_human_days > 0 else []
    choices = [r.choices for r in tail]
    results = [r.result for r in tail]
    if calibrate and cfg.calib_varied_days > 0:
        static = build_static(scn)
        varied, _ = make_choices(scn, static, init_params(static), cfg.calib_varied_days, seed=env_seed)
        choices += list(varied)
        results += executor.run_days(scn, varied, [env_seed] * len(varied))
        if on_day:
            on_day("calibration", len(varied))
    if not choices:
        z = np.zeros((0, scn.n_agents))
        return HumanPhase(humans, records, z.astype(np.int32), z.astype(np.float32), z.astype(bool))
    return HumanPhase(humans, records, np.stack(choices).astype(np.int32),
                      np.stack([r.travel_time for r in results]).astype(np.float32),
                      np.stack([r.status == ARRIVED for r in results]))


def iters_per_round(cfg: HybridConfig, days_per_iter: int, mode: str) -> int:
    """Learner iterations on the surrogate per round (each collects days_per_iter x num_envs days)."""
    if mode == "sumo":
        return 0
    return max(1, round(cfg.surrogate_days_per_round / (days_per_iter * cfg.num_envs)))


def learner_for(alg: str, alg_config: Any, env: RoutingEnv, cfg: HybridConfig, n_rounds: int,
                mode: str, n_iters_round: int = 1) -> tuple[Learner, Any]:
    """The algorithm's learner with num_envs and schedule lengths fitted to the hybrid budget:
    epsilon schedules (linear over n_iters, or IQL*'s per-update decay) end where URB's end."""
    import importlib

    module = importlib.import_module(f"algorithms.{alg}")
    fields = {f.name for f in dataclasses.fields(alg_config)}
    upd: dict[str, Any] = {"num_envs": cfg.num_envs}
    sumo_updates = cfg.sumo_updates if mode != "surrogate" else 0
    if "agent_frames_per_batch" in fields:  # TorchRL family: epsilon schedules span n_iters iterations
        per_iter = alg_config.agent_frames_per_batch
        upd["n_iters"] = max(1, math.ceil(n_rounds * (n_iters_round * per_iter + sumo_updates) / per_iter))
    if "eps_decay" in fields:  # IQL*: URB decays once per update over num_episodes updates
        updates = max(1, n_rounds * (n_iters_round + sumo_updates))
        upd["eps_decay"] = float(alg_config.eps_decay ** (alg_config.num_episodes / updates))
    alg_config = dataclasses.replace(alg_config, **upd)
    return module.make_learner(alg_config, env), alg_config


def plan_rounds(cfg: HybridConfig, mode: str, days_per_iter: int) -> tuple[int, int, int, int]:
    """(rounds, surrogate iterations per round, surrogate env-days per round, SUMO days per round)."""
    iters = iters_per_round(cfg, days_per_iter, mode)
    sur = iters * days_per_iter * cfg.num_envs
    sumo = cfg.sumo_days_per_round if mode != "surrogate" else 0
    return max(1, math.ceil(cfg.train_days / max(sur + sumo, 1))), iters, sur, sumo


class _Progress:
    """tqdm bar over URB-equivalent days with the phase and live rates in the postfix."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.bar = None
        if enabled:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, unit="day", dynamic_ncols=True, smoothing=0.1)
        self.info: dict[str, str] = {}

    def update(self, n: int, phase: str, **info: float) -> None:
        self.info.update({k: f"{v:.3g}" for k, v in info.items() if v == v})
        if self.bar is not None:
            self.bar.set_description(phase)
            self.bar.set_postfix(self.info, refresh=False)
            self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _atomic_json(path: Path, obj: Any) -> None:
    from urb_jax.results import write_json

    write_json(path, obj)


def _atomic_npz(path: Path, **arrays: np.ndarray) -> None:
    tmp = path.with_name(f".{path.name}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def latest_checkpoint(folder: Path) -> tuple[int, Path] | None:
    """(rounds done, dir) of the newest complete checkpoint (meta.json is written last)."""
    root = folder / CKPT_DIR
    done = sorted(int(p.name.split("_")[1]) for p in root.glob("round_*") if (p / "meta.json").is_file())
    return (done[-1], root / f"round_{done[-1]:05d}") if done else None


def train_seed(
    *, scn: Scenario, task: TaskConfig, env_cfg: EnvConfig, alg: str, alg_config: Any, cfg: HybridConfig,
    mode: str, seed: int, env_seed: int, folder: Path, executor: Any, human: HumanPhase | None,
    progress: bool = True, stop_after_round: int | None = None,
) -> dict[str, Any]:
    """Train one seed in `folder` (fresh when `human` is given, else resumed from its newest
    checkpoint); returns the run summary. `stop_after_round` simulates a kill (tests)."""
    from surrogate import SumoSample, build_static, init_params, predict
    from surrogate.calibrate import REFIT, FitConfig, fit_params
    from urb_jax.mutation import draw_cavs
    from urb_jax.results import RecordsWriter

    if mode not in MODES:
        raise ValueError(f"mode {mode!r}: use one of {MODES}")
    n = scn.n_agents
    H, E = task.human_learning_episodes, task.test_eps
    hp = task.human_params()
    is_cav = draw_cavs(env_seed, n, task.ratio_machines, agent_id=scn.agent_id)
    cav_index = np.flatnonzero(is_cav)
    static = build_static(scn)

    def sur_fn(params: Any, choices: jnp.ndarray) -> jnp.ndarray:
        return predict(params, static, choices)

    common = dict(human_params=hp, reward_coefficients=task.reward_coefficients,
                  observation_type=env_cfg.observations, humans_adapt=task.should_humans_adapt)
    p0 = init_params(static)
    humans0 = human.humans if human is not None else None
    # Placeholder human knowledge for a resume (shapes only; the checkpoint overwrites it).
    if humans0 is None:
        from urb_jax.humans import init_humans

        humans0 = init_humans(jax.random.PRNGKey(0), jnp.asarray(scn.fft), jnp.asarray(scn.route_valid), hp)
    env = RoutingEnv(scn, is_cav, sur_fn, human_init=humans0, travel_params=p0, **common)
    real_env = RoutingEnv(scn, is_cav, lambda p, c: p, human_init=humans0,
                          travel_params=jnp.zeros((n,), jnp.float32), **common)
    probe, _ = learner_for(alg, alg_config, env, cfg, 1, mode)
    n_rounds, n_iters_round, sur_per_round, sumo_per_round = plan_rounds(cfg, mode, probe.days_per_iter)
    learner, alg_config = learner_for(alg, alg_config, env, cfg, n_rounds, mode, n_iters_round)
    P = cfg.sumo_days_per_round
    levels = dependency_levels(env)
    k_rounds, k_test, k_start = jax.random.split(jax.random.PRNGKey(seed), 3)
    refit_cfg = dataclasses.replace(REFIT, steps=cfg.refit_steps)

    # ---- jitted pieces
    @jax.jit
    def sur_round(runner: Any, key: jax.Array):
        return jax.lax.scan(learner.iteration, runner, jax.random.split(key, n_iters_round))

    @jax.jit
    def update(runner: Any, days: Day, key: jax.Array):
        return learner.update_from_days(runner, days, key)

    def _act(runner: Any, keys: jax.Array, states: Any, explore: bool):
        pol = learner.policy(runner, explore)
        obs, actions = jax.vmap(lambda k, s: act_by_levels(real_env, k, s, pol, levels))(keys, states)
        return obs, actions, jax.vmap(real_env.joint_actions)(states, actions)

    act_explore = jax.jit(lambda r, k, s: _act(r, k, s, True))
    act_greedy = jax.jit(lambda r, k, s: _act(r, k, s, False))

    @jax.jit
    def sumo_step(keys: jax.Array, states: Any, obs: jnp.ndarray, actions: jnp.ndarray, times: jnp.ndarray):
        states = states._replace(travel_params=times)
        next_obs, states, rewards, dones, info = jax.vmap(real_env.step)(keys, states, actions)
        day = Day(obs, actions, rewards, dones, next_obs, info["mean_time_cav"], info["mean_time_human"])
        return states, jax.tree_util.tree_map(lambda x: x[None], day)  # [1, P, ...]

    predict_days = jax.jit(lambda params, choices: predict(params, static, choices))

    def fresh_state() -> dict[str, Any]:
        k_init, k_real = jax.random.split(k_start)
        _, real = jax.vmap(real_env.reset)(jax.random.split(k_real, P))
        return {"runner": learner.init(k_init), "real": real, "params": p0}

    # ---- start or resume
    writer = RecordsWriter(folder, scn.agent_id, scn.agent_od, scn.agent_depart, flush_every=10**9)
    if human is not None:
        state = fresh_state()
        for rec in human.records:
            writer.add(rec)
        sample = SumoSample(human.calib_choices, human.calib_times, human.calib_arrived)
        if mode != "sumo" and len(sample):
            state["params"] = fit_params(p0, static, sample, FitConfig(steps=cfg.calib_steps))
        state["real"] = state["real"]._replace(humans=jax.vmap(lambda _: human.humans)(jnp.arange(P)))
        rounds_log: list[dict[str, Any]] = []
        start, sumo_done = 0, 0
        writer.flush()
        _checkpoint(folder, 0, state, sample, writer, rounds_log, sumo_done)
    else:
        found = latest_checkpoint(folder)
        if found is None:
            raise RuntimeError(f"{folder}: no checkpoint to resume from")
        start, ckpt = found
        state = _restore_state(ckpt / "state", fresh_state())
        meta = json.loads((ckpt / "meta.json").read_text())
        z = np.load(ckpt / "sumo_days.npz")
        sample = SumoSample(z["choices"], z["travel_time"], z["arrived"])
        rounds_log, sumo_done = meta["rounds"], meta["sumo_days"]
        _truncate_parts(writer, meta["record_parts"])
    runner = state["runner"]
    runner = runner._replace(env_states=RoutingEnv.with_travel_params(runner.env_states, state["params"]))
    real, params = state["real"], state["params"]

    T_sumo = n_rounds * sumo_per_round
    bar = _Progress(H + n_rounds * (sur_per_round + sumo_per_round) + E, progress)
    bar.update(H + start * (sur_per_round + sumo_per_round), "resume" if human is None else "human")
    for r in range(start, n_rounds):
        k_sur, k_act, k_step, k_upd = jax.random.split(jax.random.fold_in(k_rounds, r), 4)
        row: dict[str, Any] = {"round": r + 1}
        if sur_per_round:
            t0 = time.perf_counter()
            runner, m = sur_round(runner, k_sur)
            m = jax.tree_util.tree_map(lambda x: float(np.mean(x)), m)
            dt = time.perf_counter() - t0
            row |= {"surrogate_days": sur_per_round, "surrogate_s": dt, "sur_time_cav": m["time_cav"],
                    "sur_time_hdv": m["time_human"]}
            bar.update(sur_per_round, "train/surrogate", sur_days_s=sur_per_round / dt,
                       sur_tCAV=m["time_cav"], sur_tHDV=m["time_human"])
        if sumo_per_round:
            t0 = time.perf_counter()
            obs, actions, choices = act_explore(runner, jax.random.split(k_act, P), real)
            choices = np.asarray(choices)
            results = executor.run_days(scn, choices, [env_seed] * P, is_cav=is_cav)
            times = np.stack([res.travel_time for res in results]).astype(np.float32)
            real, days = sumo_step(jax.random.split(k_step, P), real, obs, actions, jnp.asarray(times))
            for u in range(cfg.sumo_updates):
                runner, _ = update(runner, days, jax.random.fold_in(k_upd, u))
            pred = np.asarray(predict_days(params, jnp.asarray(choices)))
            new = SumoSample.from_days(choices, results)
            sample = sample + new
            _record_days(writer, H + sumo_done, PHASE_TRAIN, choices, is_cav, results, days, cav_index)
            sumo_done += P
            if mode == "hybrid":
                rng = np.random.default_rng([seed, r, 0xF17])
                pick = rng.choice(len(sample), size=cfg.refit_days, replace=len(sample) < cfg.refit_days)
                sub = SumoSample(sample.choices[pick], sample.travel_time[pick], sample.arrived[pick])
                params = fit_params(params, static, sub, refit_cfg)
                runner = runner._replace(env_states=RoutingEnv.with_travel_params(runner.env_states, params))
            dt = time.perf_counter() - t0
            sumo_cav = float(times[:, cav_index].mean()) if cav_index.size else float("nan")
            sumo_hdv = float(times[:, ~is_cav].mean())
            row |= {"sumo_days": P, "sumo_s": dt, "sumo_time_cav": sumo_cav, "sumo_time_hdv": sumo_hdv,
                    "surrogate_mean_error": float((pred.mean(1) - times.mean(1)).mean() / times.mean()),
                    "surrogate_mape": float(np.mean(np.abs(pred - times) / times))}
            bar.update(P, "train/SUMO", sumo_days_s=P / dt, sumo_tCAV=sumo_cav, sumo_tHDV=sumo_hdv)
        rounds_log.append(row)
        writer.flush()
        _checkpoint(folder, r + 1, {"runner": runner, "real": real, "params": params}, sample, writer,
                    rounds_log, sumo_done)
        if stop_after_round is not None and r + 1 >= stop_after_round:
            bar.close()
            return {"stopped": r + 1}

    # ---- test: frozen greedy policies, SUMO only
    for start_day in range(0, E, P):
        b = min(P, E - start_day)
        kt = jax.random.fold_in(k_test, start_day)
        k_act, k_step = jax.random.split(kt)
        obs, actions, choices = act_greedy(runner, jax.random.split(k_act, P), real)
        choices = np.asarray(choices)[:b]
        results = executor.run_days(scn, choices, [env_seed] * b, is_cav=is_cav)
        times = np.zeros((P, n), np.float32)
        times[:b] = np.stack([res.travel_time for res in results])
        times[b:] = times[0]
        real2, days = sumo_step(jax.random.split(k_step, P), real, obs, actions, jnp.asarray(times))
        real = real2
        days = jax.tree_util.tree_map(lambda x, b=b: x[:, :b], days)
        _record_days(writer, H + T_sumo + start_day, PHASE_TEST, choices, is_cav, results, days, cav_index)
        bar.update(b, "test/SUMO", sumo_tCAV=float(times[:b, cav_index].mean()) if cav_index.size else 0.0)
    bar.close()
    writer.close()
    return {"rounds": rounds_log, "human_days": H, "sumo_training_days": T_sumo, "n_rounds": n_rounds,
            "surrogate_days": n_rounds * sur_per_round, "alg_config": dataclasses.asdict(alg_config)}


def _record_days(writer: Any, first_day_minus1: int, phase: str, choices: np.ndarray, is_cav: np.ndarray,
                 results: list[Any], days: Day, cav_index: np.ndarray) -> None:
    obs = np.asarray(days.obs[0])  # [P, C, D]
    rewards = np.asarray(days.reward[0])
    for p, res in enumerate(results):
        times = np.asarray(res.travel_time, dtype=np.float64)
        rew = -times.copy()
        rew[cav_index] = rewards[p]
        obs_all = np.full((choices.shape[1], obs.shape[-1]), np.nan, np.float32)
        obs_all[cav_index] = obs[p]
        writer.add(DayRecord(first_day_minus1 + p + 1, phase, choices[p], is_cav, res, rew, obs_all, True))


def _checkpoint(folder: Path, rounds_done: int, state: dict[str, Any], sample: Any, writer: Any,
                rounds_log: list[dict[str, Any]], sumo_done: int) -> None:
    """checkpoints/round_NNNNN/{state (orbax), sumo_days.npz, meta.json (written last)}; older
    checkpoints are removed once the new one is complete."""
    d = folder / CKPT_DIR / f"round_{rounds_done:05d}"
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    leaves = jax.tree_util.tree_leaves(state)
    save_checkpoint(d / "state", {f"{i:05d}": np.asarray(x) for i, x in enumerate(leaves)})
    _atomic_npz(d / "sumo_days.npz", choices=sample.choices, travel_time=sample.travel_time,
                arrived=sample.arrived)
    _atomic_json(d / "meta.json", {"rounds_done": rounds_done, "sumo_days": sumo_done,
                                   "record_parts": writer._n_parts, "rounds": rounds_log})
    for old in (folder / CKPT_DIR).glob("round_*"):
        if old != d:
            shutil.rmtree(old, ignore_errors=True)


def _restore_state(path: Path, target: dict[str, Any]) -> dict[str, Any]:
    """Orbax stores the state as numbered leaves; `target` (a fresh state) gives the tree."""
    leaves, treedef = jax.tree_util.tree_flatten(target)
    flat = restore_checkpoint(path, {f"{i:05d}": np.asarray(x) for i, x in enumerate(leaves)})
    return jax.tree_util.tree_unflatten(treedef, [jnp.asarray(flat[f"{i:05d}"]) for i in range(len(leaves))])


def _truncate_parts(writer: Any, n_parts: int) -> None:
    """Drop record parts written after the checkpoint (a killed round's days are replayed)."""
    for p in writer.parts.glob("part-*.parquet"):
        if int(p.stem.split("-")[1]) >= n_parts:
            p.unlink()
    writer._n_parts = n_parts

