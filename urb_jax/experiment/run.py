"""Runs below the commands: `run_train` / `resume_train` (the hybrid trainer) and `run_baseline`
(URB's experiment with a baseline policy, every day in SUMO).

Each creates its results folder(s) and exp_config.json, gets a SUMO executor (a process pool, Ray,
or the caller's), runs, and finishes: metric files and plots from the records, rounds.csv for
train runs, exp_config.json marked done with the wall time (`urb_jax.experiment.run_folder`).
The commands parse arguments and print; tests and benchmarks call these directly.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from urb_jax.algorithms.baselines import CavPolicy, make_baseline
from urb_jax.algorithms.registry import load_algo_config, load_baseline_config
from urb_jax.city.demand import scale_demand
from urb_jax.city.scenario import Scenario, load_scenario
from urb_jax.core.choices import BASELINE_SECTIONS, DEFAULT_NETWORK
from urb_jax.core.compile_cache import enable_compile_cache
from urb_jax.core.configio import in_section, to_dict
from urb_jax.core.errors import ConfigError, UrbJaxError
from urb_jax.core.interrupt import InterruptedRunError, disk_full, no_space, on_stop
from urb_jax.core.progress import Progress
from urb_jax.core.version import __version__
from urb_jax.experiment.checkpoints import checkpoint_meta, latest_checkpoint
from urb_jax.experiment.human_phase import (
    JOURNAL_KEY,
    SURROGATE_KEY,
    HumanPhase,
    check_replayable,
    drop_journal,
    first_reusable,
    journal,
    load_replay,
    reuse_human_phase,
    run_human_phase,
    save_human_phase,
    surrogate_human_days,
)
from urb_jax.experiment.hybrid.plan import AlgoConfig, HybridConfig, load_hybrid_config
from urb_jax.experiment.hybrid.trainer import Stopped, TrainSummary, train_group
from urb_jax.experiment.protocol import DayFn, run_experiment
from urb_jax.experiment.request import BaselineRequest, ResumeRequest, TrainRequest
from urb_jax.experiment.round_log import check_logger, round_log
from urb_jax.experiment.run_folder import (
    CONFIG_FILE,
    check_exp_id,
    create_results_dir,
    lock_run,
    machine,
    mark_done,
    run_status,
    seed_groups_of,
    source_commit,
    train_run_names,
    versions,
    write_config,
    write_outputs,
    write_rounds,
)
from urb_jax.experiment.run_log import log_run_to, with_run_log
from urb_jax.experiment.urb_configs import (
    CONFIG_ALIASES_KEY,
    OVERRIDES_KEY,
    config_aliases,
    override_record,
    run_overrides,
    train_override_record,
)
from urb_jax.game.config import EnvConfig, TaskConfig, load_env, load_env_config, load_task, load_task_config
from urb_jax.reporting.records import RecordsWriter, check_run_network, networks_dir_of, remove_parts
from urb_jax.reporting.urb_names import baseline_names, names_of, train_names
from urb_jax.sumo_bridge import DayExecutor, DayResult, InProcessExecutor, MemoExecutor, SumoPool, run_day
from urb_jax.sumo_bridge.ray_executor import RayExecutor


@dataclass(frozen=True)
class RunResult:
    """What a run returns to its command."""

    folder: Path
    metrics: dict[str, float]  # empty for a stopped run
    wall_time_s: float
    summary: TrainSummary | None = None  # train runs
    stopped: int | None = None  # train runs stopped by `stop_after_round` (tests): rounds done
    days: int = 0  # baseline runs: every day of the run
    replayed_days: int = 0  # baseline runs: human days replayed from --human-phase-from


class TrainSetup(NamedTuple):
    """Scenario and configs of a train run, loaded from its arguments."""

    scn: Scenario
    task: TaskConfig
    task_path: Path
    env: EnvConfig
    env_path: Path
    hyb: HybridConfig
    hyb_path: Path
    alg_config: AlgoConfig


def load_setup(req: TrainRequest) -> TrainSetup:
    """The run's scenario and configs, each config with its `--set` overrides."""
    ov = run_overrides(req.overrides)
    task, task_path = load_task_config(req.task_conf, in_section(ov, "task"))
    env, env_path = load_env_config(req.env_conf, in_section(ov, "env"))
    hyb, hyb_path = load_hybrid_config(req.hybrid_conf, in_section(ov, "hybrid"))
    if req.train_days is not None:  # the request refuses fewer than one day
        if any(o.key == "train_days" for o in in_section(ov, "hybrid")):
            raise ConfigError(f"--train-days {req.train_days} and --set hybrid.train_days both set the "
                              "training budget. Fix: give one of them.")
        hyb = dataclasses.replace(hyb, train_days=req.train_days)
    alg_config = load_algo_config(req.alg, req.alg_conf, in_section(ov, "alg"))
    scn = _scenario(req.net, req.networks_dir, req.env_seed, env, task, req.drop_unroutable)
    return TrainSetup(scn, task, task_path, env, env_path, hyb, hyb_path, alg_config)


