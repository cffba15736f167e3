"""`run_baseline` / `run_policy`: URB's experiment with a fixed CAV policy (AON, random, human, or a
policy trained elsewhere), every day in SUMO, in one results folder with every run's metric files."""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from urb_jax.algorithms.baselines import CavPolicy, make_baseline
from urb_jax.algorithms.registry import load_baseline_config
from urb_jax.city.scenario import Scenario
from urb_jax.core.choices import BASELINE_SECTIONS, DEFAULT_NETWORK
from urb_jax.core.compile_cache import enable_compile_cache
from urb_jax.core.configio import in_section
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import EnvConfig, TaskConfig, load_env, load_task
from urb_jax.reporting.records import RecordsWriter
from urb_jax.reporting.urb_names import baseline_names
from urb_jax.runs.folder import (
    create_results_dir,
    mark_done,
    write_config,
    write_outputs,
)
from urb_jax.runs.request import BaselineRequest
from urb_jax.runs.run_log import log_run_to, with_run_log
from urb_jax.runs.setup import (
    RunResult,
    check_runnable,
    experiment_config,
    first_reusable,
    scenario_of,
    stops_cleanly,
)
from urb_jax.runs.urb_configs import (
    OVERRIDES_KEY,
    override_record,
    run_overrides,
)
from urb_jax.sumo_bridge import DayExecutor, DayResult, MemoExecutor, run_day
from urb_jax.training.human_phase import (
    check_replayable,
    load_replay,
)
from urb_jax.training.protocol import DayFn, run_experiment


@with_run_log
def run_baseline(req: BaselineRequest, *, day_fn: DayFn | None = None,
                 task_overrides: dict[str, Any] | None = None,
                 human_phase_candidates: Sequence[str] = ()) -> RunResult:
    """One baseline experiment in results/<exp_id>/ (`req.human_phase_from`: days 1..H replayed from
    that run's records instead of simulated; `human_phase_candidates`: from the first of these
    finished runs that can be replayed, if any). `day_fn`: simulate each day with it instead of
    SUMO; `task_overrides`: task config values set directly (tests)."""
    return _run_policy(make_baseline(req.model), lambda task: baseline_names(req.model, task.training_eps),
                       req.model, req, day_fn, task_overrides, human_phase_candidates)


@with_run_log
def run_policy(policy: CavPolicy, req: BaselineRequest | None = None, *, day_fn: DayFn | None = None,
               task_overrides: dict[str, Any] | None = None) -> RunResult:
    """URB's experiment in SUMO with any `CavPolicy` (e.g. `algorithms.baselines.FixedPolicy` around
    a policy trained outside urb-jax), in results/<exp_id>/ with the metric files of every run;
    `req` says where and how (its `model` is not read: the policy is given). A policy trained
    elsewhere needs no SUMO training days: task_overrides={"training_eps": 0} runs the human phase
    (or replays it, `req.human_phase_from`) and the test days only."""
    labels = {"alg_config": "outside", "algorithm": policy.name,
              "script": "urb_jax.runs.baseline.run_policy"}
    return _run_policy(policy, lambda _task: labels, policy.name, req or BaselineRequest(), day_fn,
                       task_overrides)


def _run_policy(policy: CavPolicy, labels_of: Callable[[TaskConfig], dict[str, Any]], id_prefix: str,
                req: BaselineRequest, day_fn: DayFn | None, task_overrides: dict[str, Any] | None,
                human_phase_candidates: Sequence[str] = ()) -> RunResult:
    """Every day in SUMO with `policy`; `labels_of(task)`: what exp_config.json calls the policy; the
    default id is `id_prefix`_<network>_<task>_s<env seed>."""
    enable_compile_cache()
    net = req.net or DEFAULT_NETWORK
    loaded, task_overrides = _baseline_configs(req, task_overrides)
    task, task_path = loaded["task"].config, loaded["task"].path
    if task_overrides:
        task = dataclasses.replace(task, **task_overrides)
    env, env_path = loaded["env"].config, loaded["env"].path
    check_runnable(task, task_path, 0, train=False)
    exp_id = req.exp_id or f"{id_prefix}_{Path(net).name}_{task_path.stem}_s{req.env_seed}"
    t0 = time.perf_counter()
    scn = scenario_of(net, req.networks_dir, req.env_seed, env, task, req.drop_unroutable)  # error: no folder
    human_phase_from = req.human_phase_from
    config = {**experiment_config(scn, task, task_path, env, env_path, req.env_seed, human_phase_from,
                                   req.drop_unroutable),
              **labels_of(task), "training_days": task.training_eps,
              OVERRIDES_KEY: override_record(req.overrides, loaded)}
    results_dir = Path(req.results_dir)
    if human_phase_from:  # a source that cannot be replayed: no folder either
        check_replayable(results_dir / human_phase_from, config, task.human_learning_episodes)
    elif found := first_reusable(results_dir, human_phase_candidates,
                                 lambda src: check_replayable(src, config, task.human_learning_episodes)):
        human_phase_from = config["human_phase_from"] = found[0]
    folder = create_results_dir(results_dir, exp_id, req.overwrite)
    log_run_to(folder)
    write_config(folder, config)
    with stops_cleanly([folder], resumable=False):
        return _run_baseline_days(folder, config, scn, task, env, policy, req.env_seed, day_fn, results_dir,
                                  human_phase_from, req.progress, t0)


