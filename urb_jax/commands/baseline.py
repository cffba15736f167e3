"""`urb-jax baseline`: a URB baseline experiment (aon, random, human) with every day in SUMO."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
import time
from pathlib import Path
from typing import Any

from urb_jax.commands.common import add_network_flags


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("baseline", help="run a baseline experiment (every day simulated in SUMO)")
    parser.add_argument("--model", default="aon", choices=["aon", "random", "human"],
                        help="CAV baseline policy (default aon)")
    add_network_flags(parser)
    parser.add_argument("--task-conf", default="config1",
                        help="task config id or .json path (default config1)")
    parser.add_argument("--env-conf", default="config1", help="env config id or .json path (default config1)")
    parser.add_argument("--id", default=None, help="experiment id (default: <model>_<net>_<task>_s<seed>)")
    parser.add_argument("--results-dir", default="results", help="results root (default ./results)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing results with this id")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--human-phase-from", default=None, metavar="EXP_ID",
                        help="reuse the recorded human phase of run EXP_ID in --results-dir (same network, "
                             "seed, human model and demand; choices are checked day by day)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = run_baseline(
        model=args.model, net=args.net, task_conf=args.task_conf, env_conf=args.env_conf,
        env_seed=args.env_seed, exp_id=args.id, networks_dir=args.networks_dir,
        results_dir=args.results_dir, overwrite=args.overwrite, progress=not args.no_progress,
        human_phase_from=args.human_phase_from,
    )
    m = out["metrics"]
    replayed = out.get("replayed_days", 0)
    print(f"results: {out['folder']}  ({out['wall_time_s']:.1f} s, {out['days'] - replayed} SUMO days"
          + (f" + {replayed} replayed)" if replayed else ")"))
    for key in ("t_pre", "t_CAV", "t_HDV_test", "winrate", "cost_of_learning", "delta_V", "delta_L"):
        print(f"  {key:18s} {m[key]:.4f}" if m[key] == m[key] else f"  {key:18s} N/A")
    return 0


def run_baseline(*, model: str = "aon", net: str | None = None, task_conf: str = "config1",
                 env_conf: str = "config1", env_seed: int = 42, exp_id: str | None = None,
                 networks_dir: str | None = None, results_dir: str = "results", overwrite: bool = False,
                 progress: bool = True, day_fn: Any = None, task_overrides: dict | None = None,
                 human_phase_from: str | None = None) -> dict:
    """Run one baseline experiment and write results/<exp_id>/. Returns metrics and paths."""
    from urb_jax import __version__
    from urb_jax.algorithms.baselines import make_baseline
    from urb_jax.city.demand import scale_demand
    from urb_jax.city.network import DEFAULT_NETWORK
    from urb_jax.city.scenario import load_scenario
    from urb_jax.core.configio import to_dict
    from urb_jax.experiment.protocol import run_experiment
    from urb_jax.game.config import load_env_config, load_task_config
    from urb_jax.results.records import (
        RecordsWriter,
        create_results_dir,
        versions,
        write_json,
        write_plots,
        write_run_metrics,
    )

    net = net or DEFAULT_NETWORK
    task, task_path = load_task_config(task_conf)
    if task_overrides:
        task = dataclasses.replace(task, **task_overrides)
    env, env_path = load_env_config(env_conf)
    policy = make_baseline(model)
    exp_id = exp_id or f"{model}_{Path(net).name}_{task_path.stem}_s{env_seed}"
    folder = create_results_dir(results_dir, exp_id, overwrite)
    t0 = time.perf_counter()
    scn = load_scenario(net, networks_dir=networks_dir, env_seed=env_seed, route_params=env.route_params())
    scn = scale_demand(scn, task.demand_scale, seed=env_seed, mode=task.demand_mode,
                       jitter_s=task.demand_jitter_s)
    n_cav = int(scn.n_agents * task.ratio_machines)
    config = {
        **to_dict(env), **to_dict(task),
        "network": scn.name, "net_file": scn.net_file, "env_seed": env_seed,
        "env_config": env_path.stem, "task_config": task_path.stem, "alg_config": "baseline",
        "baseline_model": model, "algorithm": f"baseline_{model}", "script": "urb-jax baseline",
        "num_agents": scn.n_agents, "num_machines": n_cav, "exp_type": "normal",
        "human_days": task.human_learning_episodes, "training_days": task.training_eps,
        "versions": versions(), "urb_jax_version": __version__, "command": sys.argv,
        "status": "running", "human_phase_from": human_phase_from,
    }
    write_json(folder / "exp_config.json", config)
    writer = RecordsWriter(folder, scn.agent_id, scn.agent_od, scn.agent_depart)
    if day_fn is None:  # SUMO's warnings go to the run's sumo.log, not the terminal
        from urb_jax.sumo_bridge import run_day

        day_fn = functools.partial(run_day, log_file=folder / "sumo.log")
    if human_phase_from:
        from urb_jax.experiment.replay import load_replay

        day_fn = load_replay(Path(results_dir) / human_phase_from, config, scn.agent_id,
                             task.human_learning_episodes, day_fn)
    run_experiment(scn, task, env, policy, env_seed=env_seed, day_fn=day_fn, sink=writer,
                   progress=progress)
    writer.close()
    H, T = task.human_learning_episodes, task.training_eps
    metrics, records = write_run_metrics(folder, H, T)
    write_plots(folder, records, H, T, smooth_by=1)
    wall = time.perf_counter() - t0
    config.update(status="done", wall_time_s=round(wall, 2))
    write_json(folder / "exp_config.json", config)
    return {"folder": folder, "metrics": metrics, "wall_time_s": wall,
            "days": task.human_learning_episodes + task.training_eps + task.test_eps,
            "replayed_days": task.human_learning_episodes if human_phase_from else 0}