def _scenario(net: str | None, networks_dir: str | None, env_seed: int, env: EnvConfig,
              task: TaskConfig, drop_unroutable: bool) -> Scenario:
    """The network's scenario with the task's demand (`drop_unroutable`: see load_scenario)."""
    scn = load_scenario(net or DEFAULT_NETWORK, networks_dir=networks_dir, env_seed=env_seed,
                        route_params=env.route_params(), drop_unroutable=drop_unroutable)
    return scale_demand(scn, task.demand_scale, seed=env_seed, mode=task.demand_mode,
                        jitter_s=task.demand_jitter_s)


def check_runnable(task: TaskConfig, task_path: Path, n_agents: int, *, train: bool, mode: str = "hybrid"
                   ) -> None:
    """Refuse, before any SUMO day, a task whose URB metrics could not exist: no human day (t_pre),
    no test day (t_CAV, t_test, WR), or, for training, no CAV to train; and a marginal credit
    without a calibrated surrogate to take its derivative (baselines, `--mode sumo`)."""
    where = f"task config {task_path}"
    needs = task.surrogate_reward_keys
    if needs and (not train or mode == "sumo"):
        given = " and ".join(f"'{k}' = {getattr(task, k)!r}" for k in needs)
        raise ConfigError(f"{where}: key(s) {given} pay each CAV from the calibrated surrogate's "
                          "derivative (the marginal credit; URB's marginal_cost_coefficient_beta), and this "
                          f"run has no surrogate ({'a baseline' if not train else '--mode sumo'}). Fix: "
                          "train with --mode hybrid or surrogate, or set reward_credit 'group' and "
                          "marginal_cost_beta 0 (URB's rewards).")
    if task.human_learning_episodes < 1:
        raise ConfigError(f"{where}: key 'human_learning_episodes' is 0, but t_pre is measured on the "
                          "last human days. Fix: set it to 1 or more (200 in URB's configs).")
    if task.test_eps < 1:
        raise ConfigError(f"{where}: key 'test_eps' is 0, but t_CAV, t_test and the win rate are measured "
                          "on test days. Fix: set it to 1 or more (100 in URB's configs).")
    if train and int(n_agents * task.ratio_machines) == 0:
        raise ConfigError(
            f"{where}: key 'ratio_machines' {task.ratio_machines} makes 0 of the {n_agents} agents CAVs, "
            "so there is nothing to train. Fix: set ratio_machines so that at least one agent is a CAV "
            f"(0.4 in URB's config1), or run the humans-only experiment with `urb-jax baseline "
            f"--task-conf {task_path}` (every day in SUMO).")


@contextlib.contextmanager
def _stops_cleanly(folders: list[Path], resumable: bool = True) -> Iterator[None]:
    """Ctrl-C and a full disk end a train run with the message that says what is kept and how to
    go on (`urb-jax train --resume`), instead of a traceback; the executor is closed by then. A
    forced stop (Ctrl-C inside a long jitted call, or pressed twice) prints the same line."""
    on_stop(lambda: _resume_hint(folders, resumable))
    try:
        yield
    except KeyboardInterrupt:
        raise InterruptedRunError(f"stopped by Ctrl-C. {_resume_hint(folders, resumable)}") from None
    except Exception as exc:  # orbax and pyarrow wrap the OS error in their own types
        if not no_space(exc):
            raise
        raise disk_full(folders[0].parent, f"({exc}) {_resume_hint(folders, resumable)}") from None
    finally:
        on_stop(None)


def _resume_hint(folders: list[Path], resumable: bool) -> str:
    """What a stopped run keeps and the command that continues it."""
    if not resumable:
        return (f"{folders[0]} is unfinished (a baseline run does not resume). Run the same command "
                "with --overwrite to start it again.")
    kept = latest_checkpoint(folders[0])
    done = (f"Its last complete checkpoint (round {kept[0]}) is kept" if kept else
            "It had no checkpoint yet; the SUMO days of its human phase are kept")
    return (f"{done}. Continue with: urb-jax train --resume {folders[0].name} "
            f"--results-dir {folders[0].parent}")


