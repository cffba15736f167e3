"""`urb-jax snapshots EXP_ID`: a train run's kept round checkpoints, each tested in SUMO as the run
tests its final policies (the learning curve; urb_jax.runs.snapshots)."""

from __future__ import annotations

import argparse

from urb_jax.commands.common import add_networks_dir


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "snapshots", help="test a train run's kept round checkpoints in SUMO (its learning curve: t_CAV "
                          "against SUMO training days and wall time; writes snapshots.csv)")
    parser.add_argument("exp_id", help="id of a train run in --results-dir (any seed's folder of its group)")
    parser.add_argument("--rounds", type=int, nargs="+", default=(),
                        help="rounds done of the checkpoints to test (default: every kept one)")
    parser.add_argument("--results-dir", default="results")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_networks_dir(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from urb_jax.runs.snapshots import SNAPSHOT_METRICS, SNAPSHOTS_FILE, SnapshotRequest, run_snapshots

    req = SnapshotRequest(args.exp_id, args.results_dir, tuple(args.rounds), args.networks_dir,
                          not args.no_progress)
    table = run_snapshots(req)
    cols = ["seed", "round", "training_days", "sumo_training_days", "wall_s", *SNAPSHOT_METRICS]
    print(table[cols].to_string(index=False, float_format=lambda x: f"{x:.4f}"))
    print(f"-> {args.results_dir}/{table.attrs.get('folder', args.exp_id)}/{SNAPSHOTS_FILE}")
    return 0
