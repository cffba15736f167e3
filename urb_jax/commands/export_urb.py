"""`urb-jax export-urb`: finished runs in URB's results layout, for URB's own analysis/metrics.py
and leaderboard generator (unmodified); `urb_jax.reporting.urb_export` writes it."""

from __future__ import annotations

import argparse
import json

from urb_jax.commands.common import add_networks_dir


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "export-urb", help="write finished runs in URB's results layout (episodes/, SUMO_output/, "
                           "exp_config.json) for URB's analysis/metrics.py and leaderboard")
    parser.add_argument("runs", nargs="+", help="run folders (results/<exp_id>)")
    parser.add_argument("--out", default="urb_results",
                        help="results root of the exports: each run goes to OUT/<exp_id>/ "
                             "(default urb_results)")
    parser.add_argument("--save-every", type=int, default=1,
                        help="export every N-th day, as URB's env config save_every (default 1: every day, "
                             "so URB's script measures what urb-jax's metrics measure; URB's runs use 5)")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier export of the same run")
    add_networks_dir(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from urb_jax.reporting.urb_export import export_urb

    for folder in args.runs:
        out = export_urb(folder, args.out, networks_dir=args.networks_dir, overwrite=args.overwrite,
                         save_every=args.save_every)
        print(json.dumps(out, indent=1))
    return 0
