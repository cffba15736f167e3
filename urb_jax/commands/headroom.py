"""`urb-jax headroom`: how much room a finished run's CAVs had, as SUMO days around its test day.
The days themselves are `urb_jax.reporting.headroom`; this module parses and prints."""

from __future__ import annotations

import argparse

from urb_jax.commands.common import add_networks_dir

DESCRIPTION = """\
SUMO days around a finished run's test day, same humans and seed, as a table of t_CAV and t_HDV:
  t_pre, and the CAVs' own mean over the last 50 human days (before they became CAVs);
  policy: the test day replayed (it must give the recorded times);
  AON: the CAVs on their minimum free-flow route (URB's AON baseline);
  CAVs only: the policy's and AON's CAV routes with every human removed, a rough floor.
--sumo-binary adds the test day run by another SUMO build's CLI; --deviations N lets N random CAVs
try every other route alone (one SUMO day each): could a CAV gain by switching?"""


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("headroom", help="put a finished run's test day next to AON, the CAVs' "
                            "pre-mutation times and a no-human floor (SUMO days)",
                            description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", help="run folder (results/<exp_id>) of a finished train or baseline run")
    add_networks_dir(parser)
    parser.add_argument("--sumo-binary", action="append", default=None, metavar="BIN",
                        help="also run the test day with this `sumo` executable (another SUMO build; "
                             "repeatable)")
    parser.add_argument("--deviations", type=int, default=0, metavar="N",
                        help="N random CAVs try each other route alone, one SUMO day each (default 0)")
    parser.add_argument("--workers", type=int, default=2,
                        help="SUMO processes for --deviations (default 2)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from urb_jax.reporting.headroom import headroom, table

    h = headroom(args.run, args.networks_dir, args.sumo_binary or (), args.deviations, args.workers)
    for line in table(h, args.run):
        print(line)
    return 0
