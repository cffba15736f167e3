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

from urb_jax.algorithms.registry import algorithm, canonical
from urb_jax.core.choices import DEFAULT_NETWORK
from urb_jax.core.configio import Loaded, in_section
from urb_jax.core.errors import UrbJaxError
from urb_jax.experiment.round_log import check_logger
from urb_jax.experiment.run import TrainArgs, TrainSetup, check_runnable, load_setup
from urb_jax.experiment.run_folder import CONFIG_FILE, ResultsExistError, check_exp_id, train_run_names
from urb_jax.experiment.urb_configs import run_overrides, train_configs
from urb_jax.reporting.urb_names import train_names


@dataclass(frozen=True)
class TrainPlan:
    """A train run, resolved: its arguments, loaded setup, configs as read, and folders."""

    args: TrainArgs
    setup: TrainSetup
    configs: dict[str, Loaded[Any]]
    seeds: list[int]
    folders: list[Path]


def plan_train(*, alg: str = "iql", net: str | None = None, task_conf: str = "config1",
               alg_conf: str = "config1", env_conf: str = "config1", hybrid_conf: str = "default",
               env_seed: int = 42, seeds: list[int] | None = None, exp_id: str | None = None,
               mode: str = "hybrid", networks_dir: str | None = None, results_dir: str = "results",
               overwrite: bool = False, train_days: int | None = None, drop_unroutable: bool = False,
               human_phase_from: str | None = None, overrides: list[str] | None = None,
               log: str | None = None) -> TrainPlan:
    """What `run.run_train` with these arguments would run; raises the error it would stop on."""
    check_logger(log)
    seeds = seeds or [0]
    args: TrainArgs = {
        "alg": canonical(alg), "net": net or DEFAULT_NETWORK, "task_conf": task_conf, "alg_conf": alg_conf,
        "env_conf": env_conf, "hybrid_conf": hybrid_conf, "env_seed": env_seed, "mode": mode,
        "networks_dir": networks_dir, "train_days": train_days, "drop_unroutable": drop_unroutable,
        "overrides": list(overrides or [])}
    setup = load_setup(args)
    check_runnable(setup.task, setup.task_path, setup.scn.n_agents, train=True, mode=mode)
    if human_phase_from:
        _check_source(Path(results_dir), human_phase_from)
    folders = _folders(args, setup, seeds, exp_id, Path(results_dir), overwrite)
    return TrainPlan(args, setup, train_configs(args), seeds, folders)


def _check_source(results_dir: Path, exp_id: str) -> None:
    """--human-phase-from names a recorded run (its match is checked when the run starts)."""
    if not (results_dir / check_exp_id(exp_id) / CONFIG_FILE).is_file():
        raise UrbJaxError(f"--human-phase-from {exp_id}: no urb-jax run in {results_dir / exp_id}. "
                          "Fix: pass the id of a finished train run in --results-dir.")


def _folders(args: TrainArgs, setup: TrainSetup, seeds: list[int], exp_id: str | None, results_dir: Path,
             overwrite: bool) -> list[Path]:
    """The results folders `run_train` would create (same names), checked but not created."""
    names = train_run_names(exp_id, args["alg"], args["mode"], args["net"], setup.task_path.stem, seeds)
    folders = [results_dir / check_exp_id(name) for name in names]
    for folder in folders:
        if folder.exists() and not overwrite:
            raise ResultsExistError(f"{folder}: results for experiment id '{folder.name}' already exist. "
                                    "Fix: pass another --id, or --overwrite to replace them.")
    return folders


def describe(plan: TrainPlan) -> list[str]:
    """The resolved experiment, one line each: network, agents, CAVs, algorithm, folders, every
    config value (with the URB key it was given as, or the --set that set it) and the URB keys
    accepted without effect."""
    scn, task, args = plan.setup.scn, plan.setup.task, plan.args
    n_cav = int(scn.n_agents * task.ratio_machines)
    lines = [
        f"network      {scn.name} ({scn.net_file}): {scn.n_agents} agents, {scn.n_od} OD pairs, "
        f"{scn.route_params.number_of_paths} routes each",
        f"CAVs         {n_cav} of {scn.n_agents} (ratio_machines {task.ratio_machines}), "
        f"behaviour {task.av_behavior}",
        f"algorithm    {args['alg']} (reads URB's {algorithm(args['alg']).urb} configs), "
        f"mode {args['mode']}, seeds {','.join(map(str, plan.seeds))}, env seed {args['env_seed']}",
        f"results      {', '.join(map(str, plan.folders))} (not created by a dry run)",
        "URB names    " + ", ".join(f"{k} {v!r}" for k, v in train_names(
            args["alg"], args["mode"], plan.setup.hyb_path.stem, plan.setup.hyb.train_days,
            args["alg_conf"]).items()) + " (exp_config.json, read by URB's leaderboard)",
    ]
    if args.get("overrides"):
        lines.append(f"overrides    {' '.join('--set ' + o for o in args['overrides'])}")
    for kind, loaded in plan.configs.items():
        lines += _config_lines(kind, loaded)
    hyb = plan.setup.hyb
    hyb_set = {o.key for o in in_section(run_overrides(args), "hybrid")}
    lines.append(f"hybrid config {plan.setup.hyb_path}")
    lines += [f"  {k} = {v!r}{'   (--set)' if k in hyb_set else ''}" for k, v in asdict(hyb).items()]
    return lines


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
