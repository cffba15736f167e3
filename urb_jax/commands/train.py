"""`urb-jax train`: a URB experiment with an RL algorithm, trained by the hybrid loop
(surrogate + SUMO, `urb_jax.hybrid`); every metric comes from SUMO days."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from urb_jax.commands.common import add_network_flags

METRIC_KEYS = ("t_pre", "t_CAV", "t_HDV_test", "t_train", "winrate", "cost_of_learning", "delta_V")


def register(sub: argparse._SubParsersAction) -> None:
    from urb_jax.algorithms.registry import ALGORITHMS
    from urb_jax.experiment.hybrid import MODES

    parser = sub.add_parser("train", help="train CAV policies (hybrid surrogate + SUMO; metrics from SUMO)")
    parser.add_argument("--alg", default="iql", choices=tuple(ALGORITHMS), help="algorithm (default iql)")
    add_network_flags(parser)
    parser.add_argument("--task-conf", default="config1",
                        help="task config id or .json path (default config1)")
    parser.add_argument("--alg-conf", default="config1", help="algorithm config id or path (default config1)")
    parser.add_argument("--env-conf", default="config1", help="env config id or .json path (default config1)")
    parser.add_argument("--hybrid-conf", default="default",
                        help="hybrid round/budget config id or path (configs/hybrid, default 'default')")
    parser.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    parser.add_argument("--seeds", default=None, help="comma-separated training seeds, e.g. 0,1,2 "
                        "(trained together under vmap, sharing the human phase and SUMO pool; a folder each)")
    parser.add_argument("--mode", default="hybrid", choices=MODES,
                        help="hybrid (default), sumo (URB protocol: SUMO days only), "
                             "surrogate (train on the surrogate only; test on SUMO)")
    parser.add_argument("--train-days", type=int, default=None,
                        help="URB-equivalent training days (overrides the hybrid config)")
    parser.add_argument("--id", default=None,
                        help="experiment id (default <alg>_<mode>_<net>_<task>_s<seed>)")
    parser.add_argument("--resume", default=None, metavar="EXP_ID",
                        help="continue the killed run EXP_ID in --results-dir from its last checkpoint")
    parser.add_argument("--human-phase-from", default=None, metavar="EXP_ID",
                        help="reuse the human phase (records, human state, calibration days) of run EXP_ID")
    parser.add_argument("--results-dir", default="results", help="results root (default ./results)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing results with this id")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--executor", choices=("pool", "ray"), default=None,
                        help="where SUMO days run: pool (default; local processes) or ray (a Ray cluster, "
                             "pip install 'urb-jax[ray]'); --resume uses the recorded one unless given")
    parser.add_argument("--ray-address", default=None, help="Ray cluster: 'auto' or 'ray://host:port' "
                        "(default: start a local Ray)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.resume:
        outs = resume_train(args.resume, results_dir=args.results_dir, progress=not args.no_progress,
                            executor_kind=args.executor, ray_address=args.ray_address)
    else:
        seeds = [int(s) for s in args.seeds.split(",")] if args.seeds else [args.seed]
        outs = run_train(
            alg=args.alg, net=args.net, task_conf=args.task_conf, alg_conf=args.alg_conf,
            env_conf=args.env_conf, hybrid_conf=args.hybrid_conf, env_seed=args.env_seed, seeds=seeds,
            exp_id=args.id, mode=args.mode, networks_dir=args.networks_dir, results_dir=args.results_dir,
            overwrite=args.overwrite, progress=not args.no_progress, train_days=args.train_days,
            executor_kind=args.executor or "pool", ray_address=args.ray_address,
            human_phase_from=args.human_phase_from)
    for out in outs:
        m = out["metrics"]
        print(f"results: {out['folder']}  ({out['wall_time_s']:.1f} s)")
        for key in METRIC_KEYS:
            print(f"  {key:18s} {m[key]:.4f}" if m[key] == m[key] else f"  {key:18s} N/A")
        aon = aon_t_cav(out)
        if aon is not None:
            print(f"  {'t_CAV_AON':18s} {aon:.4f}  (AON on the same test humans, one SUMO day)")
        print(f"  {'in SUMO duration':18s} t_pre {m['t_pre_duration']:.4f}, t_CAV {m['t_CAV_duration']:.4f}"
              f"{aon_duration(out)}  (the measure of URB's published tables)")
    line = seed_summary(outs)
    if line:
        print(line)
    return 0


def aon_t_cav(out: dict[str, Any], key: str = "t_CAV") -> float | None:
    """The run's AON reference day (hybrid.aon_same_humans) t_CAV, or `key`, if it has one."""
    return ((out.get("summary") or {}).get("aon_same_humans") or {}).get(key)


