"""`urb-jax scenario`: build (or load) a Scenario and print what it holds."""

from __future__ import annotations

import argparse
import json
import time

from urb_jax.commands.common import add_network_flags


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("scenario", help="build a scenario (routes cached) and summarise it")
    add_network_flags(parser)
    parser.add_argument("--no-cache", action="store_true", help="rebuild routes, ignore the cache")
    parser.add_argument("--routes-csv", default=None,
                        help="also write URB's routes.csv (origins, destinations, path, free_flow_time)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from urb_jax.city.scenario import load_scenario

    t0 = time.perf_counter()
    scn = load_scenario(args.net, networks_dir=args.networks_dir, env_seed=args.env_seed,
                        use_cache=not args.no_cache, drop_unroutable=args.drop_unroutable)
    summary = scn.summary()
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    print(json.dumps(summary, indent=2))
    if args.routes_csv:
        from urb_jax.city.routes_io import write_routes_csv

        write_routes_csv(scn, args.routes_csv)
        print(f"wrote {args.routes_csv}")
    return 0