def make_executor(hyb: HybridConfig, log_dir: Path, kind: str = "pool",
                  ray_address: str | None = None) -> DayExecutor:
    """Where a train run's SUMO days run: `ray` actors, or local processes (`pool`; in-process for
    one worker); SUMO's logs go to `log_dir`."""
    if kind == "ray":
        return RayExecutor(max(1, hyb.sumo_workers), log_dir=log_dir, day_timeout_s=hyb.day_timeout_s,
                           address=ray_address)
    if hyb.sumo_workers <= 1:
        return InProcessExecutor(log_file=log_dir / "sumo.log")
    return SumoPool(hyb.sumo_workers, log_dir=log_dir, day_timeout_s=hyb.day_timeout_s)


@contextlib.contextmanager
def _executor(given: DayExecutor | None, hyb: HybridConfig, log_dir: Path, kind: str,
              ray_address: str | None) -> Iterator[DayExecutor]:
    """The caller's executor, or a new one (`make_executor`) closed on exit."""
    if given is not None:
        yield given
        return
    executor = make_executor(hyb, log_dir, kind, ray_address)
    try:
        yield executor
    finally:
        executor.close()


@with_run_log
def run_train(req: TrainRequest, *, executor: DayExecutor | None = None, stop_after_round: int | None = None,
              human_phase_candidates: Sequence[str] = ()) -> list[RunResult]:
    """Train every seed of `req` (sharing the human phase and the SUMO executor; groups of up to
    `max_vmapped_seeds` seeds train together); one results folder per seed. `executor`: run the
    SUMO days there instead of a new one of `req.executor`'s kind; `human_phase_candidates`: reuse
    the first of these finished runs' human phase that is this run's, if any (a suite's earlier
    runs); `stop_after_round`: stop there as a kill would (tests)."""
    enable_compile_cache()
    check_logger(req.log)
    req = req.resolved()
    t0 = time.perf_counter()
    setup = load_setup(req)
    check_runnable(setup.task, setup.task_path, setup.scn.n_agents, train=True, mode=req.mode)
    config = _train_config(setup, req)
    human = None  # checked before any results folder is created

    def reuse(source: Path) -> HumanPhase:
        return reuse_human_phase(source, config, setup.scn, setup.task, setup.hyb, req.env_seed,
                                 calibrate=req.mode != "sumo")

    if req.human_phase_from:
        human = reuse(Path(req.results_dir) / req.human_phase_from)
    elif found := first_reusable(Path(req.results_dir), human_phase_candidates, reuse):
        req, human = dataclasses.replace(req, human_phase_from=found[0]), found[1]
        config["human_phase_from"] = found[0]
    names = train_run_names(req.exp_id, req.alg, req.mode, req.net or DEFAULT_NETWORK, setup.task_path.stem,
                            list(req.seeds))
    folders = {s: create_results_dir(req.results_dir, name, req.overwrite)
               for s, name in zip(req.seeds, names, strict=True)}
    configs = _seed_configs(config, req, folders, setup.hyb)
    first = folders[req.seeds[0]]
    log_run_to(first)  # beside the SUMO logs (the executor's log_dir)
    with _stops_cleanly(list(folders.values())), \
            _executor(executor, setup.hyb, first, req.executor, req.ray_address) as ex:
        if human is None:
            days = journal(ex, first)
            human = _simulate_human_phase(setup, days, req.env_seed, req.mode, req.progress)
            for s in req.seeds:  # repeated days of converged humans, each run once
                configs[s]["human_phase_days_read_back"] = days.reused
        for folder in folders.values():
            save_human_phase(folder, human)
        t_human = time.perf_counter() - t0
        return _train_groups(setup, req, configs, folders, ex, human, t_human, stop_after_round)


def _seed_configs(config: dict[str, Any], req: TrainRequest, folders: dict[int, Path], hyb: HybridConfig
                  ) -> dict[int, dict[str, Any]]:
    """Each seed's exp_config.json, written before the first SUMO day so that a run stopped at any
    instant is a urb-jax run that `--resume` continues (and `--overwrite` may replace)."""
    size = max(1, hyb.max_vmapped_seeds)
    seeds = list(req.seeds)
    groups = [seeds[i:i + size] for i in range(0, len(seeds), size)]
    everyone = [folders[s].name for s in seeds]
    configs = {}
    for group in groups:
        for s in group:
            configs[s] = {**config, "seed": s, "train_args": req.record(s),
                          "group": [folders[g].name for g in group], "seeds_together": len(group),
                          "run_folders": everyone, JOURNAL_KEY: folders[seeds[0]].name}
            write_config(folders[s], configs[s])
    return configs


