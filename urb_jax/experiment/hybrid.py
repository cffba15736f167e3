"""The hybrid trainer: URB's experiment with CAV training split between a calibrated surrogate
(jitted, many envs) and SUMO days that fine-tune the policies and refit the surrogate.

Seeds train together (`train_group`): the learner state has a leading seed axis, every jitted
piece is vmapped over it, and each round's SUMO days of all seeds go to the executor as one
batch. Phases (one results folder per training seed, URB layout):
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

from urb_jax.algorithms.learner import Day, Learner
from urb_jax.algorithms.registry import algorithm
from urb_jax.city.scenario import Scenario
from urb_jax.experiment.checkpoints import restore_checkpoint, save_checkpoint
from urb_jax.experiment.protocol import PHASE_TEST, PHASE_TRAIN, DayRecord, train_humans
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.env import RoutingEnv
from urb_jax.game.humans import HumanState, aon_routes
from urb_jax.game.rollout import act_by_levels, dependency_levels

MODES = ("hybrid", "sumo", "surrogate")
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
    max_vmapped_seeds: int = 8  # seeds trained together under vmap; longer seed lists train in groups
    route_bias: bool = True  # correct the surrogate by SUMO's mean residual per (agent, route) driven
    route_bias_prior_days: float = 2.0  # shrinkage: residual x count / (count + prior days)
    reuse_identical_test_days: bool = True  # SUMO is deterministic: a repeated test day runs once


def load_hybrid_config(name: str = "default") -> tuple[HybridConfig, Path]:
    from urb_jax.core.configio import find_config, load_json

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
    from urb_jax.sumo_bridge.types import ARRIVED
    from urb_jax.surrogate import build_static, init_params
    from urb_jax.surrogate.data import make_choices

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
    return algorithm(alg).make_learner(alg_config, env), alg_config


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
    from urb_jax.results.records import write_json

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


def train_seed(*, folder: Path, seed: int, **kw: Any) -> dict[str, Any]:
    """One seed: `train_group` with a group of one."""
    return train_group(folders=[folder], seeds=[seed], **kw)[0]


def _stack(trees: list[Any]) -> Any:
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *trees)


def _take(tree: Any, s: int) -> Any:
    return jax.tree_util.tree_map(lambda x: x[s], tree)


def train_group(
    *, scn: Scenario, task: TaskConfig, env_cfg: EnvConfig, alg: str, alg_config: Any, cfg: HybridConfig,
    mode: str, seeds: list[int], env_seed: int, folders: list[Path], executor: Any, human: HumanPhase | None,
    progress: bool = True, stop_after_round: int | None = None,
) -> list[dict[str, Any]]:
    """Train S seeds together, seed s in `folders[s]` (fresh when `human` is given, else resumed from
    the group checkpoint in `folders[0]`); returns one run summary per seed.

    Every learner function is vmapped over a leading seed axis (runner [S], real humans [S, P],
    surrogate parameters [S]); each round's S x P SUMO days go to the executor in one batch, and
    the test days likewise. Each seed refits its own surrogate on its own SUMO days (a loop over
    seeds outside the jitted training). `stop_after_round` simulates a kill (tests)."""
    from urb_jax.game.mutation import draw_cavs
    from urb_jax.results.records import RecordsWriter
    from urb_jax.sumo_bridge.memo import MemoExecutor
    from urb_jax.surrogate import SumoSample, build_static, init_params, predict
    from urb_jax.surrogate.calibrate import REFIT, FitConfig, fit_params, route_bias, without_bias

    if mode not in MODES:
        raise ValueError(f"mode {mode!r}: use one of {MODES}")
    S = len(seeds)
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
    p0 = {**init_params(static), "route_bias": jnp.zeros((n, scn.k), jnp.float32)}

    def fit(start: Any, sub: SumoSample, fit_cfg: Any, full: SumoSample) -> Any:
        """Gradient fit of the smooth model on `sub`, then the per-route residual on all SUMO days."""
        fitted = fit_params(without_bias(start), static, sub, fit_cfg)
        bias = (route_bias(fitted, static, full, cfg.route_bias_prior_days) if cfg.route_bias
                else jnp.zeros_like(p0["route_bias"]))
        return {**fitted, "route_bias": bias}
    humans0 = human.humans if human is not None else None
    # Placeholder human knowledge for a resume (shapes only; the checkpoint overwrites it).
    if humans0 is None:
        from urb_jax.game.humans import init_humans

        humans0 = init_humans(jax.random.PRNGKey(0), jnp.asarray(scn.fft), jnp.asarray(scn.route_valid), hp)
    env = RoutingEnv(scn, is_cav, sur_fn, human_init=humans0, default_params=p0, **common)
    real_env = RoutingEnv(scn, is_cav, human_init=humans0, **common)  # SUMO days: step_with_times
    probe, _ = learner_for(alg, alg_config, env, cfg, 1, mode)
    n_rounds, n_iters_round, sur_per_round, sumo_per_round = plan_rounds(cfg, mode, probe.days_per_iter)
    learner, alg_config = learner_for(alg, alg_config, env, cfg, n_rounds, mode, n_iters_round)
    P = cfg.sumo_days_per_round
    levels = dependency_levels(env)
    keys = jax.vmap(lambda s: jax.random.split(jax.random.PRNGKey(s), 3))(jnp.asarray(seeds))
    k_rounds, k_test, k_start = keys[:, 0], keys[:, 1], keys[:, 2]  # [S, 2] each
    refit_cfg = dataclasses.replace(REFIT, steps=cfg.refit_steps)

    # ---- jitted pieces, each vmapped over the leading seed axis
    def _sur_round(runner: Any, key: jax.Array):
        return jax.lax.scan(learner.iteration, runner, jax.random.split(key, n_iters_round))

    sur_round = jax.jit(jax.vmap(_sur_round))
    update = jax.jit(jax.vmap(learner.update_from_days))

    def _act(runner: Any, keys: jax.Array, states: Any, explore: bool):
        pol = learner.policy(runner, explore)
        obs, actions = jax.vmap(lambda k, s: act_by_levels(real_env, k, s, pol, levels))(keys, states)
        return obs, actions, jax.vmap(real_env.joint_actions)(states, actions)

    act_explore = jax.jit(jax.vmap(lambda r, k, s: _act(r, k, s, True)))
    act_greedy = jax.jit(jax.vmap(lambda r, k, s: _act(r, k, s, False)))

    def _sumo_step(keys: jax.Array, states: Any, obs: jnp.ndarray, actions: jnp.ndarray, times: jnp.ndarray):
        step = jax.vmap(real_env.step_with_times)
        next_obs, states, rewards, dones, info = step(keys, states, actions, times)
        day = Day(obs, actions, rewards, dones, next_obs, info["mean_time_cav"], info["mean_time_human"])
        return states, jax.tree_util.tree_map(lambda x: x[None], day)  # [1, P, ...]

    sumo_step = jax.jit(jax.vmap(_sumo_step))
    predict_days = jax.jit(jax.vmap(lambda params, choices: predict(params, static, choices)))
    split_p = jax.vmap(lambda k: jax.random.split(k, P))
    round_keys = jax.jit(jax.vmap(lambda k, r: jax.random.split(jax.random.fold_in(k, r), 4), (0, None)))

    @jax.jit
    def fresh_runner_real(k_start: jax.Array):
        def one(k: jax.Array):
            k_init, k_real = jax.random.split(k)
            _, real = jax.vmap(real_env.reset)(jax.random.split(k_real, P))
            return learner.init(k_init), real

        return jax.vmap(one)(k_start)

    def fresh_state() -> dict[str, Any]:
        runner, real = fresh_runner_real(k_start)
        return {"runner": runner, "real": real, "params": _stack([p0] * S)}

    # ---- start or resume
    writers = [RecordsWriter(f, scn.agent_id, scn.agent_od, scn.agent_depart, flush_every=10**9)
               for f in folders]
    lead = folders[0]
    if human is not None:
        state = fresh_state()
        for writer in writers:
            for rec in human.records:
                writer.add(rec)
        sample0 = SumoSample(human.calib_choices, human.calib_times, human.calib_arrived)
        if mode != "sumo" and len(sample0):
            fitted = fit(p0, sample0, FitConfig(steps=cfg.calib_steps), sample0)
            state["params"] = _stack([fitted] * S)  # the same calibration for every seed
        state["real"] = state["real"]._replace(
            humans=jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (S, P, *x.shape)), human.humans))
        samples = [sample0] * S
        rounds_logs: list[list[dict[str, Any]]] = [[] for _ in seeds]
        start, sumo_done = 0, 0
        for writer in writers:
            writer.flush()
        _checkpoint(lead, 0, state, samples, writers, rounds_logs, sumo_done, seeds, folders)
    else:
        found = latest_checkpoint(lead)
        if found is None:
            raise RuntimeError(f"{lead}: no checkpoint to resume from")
        start, ckpt = found
        meta = json.loads((ckpt / "meta.json").read_text())
        if meta.get("seeds", seeds) != list(seeds):
            raise RuntimeError(f"{ckpt}: checkpoint holds seeds {meta['seeds']}, not {list(seeds)}")
        state = _restore_state(ckpt / "state", fresh_state())
        z = np.load(ckpt / "sumo_days.npz")
        samples = [SumoSample(z[f"choices_{i}"], z[f"travel_time_{i}"], z[f"arrived_{i}"]) for i in range(S)]
        rounds_logs, sumo_done = meta["rounds"], meta["sumo_days"]
        for writer, parts in zip(writers, meta["record_parts"], strict=True):
            _truncate_parts(writer, parts)
    runner, real, params = state["runner"], state["real"], state["params"]
    runner = runner._replace(env_params=params)

    T_sumo = n_rounds * sumo_per_round
    tag = f"[{S} seeds] " if S > 1 else ""
    bar = _Progress(S * (H + n_rounds * (sur_per_round + sumo_per_round) + E), progress)
    bar.update(S * (H + start * (sur_per_round + sumo_per_round)),
               tag + ("resume" if human is None else "human"))
    for r in range(start, n_rounds):
        rk = round_keys(k_rounds, r)  # [S, 4, 2]
        k_sur, k_act, k_step, k_upd = rk[:, 0], rk[:, 1], rk[:, 2], rk[:, 3]
        rows: list[dict[str, Any]] = [{"round": r + 1} for _ in seeds]
        if sur_per_round:
            t0 = time.perf_counter()
            runner, m = sur_round(runner, k_sur)
            m = {k: np.asarray(v).reshape(S, -1).mean(1) for k, v in m.items()}
            dt = time.perf_counter() - t0
            for i, row in enumerate(rows):
                row |= {"surrogate_days": sur_per_round, "surrogate_s": dt,
                        "sur_time_cav": float(m["time_cav"][i]), "sur_time_hdv": float(m["time_human"][i])}
            bar.update(S * sur_per_round, tag + "train/surrogate", sur_days_s=S * sur_per_round / dt,
                       sur_tCAV=float(m["time_cav"].mean()), sur_tHDV=float(m["time_human"].mean()))
        if sumo_per_round:
            t0 = time.perf_counter()
            obs, actions, choices = act_explore(runner, split_p(k_act), real)
            choices = np.asarray(choices)  # [S, P, N]
            results = executor.run_days(scn, choices.reshape(S * P, n), [env_seed] * (S * P), is_cav=is_cav)
            times = np.stack([res.travel_time for res in results]).astype(np.float32).reshape(S, P, n)
            real, days = sumo_step(split_p(k_step), real, obs, actions, jnp.asarray(times))
            for u in range(cfg.sumo_updates):
                runner, _ = update(runner, days, jax.vmap(lambda k, u=u: jax.random.fold_in(k, u))(k_upd))
            pred = np.asarray(predict_days(params, jnp.asarray(choices)))
            new_params = []
            for i, seed in enumerate(seeds):
                res_i = results[i * P:(i + 1) * P]
                samples[i] = samples[i] + SumoSample.from_days(choices[i], res_i)
                _record_days(writers[i], H + sumo_done, PHASE_TRAIN, choices[i], is_cav, res_i,
                             _take(days, i), cav_index)
                if mode == "hybrid":
                    sample = samples[i]
                    rng = np.random.default_rng([seed, r, 0xF17])
                    pick = rng.choice(len(sample), size=cfg.refit_days, replace=len(sample) < cfg.refit_days)
                    sub = SumoSample(sample.choices[pick], sample.travel_time[pick], sample.arrived[pick])
                    new_params.append(fit(_take(params, i), sub, refit_cfg, sample))
            sumo_done += P
            if mode == "hybrid":
                params = _stack(new_params)
                runner = runner._replace(env_params=params)
            dt = time.perf_counter() - t0
            for i, row in enumerate(rows):
                t = times[i]
                sumo_cav = float(t[:, cav_index].mean()) if cav_index.size else float("nan")
                row |= {"sumo_days": P, "sumo_s": dt, "sumo_time_cav": sumo_cav,
                        "sumo_time_hdv": float(t[:, ~is_cav].mean()),
                        "surrogate_mean_error": float((pred[i].mean(1) - t.mean(1)).mean() / t.mean()),
                        "surrogate_mape": float(np.mean(np.abs(pred[i] - t) / t))}
            bar.update(S * P, tag + "train/SUMO", sumo_days_s=S * P / dt,
                       sumo_tCAV=float(np.mean([row["sumo_time_cav"] for row in rows])),
                       sumo_tHDV=float(np.mean([row["sumo_time_hdv"] for row in rows])))
        for log, row in zip(rounds_logs, rows, strict=True):
            log.append(row)
        for writer in writers:
            writer.flush()
        _checkpoint(lead, r + 1, {"runner": runner, "real": real, "params": params}, samples, writers,
                    rounds_logs, sumo_done, seeds, folders)
        if stop_after_round is not None and r + 1 >= stop_after_round:
            bar.close()
            return [{"stopped": r + 1} for _ in seeds]

    # ---- test: frozen greedy policies, SUMO only; S x b days per executor batch
    test_executor = MemoExecutor(executor) if cfg.reuse_identical_test_days else executor
    first_test_choices = None
    for start_day in range(0, E, P):
        b = min(P, E - start_day)
        kt = jax.vmap(lambda k, d=start_day: jax.random.split(jax.random.fold_in(k, d)))(k_test)
        obs, actions, choices = act_greedy(runner, split_p(kt[:, 0]), real)
        choices = np.asarray(choices)[:, :b]  # [S, b, N]
        if start_day == 0:
            first_test_choices = choices[0, 0]
        results = test_executor.run_days(scn, choices.reshape(S * b, n), [env_seed] * (S * b), is_cav=is_cav)
        times = np.zeros((S, P, n), np.float32)
        times[:, :b] = np.stack([res.travel_time for res in results]).reshape(S, b, n)
        times[:, b:] = times[:, :1]
        real, days = sumo_step(split_p(kt[:, 1]), real, obs, actions, jnp.asarray(times))
        for i in range(S):
            days_i = jax.tree_util.tree_map(lambda x, b=b, i=i: x[i, :, :b], days)
            _record_days(writers[i], H + T_sumo + start_day, PHASE_TEST, choices[i], is_cav,
                         results[i * b:(i + 1) * b], days_i, cav_index)
        bar.update(S * b, tag + "test/SUMO",
                   sumo_tCAV=float(times[:, :b][..., cav_index].mean()) if cav_index.size else 0.0)
    aon = (aon_same_humans(scn, first_test_choices, is_cav, test_executor, env_seed)
           if first_test_choices is not None else {})
    bar.close()
    for writer in writers:
        writer.close()
    return [{"rounds": log, "human_days": H, "sumo_training_days": T_sumo, "n_rounds": n_rounds,
             "surrogate_days": n_rounds * sur_per_round, "alg_config": dataclasses.asdict(alg_config),
             "seeds_together": S, "aon_same_humans": aon} for log in rounds_logs]


def aon_same_humans(scn: Scenario, choices: np.ndarray, is_cav: np.ndarray, executor: Any,
                    env_seed: int) -> dict[str, float]:
    """One SUMO day: `choices`' humans, the CAVs on their minimum free-flow route.

    The quality bar is "t_CAV at or below AON's", and with frozen deterministic humans (task
    config1, Scenario 1) this day *is* URB's AON baseline on the same test humans (with stochastic
    humans, AON on the first test day's human draw), so each run reports
    it next to its own t_CAV (exp_config.json) at the cost of one SUMO day. Not a run day: it is
    not in the records or in any metric."""
    mixed = np.where(is_cav, aon_routes(scn.fft, scn.route_valid), choices)
    res = executor.run_days(scn, mixed[None], [env_seed], is_cav=is_cav)[0]
    nan = float("nan")
    return {"t_CAV": float(res.travel_time[is_cav].mean()) if is_cav.any() else nan,
            "t_HDV": float(res.travel_time[~is_cav].mean()) if (~is_cav).any() else nan,
            # the published tables' measure (urb_jax.metrics.DURATION_COLUMNS)
            "t_CAV_duration": float(np.nanmean(res.duration[is_cav]) / 60) if is_cav.any() else nan}


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


def _checkpoint(folder: Path, rounds_done: int, state: dict[str, Any], samples: list[Any], writers: list[Any],
                rounds_logs: list[list[dict[str, Any]]], sumo_done: int, seeds: list[int],
                folders: list[Path]) -> None:
    """checkpoints/round_NNNNN/{state (orbax, every seed), sumo_days.npz (per seed), meta.json
    (written last)} in the group's first folder; older checkpoints are removed once the new one
    is complete."""
    d = folder / CKPT_DIR / f"round_{rounds_done:05d}"
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    leaves = jax.tree_util.tree_leaves(state)
    save_checkpoint(d / "state", {f"{i:05d}": np.asarray(x) for i, x in enumerate(leaves)})
    arrays = {}
    for i, sample in enumerate(samples):
        arrays |= {f"choices_{i}": sample.choices, f"travel_time_{i}": sample.travel_time,
                   f"arrived_{i}": sample.arrived}
    _atomic_npz(d / "sumo_days.npz", **arrays)
    _atomic_json(d / "meta.json", {"rounds_done": rounds_done, "sumo_days": sumo_done, "seeds": list(seeds),
                                   "folders": [f.name for f in folders],
                                   "record_parts": [w._n_parts for w in writers], "rounds": rounds_logs})
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

