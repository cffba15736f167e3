"""`urb-jax baseline`: a URB baseline experiment (aon, random, human) with every day in SUMO.
The run itself is `urb_jax.runs.baseline.run_baseline`; this module parses and prints."""

from __future__ import annotations

import argparse
import json

from urb_jax.commands.common import add_day_store_flag, add_network_flags, add_set_flag
from urb_jax.core.choices import BASELINE_MODELS, BASELINE_SECTIONS


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("baseline", help="run a baseline experiment (every day simulated in SUMO)")
    parser.add_argument("--model", default="aon", choices=BASELINE_MODELS,
                        help="CAV baseline policy (default aon)")
    add_network_flags(parser)
    parser.add_argument("--task-conf", default="config1",
                        help="task config id or .json path (default config1)")
    parser.add_argument("--env-conf", default="config1", help="env config id or .json path (default config1)")
    parser.add_argument("--alg-conf", default=None,
                        help="URB baseline algo config (.json path, e.g. URB's config/algo_config/baseline/"
                             "config1.json): its training_eps sets the CAV days before testing "
                             "(default: the task config's training_eps)")
    add_set_flag(parser, BASELINE_SECTIONS)
    parser.add_argument("--id", default=None, help="experiment id (default: <model>_<net>_<task>_s<seed>)")
    parser.add_argument("--results-dir", default="results", help="results root (default ./results)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing results with this id")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_day_store_flag(parser)
    parser.add_argument("--human-phase-from", default=None, metavar="EXP_ID",
                        help="reuse the recorded human phase of run EXP_ID in --results-dir (same network, "
                             "seed, human model and demand; choices are checked day by day)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from urb_jax.runs.baseline import run_baseline
    from urb_jax.runs.request import BaselineRequest

    out = run_baseline(BaselineRequest(
        model=args.model, net=args.net, task_conf=args.task_conf, env_conf=args.env_conf,
        alg_conf=args.alg_conf, env_seed=args.env_seed, exp_id=args.id, networks_dir=args.networks_dir,
        human_phase_from=args.human_phase_from, drop_unroutable=args.drop_unroutable,
        overrides=tuple(args.overrides or ()), results_dir=args.results_dir, overwrite=args.overwrite,
        progress=not args.no_progress, day_store=not args.no_day_store))
    m = out.metrics
    config = json.loads((out.folder / "exp_config.json").read_text())
    replayed = f", {out.replayed_days} human days replayed" if out.replayed_days else ""
    print(f"results: {out.folder}  ({out.wall_time_s:.1f} s; {out.days} days: {config['sumo_days_run']} "
          f"simulated in SUMO, {config['sumo_days_repeated']} repeating a day already simulated, "
          f"{config.get('sumo_days_from_store', 0)} read from the SUMO day store{replayed})")
    no_cavs = config.get("num_machines") == 0
    for key in ("t_pre", "t_CAV", "t_HDV_test", "winrate", "cost_of_learning", "delta_V", "delta_L"):
        why = "  (no CAVs: ratio_machines makes none, a humans-only run)" if no_cavs else ""
        print(f"  {key:18s} {m[key]:.4f}" if m[key] == m[key] else f"  {key:18s} N/A{why}")
    return 0