@with_run_log
def resume_train(req: ResumeRequest, *, executor: DayExecutor | None = None) -> list[RunResult]:
    """Continue the train run results/<exp_id>/ belongs to: every unfinished group of its seeds
    (`max_vmapped_seeds`), in seed order, each from its newest checkpoint, with the request it
    recorded (`TrainRequest.from_record`) and what `req` may change: the SUMO executor, the round
    logger and where the network is now. `req.overrides`, if given, must be the recorded ones
    (`check_resume_overrides`)."""
    enable_compile_cache()
    results_dir = Path(req.results_dir)
    folder = results_dir / check_exp_id(req.exp_id)
    if not (folder / CONFIG_FILE).is_file():
        raise UrbJaxError(f"{folder}: no urb-jax run '{req.exp_id}' here (no {CONFIG_FILE}). Fix: pass the "
                          f"id of a run in --results-dir (`ls {results_dir}`), or the --results-dir it used.")
    config = json.loads((folder / CONFIG_FILE).read_text())
    if "train_args" not in config:
        raise UrbJaxError(f"{folder}: the run was stopped before its first SUMO day (or is not a train run): "
                          "there is nothing to resume. Fix: run the same command again with --overwrite.")
    # the run's seed groups, in seed order (a run from before run_folders: its own group)
    groups = seed_groups_of(results_dir, config.get("run_folders", config.get("group", [req.exp_id])))
    unfinished = [g for g in groups if any(run_status(results_dir / n) != "done" for n in g)]
    if not unfinished:
        for name in (n for g in groups for n in g):
            remove_parts(results_dir / name)  # a kill after the last exp_config write left them
        raise UrbJaxError(f"{folder}: this run is already complete.")
    return [r for group in unfinished for r in _resume_group(group, req, executor)]


def _resume_group(group: list[str], resume: ResumeRequest, executor: DayExecutor | None) -> list[RunResult]:
    """One seed group of `resume_train`, from its newest checkpoint (none: from its human phase)."""
    results_dir = Path(resume.results_dir)
    folders = [results_dir / name for name in group]
    for f in folders:
        lock_run(f)
    log_run_to(folders[0])
    configs = [json.loads((f / CONFIG_FILE).read_text()) for f in folders]
    recorded = configs[0]["train_args"]
    check_resume_overrides(folders[0], recorded.get("overrides") or [], resume.overrides)
    check_logger(resume.log or recorded.get("log"))
    now = {"results_dir": resume.results_dir, "progress": resume.progress,
           "networks_dir": networks_dir_of(configs[0], resume.networks_dir),
           "human_phase_from": configs[0].get("human_phase_from"),
           **{k: v for k, v in (("log", resume.log), ("executor", resume.executor),
                                ("ray_address", resume.ray_address)) if v is not None}}
    req = TrainRequest.from_record(recorded, [c["train_args"]["seed"] for c in configs], **now)
    setup = load_setup(req)
    if "hybrid_seed_axis" not in configs[0]:  # started before the key: its seeds were vmapped
        setup = setup._replace(hyb=dataclasses.replace(setup.hyb, seed_axis="vmap"))
    check_run_network(folders[0] / CONFIG_FILE, configs[0], setup.scn.n_agents, setup.scn.net_file)
    with _stops_cleanly(folders), \
            _executor(executor, setup.hyb, folders[0], req.executor, req.ray_address) as ex:
        elapsed = _wall_clock(_wall_before(folders[0], configs))
        human = None
        if latest_checkpoint(folders[0]) is None:  # stopped before round 0's checkpoint: start over
            human = _human_phase_again(setup, req, configs[0], ex)
            for f in folders:
                save_human_phase(f, human)
        result = _train(setup, req, list(req.seeds), folders, ex, human, None, elapsed)
    wall = elapsed()
    here = machine()  # resumed_on: where each resume computed ("machine": where the run started)
    for c in configs:  # resumed_with_source: the code that finished it (versions: the code that started it)
        c.update(resumed=c.get("resumed", 0) + 1, resumed_with_source=source_commit(),
                 resumed_on=[*c.get("resumed_on", []), here])
    return _finish_group(folders, configs, result, setup.task, [wall] * len(folders))