def aon_duration(out: dict[str, Any]) -> str:
    """', AON x' in the published tables' measure, or '' for a run without the AON day."""
    d = aon_t_cav(out, "t_CAV_duration")
    return "" if d is None else f", AON {d:.4f}"


def seed_summary(outs: list[dict[str, Any]]) -> str | None:
    """One line over the seeds of a run, in the terms of the quality bar: mean and sd of t_CAV, how
    many seeds are at or below AON on their test humans, and how many beat t_pre (WR)."""
    done = [o for o in outs if o.get("metrics")]
    if len(done) < 2:
        return None
    t = np.array([o["metrics"]["t_CAV"] for o in done])
    wins = sum(o["metrics"]["winrate"] == 1.0 for o in done)  # per seed, urb_jax.metrics' WR
    aon = [aon_t_cav(o) for o in done]
    vs_aon = (f", at or below AON {sum(x <= a for x, a in zip(t, aon, strict=True))}/{len(done)}"
              if all(a is not None for a in aon) else "")
    dur = np.array([o["metrics"]["t_CAV_duration"] for o in done])
    return (f"{len(done)} seeds: t_CAV {t.mean():.4f} (sd {t.std(ddof=1):.4f}){vs_aon}, "
            f"below t_pre {wins}/{len(done)}; in SUMO duration t_CAV {dur.mean():.4f}")


def _setup(cfg: dict[str, Any]):
    """Scenario, configs and algorithm config from the recorded arguments."""
    import dataclasses

    from urb_jax.algorithms.registry import load_algo_config
    from urb_jax.city.demand import scale_demand
    from urb_jax.city.scenario import load_scenario
    from urb_jax.experiment.hybrid import load_hybrid_config
    from urb_jax.game.config import load_env_config, load_task_config

    task, task_path = load_task_config(cfg["task_conf"])
    env, env_path = load_env_config(cfg["env_conf"])
    hyb, hyb_path = load_hybrid_config(cfg["hybrid_conf"])
    if cfg.get("train_days"):
        hyb = dataclasses.replace(hyb, train_days=int(cfg["train_days"]))
    alg_config = load_algo_config(cfg["alg"], cfg["alg_conf"])
    scn = load_scenario(cfg["net"], networks_dir=cfg["networks_dir"], env_seed=cfg["env_seed"],
                        route_params=env.route_params())
    scn = scale_demand(scn, task.demand_scale, seed=cfg["env_seed"], mode=task.demand_mode,
                       jitter_s=task.demand_jitter_s)
    return scn, task, task_path, env, env_path, hyb, hyb_path, alg_config


def _executor(hyb: Any, log_dir: Path, kind: str = "pool", ray_address: str | None = None):
    from urb_jax.sumo_bridge import InProcessExecutor, SumoPool

    if kind == "ray":
        from urb_jax.sumo_bridge.ray_executor import RayExecutor

        return RayExecutor(max(1, hyb.sumo_workers), log_dir=log_dir, day_timeout_s=hyb.day_timeout_s,
                           address=ray_address)
    if hyb.sumo_workers <= 1:
        return InProcessExecutor(log_file=log_dir / "sumo.log")
    return SumoPool(hyb.sumo_workers, log_dir=log_dir, day_timeout_s=hyb.day_timeout_s)


