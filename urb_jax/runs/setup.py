"""What every run does before and around its days: load a train run's scenario and configs
(`load_setup`), refuse a task whose URB metrics could not exist (`check_runnable`), the exp_config.json
keys every run shares (`experiment_config`), and a clean stop on Ctrl-C or a full disk with the line
that continues the run (`stops_cleanly`)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np

from urb_jax.algorithms.fleets import FleetsAlgoConfig
from urb_jax.algorithms.registry import canonical, load_algo_config
from urb_jax.city.demand import scale_demand
from urb_jax.city.scenario import Scenario, load_scenario
from urb_jax.core.choices import DEFAULT_NETWORK
from urb_jax.core.configio import Override, in_section, to_dict
from urb_jax.core.errors import ConfigError, UrbJaxError
from urb_jax.core.interrupt import InterruptedRunError, disk_full, no_space, on_stop, stop_cause
from urb_jax.core.phase import current_phase, enter_phase, is_out_of_memory, memory_hint
from urb_jax.core.version import __version__
from urb_jax.game.config import EnvConfig, TaskConfig, load_env_config, load_task_config
from urb_jax.game.mutation import draw_cavs, split_fleets
from urb_jax.reporting.records import FLEETS_KEY
from urb_jax.runs.folder import (
    machine,
    run_status,
    versions,
)
from urb_jax.runs.request import TrainRequest, default_alg
from urb_jax.runs.urb_configs import (
    run_overrides,
)
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.training.checkpoints import latest_checkpoint
from urb_jax.training.hybrid.plan import AlgoConfig, HybridConfig, load_hybrid_config
from urb_jax.training.hybrid.trainer import TrainSummary


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
    alg = req.alg or default_alg(req.task_conf)
    if task.fleets:
        alg_config: AlgoConfig = fleets_algo_config(task, task_path, alg, req.alg_conf, in_section(ov, "alg"))
    else:
        alg_config = load_algo_config(alg, req.alg_conf, in_section(ov, "alg"))
    scn = scenario_of(req.net, req.networks_dir, req.env_seed, env, task, req.drop_unroutable)
    return TrainSetup(scn, task, task_path, env, env_path, hyb, hyb_path, alg_config)


def fleets_algo_config(task: TaskConfig, task_path: Path, alg: str, alg_conf: str,
                       alg_overrides: Sequence[Override]) -> FleetsAlgoConfig:
    """Each fleet's algorithm config (its own `alg` and `alg_conf`); the run's --alg names the run
    and must be the first fleet's, and --alg-conf and --set alg.* are refused (a fleet's config is
    its `alg_conf`, one file per fleet)."""
    where = f"task config {task_path}: key 'fleets'"
    first = task.fleets[0]
    if canonical(alg) != first.alg:
        raise ConfigError(f"{where} names each fleet's algorithm, and the run is named by the first fleet's "
                          f"({first.alg}); --alg is {alg}. Fix: leave --alg out, or pass --alg {first.alg}.")
    if alg_conf != "config1" or alg_overrides:
        given = "--set alg.*" if alg_overrides else f"--alg-conf {alg_conf}"
        raise ConfigError(f"{where}: each fleet's algorithm config is its own key 'alg_conf'; {given} would "
                          "not say which fleet's. Fix: set alg_conf in the fleet's entry (a config id or "
                          "a .json path).")
    return FleetsAlgoConfig(tuple(f.name for f in task.fleets), tuple(f.alg for f in task.fleets),
                            tuple(load_algo_config(f.alg, f.alg_conf) for f in task.fleets))


def fleet_record(scn: Scenario, task: TaskConfig, env_seed: int) -> dict[str, Any]:
    """exp_config.json's fleets (FLEETS_KEY: each fleet's name -> its CAVs' agent ids, what the
    metrics read); {} for a task without fleets (its record keeps its bytes)."""
    if not task.fleets:
        return {}
    is_cav = draw_cavs(env_seed, scn.n_agents, task.ratio_machines, agent_id=scn.agent_id)
    fleet = split_fleets(env_seed, is_cav, task.fleet_shares)
    return {FLEETS_KEY: {f.name: [int(a) for a in np.sort(scn.agent_id[fleet == i])]
                         for i, f in enumerate(task.fleets)}}


def recorded_setup(configs: Sequence[dict[str, Any]], **now: Any) -> tuple[TrainRequest, TrainSetup]:
    """The request and setup of a recorded train run's seed group (`configs`: its seeds' records,
    in group order) as the run built them; `now`: the request fields this call sets anew."""
    recorded = configs[0]["train_args"]
    req = TrainRequest.from_record(recorded, [c["train_args"]["seed"] for c in configs], **now)
    setup = load_setup(req)
    if "hybrid_seed_axis" not in configs[0]:  # started before the key: its seeds were vmapped
        setup = setup._replace(hyb=dataclasses.replace(setup.hyb, seed_axis="vmap"))
    return req, setup


def scenario_of(net: str | None, networks_dir: str | None, env_seed: int, env: EnvConfig,
              task: TaskConfig, drop_unroutable: bool) -> Scenario:
    """The network's scenario with the task's demand (`drop_unroutable`: see load_scenario)."""
    scn = load_scenario(net or DEFAULT_NETWORK, networks_dir=networks_dir, env_seed=env_seed,
                        route_params=env.route_params(), drop_unroutable=drop_unroutable)
    return scale_demand(scn, task.demand_scale, seed=env_seed, mode=task.demand_mode,
                        jitter_s=task.demand_jitter_s)


def check_runnable(task: TaskConfig, task_path: Path, n_agents: int, *, train: bool, mode: str = "hybrid",
                   alg: str = "", alg_config: Any = None, baseline: str = "",
                   surrogate_model: str = "bpr") -> None:
    """Refuse, before any SUMO day, a task whose URB metrics could not exist: no human day (t_pre),
    no test day (t_CAV, t_test, WR), or, for training, no CAV to train; a marginal credit
    without a calibrated surrogate to take its derivative (baselines, `--mode sumo`); demand varying
    day to day where the run cannot honour it (`check_day_demand`, for `alg` or the `baseline` model),
    and departures varying day to day likewise (`check_departure_jitter`)."""
    check_day_demand(task, task_path, train=train, alg=canonical(alg) if alg else "", alg_config=alg_config,
                     baseline=baseline)
    check_departure_jitter(task, task_path, train=train, baseline=baseline,
                           surrogate_model=surrogate_model if mode != "sumo" else "")
    check_fleets(task, task_path, n_agents, train=train)
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


def check_fleets(task: TaskConfig, task_path: Path, n_agents: int, *, train: bool) -> None:
    """Refuse, before any day, fleets where the run has no learners to give them (a baseline: every
    CAV follows one fixed model) or a fleet the network's CAV draw leaves empty."""
    if not task.fleets:
        return
    where = f"task config {task_path}: key 'fleets'"
    if not train:
        raise ConfigError(f"{where}: fleets of learners are trained by `urb-jax train` only; a baseline's "
                          "CAVs all follow its one model. Fix: run the baseline on the one-fleet task (the "
                          "fleets' shares summed as ratio_machines, no 'fleets').")
    is_cav = np.zeros(n_agents, bool)
    is_cav[:int(n_agents * task.ratio_machines)] = True
    sizes = np.bincount(split_fleets(0, is_cav, task.fleet_shares)[is_cav], minlength=len(task.fleets))
    if n_agents and sizes.min() == 0:
        empty = [f.name for f, n in zip(task.fleets, sizes, strict=True) if n == 0]
        raise ConfigError(f"{where}: fleet(s) {', '.join(empty)} get no CAV of this network's "
                          f"{int(is_cav.sum())}. Fix: larger shares, or fewer fleets.")