def _baseline_configs(req: BaselineRequest, task_overrides: dict[str, Any] | None
                      ) -> tuple[dict[str, Any], dict[str, Any]]:
    """A baseline's task, env and (with `alg_conf`) baseline algo configs with their --set items,
    and the task keys the algo config sets (URB's baselines.py reads training_eps from it)."""
    ov = run_overrides(req.overrides, BASELINE_SECTIONS)
    loaded: dict[str, Any] = {"task": load_task(req.task_conf, in_section(ov, "task")),
                              "env": load_env(req.env_conf, in_section(ov, "env"))}
    task_overrides = dict(task_overrides or {})
    if req.alg_conf is None and in_section(ov, "alg"):
        raise ConfigError(f"--set {in_section(ov, 'alg')[0].given}: a baseline reads an algorithm config "
                          "only with --alg-conf (URB's baseline config: training_eps). Fix: --set "
                          "task.training_eps=N, or pass --alg-conf.")
    if req.alg_conf is not None:
        if any(o.key == "training_eps" for o in in_section(ov, "task")):
            raise ConfigError("--set task.training_eps and --alg-conf both set the CAV training days (URB's "
                              "baselines read them from the algo config). Fix: --set alg.training_eps=N.")
        loaded["alg"] = load_baseline_config(req.alg_conf, in_section(ov, "alg"))
        task_overrides["training_eps"] = loaded["alg"].config.training_eps
    return loaded, task_overrides


def _run_baseline_days(folder: Path, config: dict[str, Any], scn: Scenario, task: TaskConfig,
                       env: EnvConfig, policy: CavPolicy, env_seed: int, day_fn: DayFn | None,
                       results_dir: Path, human_phase_from: str | None, progress: bool,
                       t0: float) -> RunResult:
    writer = RecordsWriter(folder, scn.agent_id, scn.agent_od, scn.agent_depart)
    if day_fn is None:  # SUMO's warnings go to the run's sumo.log, not the terminal
        day_fn = functools.partial(run_day, log_file=folder / "sumo.log")
    memo = MemoExecutor(_DayFnExecutor(day_fn))  # a repeated day (AON CAVs, frozen humans) runs once
    day_fn = _one_day(memo)
    H, T = task.human_learning_episodes, task.training_eps
    if human_phase_from:
        day_fn = load_replay(results_dir / human_phase_from, config, scn.agent_id, H, day_fn)
    run_experiment(scn, task, env, policy, env_seed=env_seed, day_fn=day_fn, sink=writer, progress=progress)
    writer.close()
    metrics, phases = write_outputs(folder, H, T)
    wall = time.perf_counter() - t0
    mark_done(folder, config, **phases, wall_time_s=round(wall, 2), sumo_days_run=memo.simulated,
              sumo_days_repeated=memo.reused)
    return RunResult(folder, metrics, wall, days=H + T + task.test_eps,
                     replayed_days=H if human_phase_from else 0)


class _DayFnExecutor:
    """A day function (`DayFn`) as a `DayExecutor`, so the one day cache can sit in front of it."""

    def __init__(self, day_fn: DayFn) -> None:
        self.day_fn = day_fn

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        masks = [None] * len(choices) if is_cav is None else list(is_cav)
        return [self.day_fn(scenario, c, seed=int(s), is_cav=m) for c, s, m in zip(choices, seeds, masks,
                                                                                     strict=True)]

    def close(self) -> None:
        pass


def _one_day(executor: DayExecutor) -> DayFn:
    """The `DayFn` of one-day batches on `executor`."""
    def day(scenario: Scenario, choices: np.ndarray, *, seed: int, is_cav: np.ndarray | None = None
            ) -> DayResult:
        return executor.run_days(scenario, np.asarray(choices)[None], [seed],
                                 None if is_cav is None else np.asarray(is_cav)[None])[0]
    return day