def run_train(*, alg: str = "iql", net: str | None = None, task_conf: str = "config1",
              alg_conf: str = "config1", env_conf: str = "config1", hybrid_conf: str = "default",
              env_seed: int = 42,
              seeds: list[int] | None = None, exp_id: str | None = None, mode: str = "hybrid",
              networks_dir: str | None = None, results_dir: str = "results", overwrite: bool = False,
              progress: bool = True, train_days: int | None = None, executor: Any = None,
              stop_after_round: int | None = None, executor_kind: str = "pool",
              ray_address: str | None = None, human_phase_from: str | None = None
              ) -> list[dict[str, Any]]:
    """Train every seed (sharing the human phase and the SUMO pool; groups of up to
    `max_vmapped_seeds` seeds train together under vmap); one results folder per seed.
    `human_phase_from`: reuse that earlier train run's human phase instead of simulating it."""
    from urb_jax.city.network import DEFAULT_NETWORK
    from urb_jax.core.configio import to_dict
    from urb_jax.experiment.human_reuse import reuse_human_phase, save_human_phase
    from urb_jax.experiment.hybrid import run_human_phase
    from urb_jax.results.records import create_results_dir, versions, write_json

    seeds = seeds or [0]
    net = net or DEFAULT_NETWORK
    args = {"alg": alg, "net": net, "task_conf": task_conf, "alg_conf": alg_conf, "env_conf": env_conf,
            "hybrid_conf": hybrid_conf, "env_seed": env_seed, "mode": mode, "networks_dir": networks_dir,
            "train_days": train_days, "executor": executor_kind, "ray_address": ray_address}
    t0 = time.perf_counter()
    scn, task, task_path, env, env_path, hyb, hyb_path, alg_config = _setup(args)
    base = exp_id or f"{alg}_{mode}_{Path(net).name}_{task_path.stem}"
    common = {
        **to_dict(env), **to_dict(task), **{f"hybrid_{k}": v for k, v in to_dict(hyb).items()},
        "network": scn.name, "net_file": scn.net_file, "env_seed": env_seed,
        "env_config": env_path.stem, "task_config": task_path.stem, "alg_config": alg_conf,
        "hybrid_config": hyb_path.stem, "algorithm": alg, "mode": mode, "script": "urb-jax train",
        "num_agents": scn.n_agents, "num_machines": int(scn.n_agents * task.ratio_machines),
        "exp_type": "normal", "human_days": task.human_learning_episodes, "versions": versions(),
        "command": sys.argv, "status": "running", "human_phase_from": human_phase_from,
    }
    human = None  # checked before any results folder is created
    if human_phase_from:
        human = reuse_human_phase(Path(results_dir) / human_phase_from, common, scn, task, hyb, env_seed,
                                  calibrate=mode != "sumo")
    folders = {}
    for s in seeds:
        name = exp_id if (exp_id and len(seeds) == 1) else f"{base}_s{s}"
        folders[s] = create_results_dir(results_dir, name, overwrite)
    own = executor is None
    executor = executor or _executor(hyb, folders[seeds[0]], executor_kind, ray_address)
    outs = []
    try:
        if human is None:
            bar = None
            if progress:
                from tqdm.auto import tqdm

                calib_days = hyb.calib_varied_days if mode != "sumo" else 0
                bar = tqdm(total=task.human_learning_episodes + calib_days, unit="day", dynamic_ncols=True,
                           desc="human/SUMO")

            def on_day(phase: str, n: int) -> None:
                if bar is not None:
                    bar.set_description(f"{phase}/SUMO")
                    bar.update(n)

            human = run_human_phase(scn, task, hyb, executor, env_seed, on_day=on_day,
                                    calibrate=mode != "sumo")
            if bar is not None:
                bar.close()
        for folder in folders.values():
            save_human_phase(folder, human)
        t_human = time.perf_counter() - t0
        size = max(1, hyb.max_vmapped_seeds)
        groups = [seeds[i:i + size] for i in range(0, len(seeds), size)]
        for gi, group in enumerate(groups):
            configs = {s: {**common, "seed": s, "train_args": args | {"seed": s},
                           "group": [folders[g].name for g in group], "seeds_together": len(group),
                           "human_phase_s": round(t_human, 2)} for s in group}
            for s in group:
                write_json(folders[s] / "exp_config.json", configs[s])
            ts = time.perf_counter()
            summaries = _train(scn, task, env, hyb, alg, alg_config, mode, group, env_seed,
                               [folders[s] for s in group], executor, human, progress, stop_after_round)
            wall = time.perf_counter() - ts + (t_human if gi == 0 else 0.0)
            for s, summary in zip(group, summaries, strict=True):
                outs.append(_finish(folders[s], configs[s], summary, task, wall))
    finally:
        if own:
            executor.close()
    return outs


