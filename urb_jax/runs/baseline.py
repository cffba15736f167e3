"""`run_baseline` / `run_policy`: URB's experiment with a fixed CAV policy (AON, random, human, or a
policy trained elsewhere), every day in SUMO, in one results folder with every run's metric files."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from urb_jax.algorithms.baselines import CavPolicy, make_baseline
from urb_jax.algorithms.registry import load_baseline_config
from urb_jax.city.scenario import Scenario
from urb_jax.core.choices import BASELINE_SECTIONS, DEFAULT_NETWORK
from urb_jax.core.compile_cache import enable_compile_cache
from urb_jax.core.configio import in_section
from urb_jax.core.errors import ConfigError
from urb_jax.core.paths import day_store_bytes
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
from urb_jax.sumo_bridge import DayExecutor, InProcessExecutor, MemoExecutor
from urb_jax.sumo_bridge.memo import day_store
from urb_jax.training.human_phase import (
    check_replayable,
    load_replay,
)
from urb_jax.training.protocol import run_experiment


@with_run_log
def run_baseline(req: BaselineRequest, *, executor: DayExecutor | None = None,
                 task_overrides: dict[str, Any] | None = None,
                 human_phase_candidates: Sequence[str] = ()) -> RunResult:
    """One baseline experiment in results/<exp_id>/ (`req.human_phase_from`: days 1..H replayed from
    that run's records instead of simulated; `human_phase_candidates`: from the first of these
    finished runs that can be replayed, if any). `executor`: run the days on it instead of SUMO in
    this process (left open); `task_overrides`: task config values set directly (tests)."""
    return _run_policy(make_baseline(req.model), lambda task: baseline_names(req.model, task.training_eps),
                       req.model, req, executor, task_overrides, human_phase_candidates, baseline=req.model)


@with_run_log
def run_policy(policy: CavPolicy, req: BaselineRequest | None = None, *, executor: DayExecutor | None = None,
               task_overrides: dict[str, Any] | None = None) -> RunResult:
    """URB's experiment in SUMO with any `CavPolicy` (e.g. `algorithms.baselines.FixedPolicy` around
    a policy trained outside urb-jax), in results/<exp_id>/ with the metric files of every run;
    `req` says where and how (its `model` is not read: the policy is given). A policy trained
    elsewhere needs no SUMO training days: task_overrides={"training_eps": 0} runs the human phase
    (or replays it, `req.human_phase_from`) and the test days only."""
    labels = {"alg_config": "outside", "algorithm": policy.name,
              "script": "urb_jax.runs.baseline.run_policy"}
    return _run_policy(policy, lambda _task: labels, policy.name, req or BaselineRequest(), executor,
                       task_overrides)


def _run_policy(policy: CavPolicy, labels_of: Callable[[TaskConfig], dict[str, Any]], id_prefix: str,
                req: BaselineRequest, executor: DayExecutor | None, task_overrides: dict[str, Any] | None,
                human_phase_candidates: Sequence[str] = (), baseline: str = "") -> RunResult:
    """Every day in SUMO with `policy`; `labels_of(task)`: what exp_config.json calls the policy; the
    default id is `id_prefix`_<network>_<task>_s<env seed>; `baseline`: the baseline model it is
    (empty: a policy from outside)."""
    enable_compile_cache()
    if req.day_store:
        day_store_bytes()  # a bad $URB_JAX_DAY_STORE_GB stops the run before it starts
    net = req.net or DEFAULT_NETWORK
    loaded, task_overrides = _baseline_configs(req, task_overrides)
    task, task_path = loaded["task"].config, loaded["task"].path
    if task_overrides:
        task = dataclasses.replace(task, **task_overrides)
    env, env_path = loaded["env"].config, loaded["env"].path
    check_runnable(task, task_path, 0, train=False, baseline=baseline)
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
        return _run_baseline_days(folder, config, scn, task, env, policy, req.env_seed, executor, results_dir,
                                  human_phase_from, req.progress, t0, req.day_store)


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
                       env: EnvConfig, policy: CavPolicy, env_seed: int, executor: DayExecutor | None,
                       results_dir: Path, human_phase_from: str | None, progress: bool,
                       t0: float, stored: bool) -> RunResult:
    writer = RecordsWriter(folder, scn.agent_id, scn.agent_od, scn.agent_depart)
    # SUMO's warnings go to the run's sumo.log, not the terminal
    inner = InProcessExecutor(log_file=folder / "sumo.log") if executor is None else executor
    store = day_store(inner, stored)  # days already paid for by any run are read back
    memo = MemoExecutor(store)  # a repeated day (AON CAVs, frozen humans) runs once
    H, T = task.human_learning_episodes, task.training_eps
    days: DayExecutor = load_replay(results_dir / human_phase_from, config, scn.agent_id, H, memo
                                    ) if human_phase_from else memo
    try:
        run_experiment(scn, task, env, policy, env_seed=env_seed, executor=days, sink=writer,
                       progress=progress)
    finally:
        if executor is None:
            inner.close()
    writer.close()
    metrics, phases = write_outputs(folder, H, T)
    wall = time.perf_counter() - t0
    from_store = store.reused if isinstance(store, MemoExecutor) else 0
    mark_done(folder, config, **phases, wall_time_s=round(wall, 2), sumo_days_run=memo.simulated - from_store,
              sumo_days_repeated=memo.reused, sumo_days_from_store=from_store)
    return RunResult(folder, metrics, wall, days=H + T + task.test_eps,
                     replayed_days=H if human_phase_from else 0)