# The learners whose losses leave out the CAVs that stayed home (Day.active), in their default
# "days" frames (IQL*, IPPO*: a CAV learns only from the samples of days it travelled); the others
# would learn from days their CAVs did not travel.
DAY_DEMAND_ALGORITHMS = ("iql", "ippo", "mappo", "iql_star", "ippo_star")
# The baselines whose CAVs learn nothing, so a day at home changes nothing for them (the human
# baseline's CAVs learn as humans; its learning is not masked).
DAY_DEMAND_BASELINES = ("aon", "random")


def check_day_demand(task: TaskConfig, task_path: Path, *, train: bool, alg: str = "",
                     alg_config: Any = None, baseline: str = "") -> None:
    """Refuse, before any day, a run that cannot honour `day_participation` < 1 (demand varying
    day to day): the human baseline, a policy from outside and other SUMO-only protocols (their
    days are not wired to it), a learner that does not mask the CAVs who stay home, and the marginal
    rewards (their model derivative counts every driver)."""
    if not task.varies_daily:
        return
    where = f"task config {task_path}: key 'day_participation' = {task.day_participation}"
    _refuse_unwired(where, "demand", train=train, baseline=baseline, off="day_participation to 1")
    frames = getattr(alg_config, "frames", "days")
    if train and (alg not in DAY_DEMAND_ALGORITHMS or frames != "days"):
        raise ConfigError(f"{where}: algorithm '{alg}' (frames {frames!r}) does not leave the CAVs who "
                          "stay home out of its loss. Fix: use one of "
                          f"{', '.join(DAY_DEMAND_ALGORITHMS)} with frames 'days', or set day_participation "
                          "to 1.")
    if task.surrogate_reward_keys:
        raise ConfigError(f"{where} with key(s) {', '.join(task.surrogate_reward_keys)}: the surrogate's "
                          "marginal rewards count every driver, also those who stay home. Fix: set "
                          "reward_credit 'group' and marginal_cost_beta 0, or day_participation to 1.")