def _wall_before(folder: Path, configs: list[dict[str, Any]]) -> float:
    """The group's wall seconds before this resume: what a stop wrote to exp_config.json, or, after
    a kill that wrote nothing, what its newest checkpoint recorded (the time since it is lost work)."""
    meta = checkpoint_meta(folder) or {}
    return max([meta.get("wall_s") or 0.0, *(c.get("wall_time_s", 0.0) for c in configs)])


def check_resume_overrides(folder: Path, recorded: Sequence[str], given: Sequence[str]) -> None:
    """A resume re-applies the run's recorded --set items; different ones would change the run's
    configs half-way, so they are refused (the same ones, however spelled, are accepted)."""
    if not given:
        return
    same = [(o.section, o.key, o.value) for o in run_overrides(given)] == \
        [(o.section, o.key, o.value) for o in run_overrides(recorded)]
    if not same:
        was = " ".join(f"--set {g}" for g in recorded) or "no --set"
        raise UrbJaxError(f"{folder}: --resume continues the run with the configs it started with ({was}, "
                          "re-applied on resume); --set " + " --set ".join(given) + " would change them "
                          "half-way. Fix: drop --set (the recorded overrides are re-applied), or start a new "
                          "run with another --id.")


def _human_phase_again(setup: TrainSetup, req: TrainRequest, config: dict[str, Any],
                       executor: DayExecutor) -> HumanPhase:
    """The human phase of a run resumed before its first checkpoint: replayed from the run it
    reuses, or simulated again with the days already done read back from the run's journal."""
    results_dir = Path(req.results_dir)
    if req.human_phase_from:
        return reuse_human_phase(results_dir / req.human_phase_from, config, setup.scn, setup.task,
                                 setup.hyb, req.env_seed, calibrate=req.mode != "sumo")
    holder = results_dir / config.get(JOURNAL_KEY, config["group"][0])
    return _simulate_human_phase(setup, journal(executor, holder), req.env_seed, req.mode, req.progress)


def _train_config(setup: TrainSetup, req: TrainRequest) -> dict[str, Any]:
    """exp_config.json of every seed of a train run, before its seed and group keys."""
    scn, task, task_path, env, env_path, hyb, hyb_path, _ = setup
    return {
        **_experiment_config(scn, task, task_path, env, env_path, req.env_seed, req.human_phase_from,
                             req.drop_unroutable),
        **{f"hybrid_{k}": v for k, v in to_dict(hyb).items()}, "hybrid_config": hyb_path.stem,
        **train_names(req.alg, req.mode, hyb_path.stem, hyb.train_days, req.alg_conf),
        "training_eps": None,  # the task's 200 is no train run's: the SUMO training days, set at the end
        "mode": req.mode,
        SURROGATE_KEY: surrogate_human_days(hyb, task.human_learning_episodes, req.mode != "sumo"),
        CONFIG_ALIASES_KEY: config_aliases(req),  # URB key names given, and what they set
        OVERRIDES_KEY: train_override_record(req),  # --set items as given and the values they set
    }


def _experiment_config(scn: Scenario, task: TaskConfig, task_path: Path, env: EnvConfig, env_path: Path,
                       env_seed: int, human_phase_from: str | None, drop_unroutable: bool) -> dict[str, Any]:
    """exp_config.json's keys of every run, train or baseline: the configs' values, the network and
    its agents, where and with what the run computed."""
    return {
        **to_dict(env), **to_dict(task),
        "network": scn.name, "net_file": scn.net_file, "env_seed": env_seed,
        "env_config": env_path.stem, "task_config": task_path.stem,
        "num_agents": scn.n_agents, "num_machines": int(scn.n_agents * task.ratio_machines),
        "exp_type": "normal", "human_days": task.human_learning_episodes,
        "versions": versions(), "machine": machine(), "urb_jax_version": __version__, "command": sys.argv,
        "status": "running", "human_phase_from": human_phase_from, **_dropped(scn, drop_unroutable),
    }


def _dropped(scn: Scenario, drop_unroutable: bool) -> dict[str, Any]:
    """exp_config.json keys of the --drop-unroutable opt-in: the choice and the agents it left out
    (`export-day` rebuilds the scenario from the choice)."""
    return {"drop_unroutable": drop_unroutable, "dropped_unroutable_agents": scn.dropped_record()}


