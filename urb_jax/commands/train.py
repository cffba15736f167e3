"""`urb-jax train`: a URB experiment with an RL algorithm, trained by the hybrid loop
(surrogate + SUMO, `urb_jax.training.hybrid`); every metric comes from SUMO days. The run
itself is `urb_jax.runs.train`; this module parses and prints."""

from __future__ import annotations

import argparse

from urb_jax.commands.common import add_day_store_flag, add_network_flags, add_set_flag
from urb_jax.core.choices import ALGORITHM_URB_NAMES, EXECUTORS, LOGGERS, MODES, TRAIN_SECTIONS, URB_ALIASES
from urb_jax.runs.request import ResumeRequest, TrainRequest, repeated_seed

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing
if TYPE_CHECKING:
    from urb_jax.runs.setup import RunResult

METRIC_KEYS = ("t_pre", "t_CAV", "t_HDV_test", "t_train", "winrate", "cost_of_learning", "delta_V")


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("train", help="train CAV policies (hybrid surrogate + SUMO; metrics from SUMO)")
    parser.add_argument("--alg", default=None, choices=(*ALGORITHM_URB_NAMES, *URB_ALIASES),
                        help="algorithm (default iql, URB's iql_torchrl; URB's bandit iql is iql_star, its "
                             "ippo ippo_star; URB's *_torchrl names are accepted: docs/experiment.md); a "
                             "task with fleets names each fleet's, and the run is named by the first's")
    add_network_flags(parser)
    parser.add_argument("--task-conf", default="config1",
                        help="task config id or .json path (default config1)")
    parser.add_argument("--alg-conf", default="config1", help="algorithm config id or path (default config1)")
    parser.add_argument("--env-conf", default="config1", help="env config id or .json path (default config1)")
    parser.add_argument("--hybrid-conf", default="default",
                        help="hybrid round/budget config id or path (configs/hybrid, default 'default')")
    add_set_flag(parser, TRAIN_SECTIONS)
    parser.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    parser.add_argument("--seeds", default=None, type=seed_list,
                        help="comma-separated training seeds, e.g. 0,1,2 (trained together under vmap, "
                             "sharing the human phase and SUMO pool; a folder each)")
    parser.add_argument("--mode", default="hybrid", choices=MODES,
                        help="hybrid (default), sumo (URB protocol: SUMO days only), "
                             "surrogate (train on the surrogate only; test on SUMO)")
    parser.add_argument("--train-days", type=int, default=None,
                        help="URB-equivalent training days (overrides the hybrid config)")
    parser.add_argument("--id", default=None,
                        help="experiment id (default <alg>_<mode>_<net>_<task>_s<seed>)")
    parser.add_argument("--resume", default=None, metavar="EXP_ID",
                        help="continue the killed run EXP_ID in --results-dir from its last checkpoint "
                             "(it finds the network it started with; --networks-dir: where it is now)")
    parser.add_argument("--human-phase-from", default=None, metavar="EXP_ID",
                        help="reuse the human phase (records, human state, calibration days) of run EXP_ID")
    parser.add_argument("--results-dir", default="results", help="results root (default ./results)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing results with this id")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_day_store_flag(parser)
    parser.add_argument("--log", choices=LOGGERS, default=None,
                        help="also log each round (rounds.csv's values) live to results/<id>/tensorboard/ "
                             "(needs pip install 'urb-jax[tensorboard]'); --resume keeps the recorded choice")
    parser.add_argument("--executor", choices=EXECUTORS, default=None,
                        help="where SUMO days run: pool (default; local processes) or ray (a Ray cluster, "
                             "pip install 'urb-jax[ray]'); --resume uses the recorded one unless given")
    parser.add_argument("--ray-address", default=None, help="Ray cluster: 'auto' or 'ray://host:port' "
                        "(default: start a local Ray)")
    parser.add_argument("--dry-run", action="store_true",
                        help="load and check every config and the network, print the resolved experiment "
                             "and exit (0: it would run; 2 and the reason: it would not); simulates "
                             "nothing and creates no results folder")
    parser.set_defaults(func=run)


