"""`urb-jax train --dry-run`: load and check everything a train run reads, and say what it would
run, without simulating anything.

It reads the task, env, algorithm and hybrid configs (URB's key names included), resolves the
network (the cached scenario, its routes and demand), applies the run-ability checks of a real run
(`run.check_runnable`) and the results-folder checks, and describes the experiment. No SUMO day,
no executor or process pool, no results folder: a ConfigError or UrbJaxError is the reason it
would not run (exit 2 from the CLI).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from urb_jax.algorithms.registry import algorithm
from urb_jax.core.configio import Loaded, in_section
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.paths import day_store_bytes
from urb_jax.reporting.urb_names import train_names
from urb_jax.runs.folder import (
    CONFIG_FILE,
    ResultsExistError,
    check_exp_id,
    check_results_root,
    train_run_names,
)
from urb_jax.runs.request import TrainRequest
from urb_jax.runs.round_log import check_logger
from urb_jax.runs.setup import TrainSetup, check_runnable, load_setup
from urb_jax.runs.urb_configs import run_overrides, train_configs
from urb_jax.training.hybrid.trainer import budget_plan, budget_text


@dataclass(frozen=True)
class TrainPlan:
    """A train run, resolved: its request, loaded setup, configs as read, and folders."""

    request: TrainRequest
    setup: TrainSetup
    configs: dict[str, Loaded[Any]]
    folders: list[Path]


def plan_train(req: TrainRequest) -> TrainPlan:
    """What `run.run_train(req)` would run; raises the error it would stop on."""
    check_logger(req.log)
    if req.day_store:
        day_store_bytes()  # the SUMO day store's cap ($URB_JAX_DAY_STORE_GB)
    req = req.resolved()
    setup = load_setup(req)
    check_runnable(setup.task, setup.task_path, setup.scn.n_agents, train=True, mode=req.mode,
                   alg=req.alg, alg_config=setup.alg_config, surrogate_model=setup.hyb.surrogate_model)
    if req.human_phase_from:
        _check_source(Path(req.results_dir), req.human_phase_from)
    return TrainPlan(req, setup, train_configs(req), _folders(req, setup))


def _check_source(results_dir: Path, exp_id: str) -> None:
    """--human-phase-from names a recorded run (its match is checked when the run starts)."""
    if not (results_dir / check_exp_id(exp_id) / CONFIG_FILE).is_file():
        raise UrbJaxError(f"--human-phase-from {exp_id}: no urb-jax run in {results_dir / exp_id}. "
                          "Fix: pass the id of a finished train run in --results-dir.")


def _folders(req: TrainRequest, setup: TrainSetup) -> list[Path]:
    """The results folders `run_train` would create (same names), checked but not created."""
    names = train_run_names(req.exp_id, req.alg, req.mode, req.net or "", setup.task_path.stem,
                            list(req.seeds))
    folders = [Path(req.results_dir) / check_exp_id(name) for name in names]
    check_results_root(req.results_dir)
    for folder in folders:
        if folder.exists() and not req.overwrite:
            raise ResultsExistError(f"{folder}: results for experiment id '{folder.name}' already exist. "
                                    "Fix: pass another --id, or --overwrite to replace them.")
    return folders


def describe(plan: TrainPlan) -> list[str]:
    """The resolved experiment, one line each: network, agents, CAVs, algorithm, folders, every
    config value (with the URB key it was given as, or the --set that set it) and the URB keys
    accepted without effect."""
    scn, task, req = plan.setup.scn, plan.setup.task, plan.request
    n_cav = int(scn.n_agents * task.ratio_machines)
    lines = [
        f"network      {scn.name} ({scn.net_file}): {scn.n_agents} agents, {scn.n_od} OD pairs, "
        f"{scn.route_params.number_of_paths} routes each",
        f"CAVs         {n_cav} of {scn.n_agents} (ratio_machines {task.ratio_machines}), "
        f"behaviour {task.av_behavior}",
        f"algorithm    {req.alg} (reads URB's {algorithm(req.alg).urb} configs), "
        f"mode {req.mode}, seeds {','.join(map(str, req.seeds))}, env seed {req.env_seed}",
        f"results      {', '.join(map(str, plan.folders))} (not created by a dry run)",
        "URB names    " + ", ".join(f"{k} {v!r}" for k, v in train_names(
            req.alg, req.mode, plan.setup.hyb_path.stem, plan.setup.hyb.train_days,
            req.alg_conf).items()) + " (exp_config.json, read by URB's leaderboard)",
    ]
    if req.overrides:
        lines.append(f"overrides    {' '.join('--set ' + o for o in req.overrides)}")
    for kind, loaded in plan.configs.items():
        lines += _config_lines(kind, loaded)
    hyb = plan.setup.hyb
    hyb_set = {o.key for o in in_section(run_overrides(req.overrides), "hybrid")}
    lines.append(f"budget       {_budget(plan)}")
    lines.append(f"hybrid config {plan.setup.hyb_path}")
    lines += [f"  {k} = {v!r}{'   (--set)' if k in hyb_set else ''}" for k, v in asdict(hyb).items()]
    return lines


def _budget(plan: TrainPlan) -> str:
    """The rounds the run would train (the learner is built, not compiled, to know its iteration)."""
    req, st = plan.request, plan.setup
    rounds = budget_plan(st.scn, st.task, st.env, req.alg, st.alg_config, st.hyb, req.mode, req.env_seed)
    return budget_text(rounds, st.hyb.train_days)


def _config_lines(kind: str, loaded: Loaded[Any]) -> list[str]:
    res = loaded.resolution
    given_as: dict[str, list[str]] = {}
    for urb, ours in res.aliases.items():
        given_as.setdefault(ours, []).append(f"'{urb}'")
    lines = [f"{kind} config{' ' * (6 - len(kind))}{loaded.path} (read as URB's {res.family})"]
    for key, value in asdict(loaded.config).items():
        note = f"   (given as URB's {' and '.join(given_as[key])})" if key in given_as else ""
        note += "   (--set)" if key in loaded.overridden else ""
        lines.append(f"  {key} = {value!r}{note}")
    lines += [f"  URB key '{k}' = {res.given[k]!r} ignored: {why}" for k, why in res.ignored.items()]
    lines += [f"  URB key '{k}' = {res.given[k]!r} checked against {rule}" for k, rule in res.derived.items()]
    return lines
