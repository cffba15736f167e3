"""`urb-jax export-day`: a recorded SUMO day as a routes file for `sumo` / `sumo-gui`."""

from __future__ import annotations

import argparse
import json

from urb_jax.commands.common import add_networks_dir


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "export-day", help="write a run's recorded SUMO day as a .rou.xml to replay or watch in sumo-gui")
    parser.add_argument("run", help="run folder (results/<exp_id>)")
    parser.add_argument("--day", type=int, default=None, help="day number (default: the last SUMO day)")
    parser.add_argument("--out", default=None, help="output file (default: RUN/day<N>.rou.xml)")
    add_networks_dir(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from urb_jax.reporting.day_export import export_day

    out = args.out
    if out is None:
        out = Path(args.run) / ("day_last.rou.xml" if args.day is None else f"day{args.day}.rou.xml")
    print(json.dumps(export_day(args.run, out, args.day, args.networks_dir), indent=1))
    return 0