def request_of(args: argparse.Namespace) -> TrainRequest:
    """The one train request the flags ask for (a run and its dry run read the same)."""
    return TrainRequest(
        alg=args.alg or "", net=args.net, task_conf=args.task_conf, alg_conf=args.alg_conf,
        env_conf=args.env_conf,
        hybrid_conf=args.hybrid_conf, env_seed=args.env_seed, seeds=tuple(args.seeds or [args.seed]),
        mode=args.mode, train_days=args.train_days, exp_id=args.id, networks_dir=args.networks_dir,
        human_phase_from=args.human_phase_from, drop_unroutable=args.drop_unroutable,
        overrides=tuple(args.overrides or ()), executor=args.executor or "pool", ray_address=args.ray_address,
        log=args.log, results_dir=args.results_dir, overwrite=args.overwrite, progress=not args.no_progress,
        day_store=not args.no_day_store)


def resume_request_of(args: argparse.Namespace) -> ResumeRequest:
    """What `--resume` may say besides the run's id (the rest is the run's recorded request)."""
    return ResumeRequest(
        exp_id=args.resume, results_dir=args.results_dir, networks_dir=args.networks_dir,
        executor=args.executor, ray_address=args.ray_address, overrides=tuple(args.overrides or ()),
        log=args.log, progress=not args.no_progress, day_store=not args.no_day_store)


def run(args: argparse.Namespace) -> int:
    from urb_jax.reporting.comparable import SUMO_DAYS
    from urb_jax.runs.train import resume_train, run_train

    if args.dry_run:
        return dry_run(args)
    outs = resume_train(resume_request_of(args)) if args.resume else run_train(request_of(args))
    for out in outs:
        m = out.metrics
        print(f"results: {out.folder}  ({out.wall_time_s:.1f} s)")
        for key in (SUMO_DAYS[k] if SUMO_DAYS.get(k) in m else k for k in METRIC_KEYS):  # hybrid: its own
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


def dry_run(args: argparse.Namespace) -> int:
    """Print the experiment `run` would start; errors reach the CLI as exit code 2 with the reason."""
    from urb_jax.core.errors import UrbJaxError
    from urb_jax.runs.dry_run import describe, plan_train

    if args.resume:
        raise UrbJaxError("--dry-run checks a new run's configs; --resume continues a recorded run whose "
                          "configs were checked when it started. Fix: drop one of the two flags.")
    plan = plan_train(request_of(args))
    print("dry run: every config loaded and checked; nothing simulated, no results folder created.")
    for line in describe(plan):
        print(line)
    print("would run: yes")
    return 0


def seed_list(text: str) -> list[int]:
    """--seeds: comma-separated, distinct integers (argparse turns the error into exit code 2)."""
    try:
        seeds = [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: seeds are comma-separated integers, e.g. 0,1,2"
                                         ) from None
    repeated = repeated_seed(seeds)
    if repeated is not None:
        raise argparse.ArgumentTypeError(f"{text!r}: seed {repeated} is given twice (each seed is one "
                                         "results folder); e.g. 0,1,2")
    return seeds


def aon_t_cav(out: RunResult, key: str = "t_CAV") -> float | None:
    """The run's AON reference day (hybrid.trainer.aon_same_humans) t_CAV, or `key`, if it has one."""
    return out.summary.aon_same_humans.get(key) if out.summary is not None else None


def aon_duration(out: RunResult) -> str:
    """', AON x' in the published tables' measure, or '' for a run without the AON day."""
    d = aon_t_cav(out, "t_CAV_duration")
    return "" if d is None else f", AON {d:.4f}"


def seed_summary(outs: list[RunResult]) -> str | None:
    """One line over the seeds of a run, in the terms of the quality bar: mean and sd of t_CAV, how
    many seeds are at or below AON on their test humans, and how many beat t_pre (WR)."""
    import numpy as np

    done = [o for o in outs if o.metrics]
    if len(done) < 2:
        return None
    t = np.array([o.metrics["t_CAV"] for o in done])
    wins = sum(o.metrics["winrate"] == 1.0 for o in done)  # per seed, urb_jax.metrics' WR
    aon = [aon_t_cav(o) for o in done]
    vs_aon = (f", at or below AON {sum(x <= a for x, a in zip(t, aon, strict=True))}/{len(done)}"
              if all(a is not None for a in aon) else "")
    dur = np.array([o.metrics["t_CAV_duration"] for o in done])
    return (f"{len(done)} seeds: t_CAV {t.mean():.4f} (sd {t.std(ddof=1):.4f}){vs_aon}, "
            f"below t_pre {wins}/{len(done)}; in SUMO duration t_CAV {dur.mean():.4f}")