def check_departure_jitter(task: TaskConfig, task_path: Path, *, train: bool, baseline: str = "",
                           surrogate_model: str = "") -> None:
    """Refuse, before any day, a run that cannot honour `day_departure_jitter_s` > 0: the protocols
    whose days are not wired to it (as for `day_participation`), and the queue surrogate (its entries
    are placed once, from the scheduled departures); `surrogate_model`: the run's ("" none)."""
    if not task.jitters_departures:
        return
    where = f"task config {task_path}: key 'day_departure_jitter_s' = {task.day_departure_jitter_s}"
    _refuse_unwired(where, "departures", train=train, baseline=baseline, off="day_departure_jitter_s to 0")
    if surrogate_model == "queue":
        raise ConfigError(f"{where}: the queue surrogate places its entries from the scheduled departures, "
                          "so its days cannot follow departures that move. Fix: set the hybrid config's key "
                          "'surrogate_model' to 'bpr' (--set hybrid.surrogate_model=bpr), or "
                          "day_departure_jitter_s to 0.")


def _refuse_unwired(where: str, varying: str, *, train: bool, baseline: str, off: str) -> None:
    """Refuse a day-to-day variation (`varying`: what varies) outside `urb-jax train` and the baselines
    whose days are wired to it; `off`: the setting that turns it off."""
    if not train and baseline not in DAY_DEMAND_BASELINES:
        what = f"the '{baseline}' baseline" if baseline else "a policy run outside `urb-jax train`"
        raise ConfigError(f"{where} ({varying} varying day to day) is supported by `urb-jax train` and the "
                          f"{' and '.join(DAY_DEMAND_BASELINES)} baselines only, not by {what}. Fix: use "
                          f"--model {' or '.join(DAY_DEMAND_BASELINES)}, or set {off}.")


def check_emission_source(setup: TrainSetup, executor: object | None) -> None:
    """A run asking for emissions (hybrid key 'emissions') whose SUMO days come from a given executor
    (a suite's, an API caller's, a test's stand-in) needs one that runs SUMO's emission device: its
    days would otherwise reach the records without CO2 and fuel, so it is refused before any day.
    An executor the run makes itself is made with the device (`HybridConfig.sumo_config`)."""
    if executor is None or not setup.hyb.emissions:
        return
    config = getattr(executor, "config", None)
    if isinstance(config, SumoConfig) and config.emissions:
        return
    runs = f"with {config!r}" if isinstance(config, SumoConfig) else "without SUMO (no SumoConfig)"
    raise ConfigError(f"hybrid config {setup.hyb_path}: key 'emissions' is true, but this run's days come "
                      f"from the {type(executor).__name__} it was given, which runs {runs}: no day would "
                      "carry CO2 or fuel. Fix: set 'emissions' false (or drop --set hybrid.emissions), or "
                      "give an executor built with SumoConfig(emissions=True), or none (the run makes one).")


@contextlib.contextmanager
def stops_cleanly(folders: list[Path], resumable: bool = True) -> Iterator[None]:
    """Ctrl-C, SIGTERM, SIGHUP (`core.interrupt`), a full disk and memory exhaustion (with the phase
    it happened in and what uses less memory, `core.phase`) end a train run with the message
    that says what is kept and how to go on (`urb-jax train --resume`), instead of a traceback; the
    executor is closed by then. A forced stop (a signal inside a long jitted call, or sent twice)
    prints the same line."""
    on_stop(lambda: _resume_hint(folders, resumable))
    enter_phase("setup")
    try:
        yield
    except KeyboardInterrupt:
        raise InterruptedRunError(f"stopped by {stop_cause()}. {_resume_hint(folders, resumable)}") from None
    except Exception as exc:  # orbax and pyarrow wrap the OS error in their own types
        if is_out_of_memory(exc):
            raise OutOfMemoryError(folders, exc, _resume_hint(folders, resumable)) from None
        if not no_space(exc):
            raise
        raise disk_full(folders[0].parent, f"({exc}) {_resume_hint(folders, resumable)}") from None
    finally:
        on_stop(None)


class OutOfMemoryError(UrbJaxError):
    """Memory ran out in this process (MemoryError, XLA's RESOURCE_EXHAUSTED) or in a SUMO worker
    process: the phase, what uses less memory there (`core.phase.memory_hint`), and how to continue."""

    def __init__(self, folders: list[Path], exc: BaseException, resume: str) -> None:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:300]
        super().__init__(f"{folders[0]}: out of memory during {current_phase()} ({type(exc).__name__}: "
                         f"{first}). {memory_hint(exc)}. {resume} (with the same settings, once more "
                         "memory is free).")


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