def _simulate_human_phase(setup: TrainSetup, executor: DayExecutor, env_seed: int, mode: str,
                          progress: bool) -> HumanPhase:
    calibrate = mode != "sumo"
    bar = Progress(setup.task.human_learning_episodes + (setup.hyb.calib_varied_days if calibrate else 0),
                   progress, desc="human/SUMO")
    human = run_human_phase(setup.scn, setup.task, setup.hyb, executor, env_seed, bar, calibrate=calibrate)
    bar.close()
    return human


def _train_groups(setup: TrainSetup, req: TrainRequest, configs: dict[int, dict[str, Any]],
                  folders: dict[int, Path], executor: DayExecutor, human: HumanPhase, t_human: float,
                  stop_after_round: int | None) -> list[RunResult]:
    """The seeds in groups of up to `max_vmapped_seeds`, one group after another; the first
    group's wall time includes the human phase."""
    size = max(1, setup.hyb.max_vmapped_seeds)
    seeds = list(req.seeds)
    outs: list[RunResult] = []
    for gi, first in enumerate(range(0, len(seeds), size)):
        group = seeds[first:first + size]
        for s in group:
            configs[s]["human_phase_s"] = round(t_human, 2)
            write_config(folders[s], configs[s])
        elapsed = _wall_clock(t_human if gi == 0 else 0.0)
        result = _train(setup, req, group, [folders[s] for s in group], executor, human, stop_after_round,
                        elapsed)
        wall = elapsed()
        outs += _finish_group([folders[s] for s in group], [configs[s] for s in group], result, setup.task,
                              [wall] * len(group))
    return outs


def _train(setup: TrainSetup, req: TrainRequest, seeds: list[int], folders: list[Path],
           executor: DayExecutor, human: HumanPhase | None, stop_after_round: int | None,
           elapsed: Callable[[], float]) -> list[TrainSummary] | Stopped:
    with round_log(folders, req.log, resumed=human is None) as on_round:
        return train_group(scn=setup.scn, task=setup.task, env_cfg=setup.env, alg=req.alg,
                           alg_config=setup.alg_config, cfg=setup.hyb, mode=req.mode, seeds=seeds,
                           env_seed=req.env_seed, folders=folders, executor=executor, human=human,
                           progress=req.progress, stop_after_round=stop_after_round, on_round=on_round,
                           elapsed=elapsed)


def _wall_clock(before: float) -> Callable[[], float]:
    """The group's wall seconds so far: `before` (earlier processes', the human phase) plus this
    process's since now."""
    t0 = time.perf_counter()
    return lambda: before + time.perf_counter() - t0


def _finish_group(folders: list[Path], configs: list[dict[str, Any]], result: list[TrainSummary] | Stopped,
                  task: TaskConfig, walls: list[float]) -> list[RunResult]:
    """Each seed's metric files, plots, rounds.csv and finished exp_config.json; a stopped group
    (a simulated kill) is left as a crash would leave it, with its wall time."""
    if isinstance(result, Stopped):
        outs = []
        for folder, config, wall in zip(folders, configs, walls, strict=True):
            config.update(wall_time_s=round(wall, 2))
            write_config(folder, config)
            outs.append(RunResult(folder, {}, wall, stopped=result.rounds_done))
        return outs
    return [_finish_train(f, c, s, task.human_learning_episodes, w)
            for f, c, s, w in zip(folders, configs, result, walls, strict=True)]


def _finish_train(folder: Path, config: dict[str, Any], summary: TrainSummary, H: int,
                  wall: float) -> RunResult:
    T = summary.sumo_training_days
    metrics, phases = write_outputs(folder, H, T)
    write_rounds(folder, summary.rounds)
    mark_done(folder, config, **names_of(config), **phases, wall_time_s=round(wall, 2), training_days=T,
              sumo_training_days=T,
              surrogate_training_days=summary.surrogate_days, rounds=summary.n_rounds,
              alg_config_values=summary.alg_config, aon_same_humans=summary.aon_same_humans,
              seed_axis_used=summary.seed_axis)
    drop_journal(folder.parent, config)
    return RunResult(folder, metrics, wall, summary=summary)


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
              "script": "urb_jax.experiment.run.run_policy"}
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
    scn = _scenario(net, req.networks_dir, req.env_seed, env, task, req.drop_unroutable)  # error: no folder
    human_phase_from = req.human_phase_from
    config = {**_experiment_config(scn, task, task_path, env, env_path, req.env_seed, human_phase_from,
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
    with _stops_cleanly([folder], resumable=False):
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
