"""`run_train` / `resume_train`: a train run of a request (urb_jax.runs.request), its seeds trained by
the hybrid trainer (urb_jax.training.hybrid) on one SUMO executor.

Each creates its results folder(s) and exp_config.json (the request recorded: `--resume` rebuilds it),
runs the human phase once for every seed, trains the seed groups and finishes: metric files and plots
from the records, rounds.csv, exp_config.json marked done with the wall time (urb_jax.runs.folder).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from urb_jax.core.choices import DEFAULT_NETWORK
from urb_jax.core.compile_cache import enable_compile_cache
from urb_jax.core.configio import to_dict
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.paths import day_store_bytes
from urb_jax.core.phase import enter_phase
from urb_jax.core.progress import Progress
from urb_jax.game.config import TaskConfig
from urb_jax.reporting.drift import drift_warning
from urb_jax.reporting.records import check_run_network, networks_dir_of, remove_parts
from urb_jax.reporting.urb_names import names_of, train_names
from urb_jax.runs.folder import (
    CONFIG_FILE,
    check_exp_id,
    create_results_dir,
    lock_run,
    machine,
    mark_done,
    read_run_config,
    run_status,
    seed_groups_of,
    source_commit,
    train_run_names,
    write_config,
    write_outputs,
    write_rounds,
)
from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.round_log import check_logger, round_log
from urb_jax.runs.run_log import log_run_to, with_run_log
from urb_jax.runs.setup import (
    ALG_GIVEN_KEY,
    RunResult,
    TrainSetup,
    check_emission_source,
    check_recorded_configs,
    check_runnable,
    experiment_config,
    first_reusable,
    fleet_record,
    load_setup,
    recorded_setup,
    stops_cleanly,
)
from urb_jax.runs.urb_configs import (
    CONFIG_ALIASES_KEY,
    OVERRIDES_KEY,
    config_aliases,
    run_overrides,
    train_override_record,
)
from urb_jax.sumo_bridge import DayExecutor, InProcessExecutor, SumoPool
from urb_jax.sumo_bridge.memo import LazyExecutor, day_store
from urb_jax.sumo_bridge.ray_executor import RayExecutor
from urb_jax.training.checkpoints import checkpoint_meta, latest_checkpoint
from urb_jax.training.human_phase import (
    JOURNAL_DIR,
    JOURNAL_KEY,
    SURROGATE_KEY,
    HumanPhase,
    journal,
    reuse_human_phase,
    run_human_phase,
    save_human_phase,
    surrogate_human_days,
)
from urb_jax.training.hybrid.plan import HybridConfig
from urb_jax.training.hybrid.trainer import Stopped, TrainSummary, check_group_records, train_group

log = logging.getLogger(__name__)


def make_executor(hyb: HybridConfig, log_dir: Path, kind: str = "pool",
                  ray_address: str | None = None) -> DayExecutor:
    """Where a train run's SUMO days run: `ray` actors, or local processes (`pool`; in-process for
    one worker); SUMO's logs go to `log_dir`."""
    config = hyb.sumo_config
    if kind == "ray":
        return RayExecutor(max(1, hyb.sumo_workers), config, log_dir=log_dir, day_timeout_s=hyb.day_timeout_s,
                           address=ray_address)
    if hyb.sumo_workers <= 1:
        return InProcessExecutor(config, log_file=log_dir / "sumo.log")
    return SumoPool(hyb.sumo_workers, config, log_dir=log_dir, day_timeout_s=hyb.day_timeout_s)


@contextlib.contextmanager
def _executor(given: DayExecutor | None, hyb: HybridConfig, log_dir: Path, kind: str,
              ray_address: str | None, stored: bool) -> Iterator[DayExecutor]:
    """The caller's executor, or a new one (`make_executor`) closed on exit; behind the SUMO day
    store (`day_store`) unless `stored` is False or the store is off."""
    if given is not None:
        yield day_store(given, stored)
        return
    # behind the store, SUMO's processes start with the first day not in it (none: never)
    def make() -> DayExecutor:
        return make_executor(hyb, log_dir, kind, ray_address)

    executor = LazyExecutor(make, hyb.sumo_config) if stored and day_store_bytes() else make()
    try:
        yield day_store(executor, stored)
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
    if req.day_store:
        day_store_bytes()  # a bad $URB_JAX_DAY_STORE_GB stops the run before it starts
    req = req.resolved()
    t0 = time.perf_counter()
    setup = load_setup(req)
    check_runnable(setup.task, setup.task_path, setup.scn.n_agents, train=True, mode=req.mode,
                   alg=req.alg, alg_config=setup.alg_config, surrogate_model=setup.hyb.surrogate_model)
    check_emission_source(setup, executor)
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
    with stops_cleanly(list(folders.values())), \
            _executor(executor, setup.hyb, first, req.executor, req.ray_address, req.day_store) as ex:
        if human is None:
            days = journal(ex, first)
            before = days.reused
            human = _simulate_human_phase(setup, days, req.env_seed, req.mode, req.progress)
            for s in req.seeds:  # repeated days of converged humans, and days in the day store
                configs[s]["human_phase_days_read_back"] = days.reused - before
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
    config = read_run_config(folder)
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
    for group in unfinished[1:]:  # refused now rather than after the groups ahead of it train
        for name in group:
            lock_run(results_dir / name)
        check_group_records([results_dir / name for name in group])
    return [r for group in unfinished for r in _resume_group(group, req, executor)]