def task_values(task: TaskConfig) -> dict[str, Any]:
    """The task's values as exp_config.json records them: `fleets` only where the task has some, so a
    run without fleets records (and a resume compares) exactly the keys it did before fleets."""
    values = to_dict(task)
    if not task.fleets:
        del values["fleets"]
    return values


def experiment_config(scn: Scenario, task: TaskConfig, task_path: Path, env: EnvConfig, env_path: Path,
                       env_seed: int, human_phase_from: str | None, drop_unroutable: bool) -> dict[str, Any]:
    """exp_config.json's keys of every run, train or baseline: the configs' values, the network and
    its agents, where and with what the run computed."""
    return {
        **to_dict(env), **task_values(task),
        "network": scn.name, "net_file": scn.net_file, "env_seed": env_seed,
        "env_config": env_path.stem, "task_config": task_path.stem,
        "num_agents": scn.n_agents, "num_machines": int(scn.n_agents * task.ratio_machines),
        "exp_type": "normal", "human_days": task.human_learning_episodes,
        "versions": versions(), "machine": machine(), "urb_jax_version": __version__, "command": sys.argv,
        "status": "running", "human_phase_from": human_phase_from, **_dropped(scn, drop_unroutable),
    }


ALG_GIVEN_KEY = "alg_config_given"  # exp_config.json: the algorithm config's values as read (file, --set)


def recorded_values(setup: TrainSetup) -> dict[str, Any]:
    """What a train run records of the configs it read, as exp_config.json holds it (tuples as
    lists): the env and task values, the hybrid ones as hybrid_<key>, the algorithm's under
    ALG_GIVEN_KEY (before the trainer fits them to the run: `alg_config_values` at the end)."""
    return json.loads(json.dumps({**to_dict(setup.env), **task_values(setup.task),
                                  **{f"hybrid_{k}": v for k, v in to_dict(setup.hyb).items()},
                                  ALG_GIVEN_KEY: to_dict(setup.alg_config)}))


def _flat(values: dict[str, Any]) -> dict[str, Any]:
    """`values` with the algorithm's as alg.<key> (the --set spelling) instead of one nested key."""
    alg = values.get(ALG_GIVEN_KEY) or {}
    rest = {k: v for k, v in values.items() if k != ALG_GIVEN_KEY}
    return {**rest, **{f"alg.{k}": v for k, v in alg.items()}}


def check_recorded_configs(config_file: Path, config: dict[str, Any], setup: TrainSetup,
                           ignore: Sequence[str] = ()) -> None:
    """A resume re-reads the run's task, env, hybrid and algorithm configs: each value must be the one
    the run recorded when it started (a file edited since would change the run half-way). `ignore`:
    keys the record gives a value of its own. A key the record lacks (a run from before it) is not
    compared."""
    now, was = _flat(recorded_values(setup)), _flat(config)
    changed = [k for k, v in now.items() if k in was and k not in ignore and v != was[k]]
    if changed:
        alg_conf = config.get("train_args", {}).get("alg_conf")
        files = f"{setup.task_path}, {setup.env_path}, {setup.hyb_path}, the algorithm config {alg_conf!r}"
        diffs = "; ".join(f"'{k}' was {was[k]!r}, now {now[k]!r}" for k in changed)
        raise UrbJaxError(f"{config_file}: the run's configs changed since it started ({diffs}; read from "
                          f"{files} and the recorded --set items). Fix: restore the files, or start a new "
                          "run with another --id.")


def _dropped(scn: Scenario, drop_unroutable: bool) -> dict[str, Any]:
    """exp_config.json keys of the --drop-unroutable opt-in: the choice and the agents it left out
    (`export-day` rebuilds the scenario from the choice)."""
    return {"drop_unroutable": drop_unroutable, "dropped_unroutable_agents": scn.dropped_record()}


T = TypeVar("T")  # what a reuse check returns


def first_reusable(results_dir: Path, candidates: Sequence[str], reuse: Callable[[Path], T]
                   ) -> tuple[str, T] | None:
    """(id, what `reuse` returned) of the first finished run among `candidates` (experiment ids in
    `results_dir`) whose human phase `reuse` accepts; `reuse` raises UrbJaxError to refuse one.
    What a suite uses to simulate each human phase once: runs that differ only in their CAVs
    (algorithm, CAV behaviour, seeds) share it, and `reuse` checks everything else."""
    for exp_id in candidates:
        if run_status(results_dir / exp_id) != "done":
            continue
        try:
            return exp_id, reuse(results_dir / exp_id)
        except UrbJaxError:
            continue
    return None