def resume_train(exp_id: str, *, results_dir: str = "results", progress: bool = True,
                 executor: Any = None, executor_kind: str | None = None,
                 ray_address: str | None = None) -> list[dict[str, Any]]:
    """Continue results/<exp_id>/ (and the seeds trained together with it) from the group's newest
    checkpoint, with the recorded arguments (and the recorded SUMO executor unless `executor_kind`
    overrides it); one result per seed of the group."""
    folder = Path(results_dir) / exp_id
    config = json.loads((folder / "exp_config.json").read_text())
    folders = [Path(results_dir) / name for name in config.get("group", [exp_id])]
    configs = [json.loads((f / "exp_config.json").read_text()) for f in folders]
    if all(c.get("status") == "done" for c in configs):
        raise SystemExit(f"{folder}: this run is already complete.")
    args = configs[0]["train_args"]
    seeds = [c["train_args"]["seed"] for c in configs]
    scn, task, _, env, _, hyb, _, alg_config = _setup(args)
    own = executor is None
    executor = executor or _executor(hyb, folders[0], executor_kind or args.get("executor", "pool"),
                                     ray_address or args.get("ray_address"))
    t0 = time.perf_counter()
    try:
        summaries = _train(scn, task, env, hyb, args["alg"], alg_config, args["mode"], seeds,
                           args["env_seed"], folders, executor, None, progress, None)
    finally:
        if own:
            executor.close()
    wall = time.perf_counter() - t0
    outs = []
    for f, c, summary in zip(folders, configs, summaries, strict=True):
        c["resumed"] = c.get("resumed", 0) + 1
        outs.append(_finish(f, c, summary, task, wall + c.get("wall_time_s", 0.0)))
    return outs


def _train(scn, task, env, hyb, alg, alg_config, mode, seeds, env_seed, folders, executor, human, progress,
           stop_after_round):
    from urb_jax.experiment.hybrid import train_group

    return train_group(scn=scn, task=task, env_cfg=env, alg=alg, alg_config=alg_config, cfg=hyb, mode=mode,
                       seeds=seeds, env_seed=env_seed, folders=folders, executor=executor, human=human,
                       progress=progress, stop_after_round=stop_after_round)


def _finish(folder: Path, config: dict[str, Any], summary: dict[str, Any], task: Any, wall: float) -> dict:
    from urb_jax.results.records import write_json, write_plots, write_run_metrics

    if "stopped" in summary:  # simulated kill (tests): leave the run as a crash would
        config.update(wall_time_s=round(wall, 2))
        write_json(folder / "exp_config.json", config)
        return {"folder": folder, "stopped": summary["stopped"], "metrics": {}, "wall_time_s": wall}
    H, T = task.human_learning_episodes, summary["sumo_training_days"]
    metrics, records = write_run_metrics(folder, H, T)
    write_plots(folder, records, H, T, smooth_by=1)
    _write_rounds(folder, summary["rounds"])
    config.update(status="done", wall_time_s=round(wall, 2), training_days=T, sumo_training_days=T,
                  surrogate_training_days=summary["surrogate_days"], rounds=summary["n_rounds"],
                  alg_config_values=summary["alg_config"], aon_same_humans=summary.get("aon_same_humans"))
    write_json(folder / "exp_config.json", config)
    return {"folder": folder, "metrics": metrics, "wall_time_s": wall, "summary": summary}


def _write_rounds(folder: Path, rounds: list[dict[str, Any]]) -> None:
    """rounds.csv (per round: surrogate and SUMO days, times, surrogate error) and its plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    from urb_jax.results.records import atomic_write_bytes

    df = pd.DataFrame(rounds)
    atomic_write_bytes(folder / "rounds.csv", df.to_csv(index=False).encode())
    if "surrogate_mean_error" not in df:
        return
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(df["round"], 100 * df["surrogate_mean_error"], label="error of the day mean (%)")
    ax.plot(df["round"], 100 * df["surrogate_mape"], label="per agent-day MAPE (%)")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_xlabel("round")
    ax.set_ylabel("surrogate vs SUMO (before refit)")
    ax.legend()
    fig.tight_layout()
    (folder / "plots").mkdir(exist_ok=True)
    fig.savefig(folder / "plots" / "surrogate_error.png", dpi=110)
    plt.close(fig)
