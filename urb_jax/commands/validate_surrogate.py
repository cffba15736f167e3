"""`urb-jax validate-surrogate`: calibrate the surrogate on SUMO days, report its error on held-out ones."""

from __future__ import annotations

import argparse
import json

from urb_jax.commands.common import add_day_store_flag, add_network_flags


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("validate-surrogate",
                            help="calibrate the surrogate and compare it with SUMO on held-out days")
    add_network_flags(parser)
    parser.add_argument("--days", type=int, default=10, help="held-out SUMO days (default 10)")
    parser.add_argument("--train-days", type=int, default=40, help="calibration SUMO days (default 40)")
    parser.add_argument("--agents", type=int, default=30,
                        help="agents whose single-route deviations are re-simulated (default 30)")
    parser.add_argument("--model", choices=("bpr", "queue"), default="bpr",
                        help="surrogate model: time-dependent BPR (default) or BPR plus point queues "
                             "with spill-back (docs/surrogate.md)")
    parser.add_argument("--workers", type=int, default=2, help="SUMO days run in parallel (default 2)")
    parser.add_argument("--out", default=None,
                        help="results folder (default results/surrogate_validation/<net>)")
    add_day_store_flag(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from urb_jax.city.scenario import load_scenario
    from urb_jax.surrogate.model import SurrogateConfig
    from urb_jax.surrogate.validate import ValidationConfig, validate

    scn = load_scenario(args.net, networks_dir=args.networks_dir, env_seed=args.env_seed,
                        drop_unroutable=args.drop_unroutable)
    name = scn.name if args.model == "bpr" else f"{scn.name}-{args.model}"
    out = Path(args.out) if args.out else Path("results") / "surrogate_validation" / name
    vcfg = ValidationConfig(train_days=args.train_days, test_days=args.days,
                            deviation_agents=args.agents, noise_agents=max(1, args.agents // 3),
                            seed=args.env_seed, workers=args.workers,
                            day_store=not args.no_day_store)
    metrics = validate(scn, out, vcfg, SurrogateConfig(model=args.model))
    print(json.dumps({"held_out": metrics["held_out"], "route_agreement": metrics["route_agreement"],
                      "seed_to_seed_mape": metrics.get("seed_to_seed_mape_base")}, indent=2))
    print(f"report: {out / 'report.md'}")
    return 0