def _resume_group(group: list[str], resume: ResumeRequest, executor: DayExecutor | None) -> list[RunResult]:
    """One seed group of `resume_train`, from its newest checkpoint (none: from its human phase)."""
    results_dir = Path(resume.results_dir)
    folders = [results_dir / name for name in group]
    for f in folders:
        lock_run(f)
    log_run_to(folders[0])
    configs = [read_run_config(f) for f in folders]
    recorded = configs[0]["train_args"]
    check_resume_overrides(folders[0], recorded.get("overrides") or [], resume.overrides)
    check_logger(resume.log or recorded.get("log"))
    now = {"results_dir": resume.results_dir, "progress": resume.progress, "day_store": resume.day_store,
           "networks_dir": networks_dir_of(configs[0], resume.networks_dir),
           "human_phase_from": configs[0].get("human_phase_from"),
           **{k: v for k, v in (("log", resume.log), ("executor", resume.executor),
                                ("ray_address", resume.ray_address)) if v is not None}}
    req, setup = recorded_setup(configs, **now)
    check_run_network(folders[0] / CONFIG_FILE, configs[0], setup.scn.n_agents, setup.scn.net_file)
    check_recorded_configs(folders[0] / CONFIG_FILE, configs[0], setup, ignore=RECORD_OWN_KEYS)
    check_emission_source(setup, executor)
    with stops_cleanly(folders), \
            _executor(executor, setup.hyb, folders[0], req.executor, req.ray_address, resume.day_store) as ex:
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


# exp_config.json keys of a config's field that a train run's record sets itself (see _train_config)
RECORD_OWN_KEYS = ("training_eps",)


def _train_config(setup: TrainSetup, req: TrainRequest) -> dict[str, Any]:
    """exp_config.json of every seed of a train run, before its seed and group keys."""
    scn, task, task_path, env, env_path, hyb, hyb_path, _ = setup
    return {
        **experiment_config(scn, task, task_path, env, env_path, req.env_seed, req.human_phase_from,
                             req.drop_unroutable),
        **{f"hybrid_{k}": v for k, v in to_dict(hyb).items()}, "hybrid_config": hyb_path.stem,
        **train_names(req.alg, req.mode, hyb_path.stem, hyb.train_days, req.alg_conf),
        ALG_GIVEN_KEY: to_dict(setup.alg_config),  # compared on resume (check_recorded_configs)
        "training_eps": None,  # the task's 200 is no train run's: the SUMO training days, set at the end
        "mode": req.mode,
        SURROGATE_KEY: surrogate_human_days(hyb, task.human_learning_episodes, req.mode != "sumo"),
        CONFIG_ALIASES_KEY: config_aliases(req),  # URB key names given, and what they set
        OVERRIDES_KEY: train_override_record(req),  # --set items as given and the values they set
        **fleet_record(scn, task, req.env_seed),  # competing fleets' CAVs; nothing without fleets
    }


def _simulate_human_phase(setup: TrainSetup, executor: DayExecutor, env_seed: int, mode: str,
                          progress: bool) -> HumanPhase:
    calibrate = mode != "sumo"
    enter_phase("the human phase (human SUMO days, calibration days)")
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
    if (warning := drift_warning(summary.surrogate_late_error)) is not None:
        log.warning("%s: %s", folder.name, warning)  # also in the run's run.log
    enter_phase("the metric files")
    metrics, phases = write_outputs(folder, H, T, hybrid=summary.surrogate_days > 0)
    write_rounds(folder, summary.rounds)
    mark_done(folder, config, **names_of(config), **phases, wall_time_s=round(wall, 2), training_days=T,
              sumo_training_days=T,
              surrogate_training_days=summary.surrogate_days, rounds=summary.n_rounds,
              alg_config_values=summary.alg_config, aon_same_humans=summary.aon_same_humans,
              seed_axis_used=summary.seed_axis, surrogate_late_error=summary.surrogate_late_error)
    drop_journal(folder.parent, config)
    return RunResult(folder, metrics, wall, summary=summary)


def drop_journal(root: Path, config: dict[str, Any]) -> None:
    """Remove the run's journal once every folder of the run (`run_folders`) is done."""
    holder = config.get(JOURNAL_KEY)
    if not holder or not (root / holder / JOURNAL_DIR).is_dir():
        return
    for name in config.get("run_folders", [holder]):
        if run_status(root / name) != "done":
            return
    shutil.rmtree(root / holder / JOURNAL_DIR, ignore_errors=True)
