"""`urb-jax optimum RUN`: the system-optimum and selfish-equilibrium references of a finished run."""

from __future__ import annotations

import argparse
import json
import re

from urb_jax.commands.common import add_networks_dir
from urb_jax.core.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "optimum", help="how well could the CAVs of a finished run have done? (SUMO-checked optimum, "
                        "selfish equilibrium, optimality gap; writes RUN/optimum.json)")
    parser.add_argument("run", help="run folder (results/<exp_id>) of a finished `urb-jax train` run")
    parser.add_argument("--objective", choices=["cav", "all", "reward"], default=None,
                        help="what the fleet minimises (default: from the task's behaviour: mean CAV "
                             "time, mean time of everyone for social/altruistic fleets)")
    parser.add_argument("--sumo-rounds", type=int, default=8, help="SUMO-in-the-loop rounds per reference")
    parser.add_argument("--relax-steps", type=int, default=300, help="relaxed-descent steps per start")
    parser.add_argument("--seed", type=int, default=0)
    add_networks_dir(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from urb_jax.analysis.optimum import SearchConfig, run_references

    try:
        cfg = SearchConfig(objective=args.objective, sumo_rounds=args.sumo_rounds,
                           relax_steps=args.relax_steps, seed=args.seed)
    except ConfigError as exc:  # "key 'sumo_rounds' ...": name the flag
        flag = re.sub(r"key '(\w+)'", lambda m: f"flag --{m.group(1).replace('_', '-')}", str(exc))
        raise ConfigError(f"urb-jax optimum: {flag}") from None
    out = run_references(args.run, args.networks_dir, cfg, log=lambda line: print(line, flush=True))
    rows = [("run (its first test day)", out["run_day"]), ("AON, same humans", out["aon"]),
            ("optimum", out["optimum"]), ("selfish equilibrium", out["equilibrium"])]
    print(f"\nobjective: {out['objective']} {json.dumps(out['objective_weights'])}; every row a SUMO day")
    print(f"{'':26s} {'J':>8s} {'t_CAV':>8s} {'t_HDV':>8s} {'t_all':>8s}   (duration: t_CAV t_all)")
    for name, d in rows:
        print(f"{name:26s} {d['objective']:8.4f} {d['t_CAV']:8.4f} {d['t_HDV']:8.4f} {d['t_all']:8.4f}"
              f"   ({d['t_CAV_duration']:.4f} {d['t_all_duration']:.4f})")
    print(f"optimality gap {out['optimality_gap']:.4f} min; gap closed from AON "
          f"{out['gap_closed_from_aon']}; price of anarchy {out['price_of_anarchy']}; "
          f"{out['sumo_days']} SUMO days, {out['wall_s']} s -> {args.run}/optimum.json")
    return 0
