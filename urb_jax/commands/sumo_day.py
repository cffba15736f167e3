"""`urb-jax sumo-day`: run SUMO days of a scenario on fixed routes and print what SUMO reports."""

from __future__ import annotations

import argparse
import json

from urb_jax.commands.common import add_network_flags
from urb_jax.core.choices import STUCK_PENALTIES, STUCK_RULES


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("sumo-day", help="run SUMO days (libsumo) on fixed routes and summarise them")
    add_network_flags(parser)
    parser.add_argument("--routes", default="fft",
                        help="'fft' (free-flow fastest), 'random', or a route index k for everyone")
    parser.add_argument("--seed", type=int, default=None, help="SUMO --seed (default: --env-seed)")
    parser.add_argument("--days", type=int, default=1)
    parser.add_argument("--workers", type=int, default=0, help="pool processes (0: in this process)")
    parser.add_argument("--stuck-rule", default="urb", choices=STUCK_RULES)
    parser.add_argument("--stuck-penalty", default="elapsed", choices=STUCK_PENALTIES)
    parser.add_argument("--log-dir", default=None, help="folder for SUMO's warnings (one log per worker)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from urb_jax.city.scenario import load_scenario
    from urb_jax.sumo_bridge import ARRIVED, InProcessExecutor, SumoConfig, SumoPool

    scn = load_scenario(args.net, networks_dir=args.networks_dir, env_seed=args.env_seed,
                        drop_unroutable=args.drop_unroutable)
    if args.routes == "fft":
        choices = scn.fft.argmin(1)
    elif args.routes == "random":
        choices = np.random.default_rng(args.env_seed).integers(0, scn.k, size=scn.n_agents)
    else:
        choices = np.full(scn.n_agents, int(args.routes))
    cfg = SumoConfig(stuck_rule=args.stuck_rule, stuck_penalty=args.stuck_penalty)
    seed = args.env_seed if args.seed is None else args.seed
    batch = np.repeat(choices[None], args.days, axis=0)
    if args.log_dir:
        Path(args.log_dir).mkdir(parents=True, exist_ok=True)
    ex: SumoPool | InProcessExecutor
    if args.workers > 0:
        ex = SumoPool(args.workers, config=cfg, log_dir=args.log_dir)
    else:
        ex = InProcessExecutor(cfg, Path(args.log_dir) / "sumo.log" if args.log_dir else None)
    try:
        results = ex.run_days(scn, batch, [seed] * args.days)
    finally:
        ex.close()
    for d, r in enumerate(results):
        print(json.dumps({
            "day": d, "network": scn.name, "seed": r.seed, "agents": r.n,
            "arrived": int((r.status == ARRIVED).sum()), "removed": r.n_removed,
            "mean_travel_time_min": round(float(r.travel_time.mean()), 4),
            "sumo_mean_speed_kmh": round(r.stat_mean_speed * 3.6, 3),
            "sumo_mean_route_length_km": round(r.stat_mean_route_length / 1000, 4),
            "teleports": r.teleports, "sim_end_s": r.sim_end_time, "wall_s": round(r.wall_time, 3),
        }))
    return 0
