"""Scenario build times: first build (routes generated) vs cached load, per network.

Usage: python benchmarks/scenario_build.py [--networks-dir ../shared/networks] [--workers 2]
       [--nets provins rambouillet] [--drop-unroutable]   (mantes_la_jolie needs --drop-unroutable)
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

DEFAULT_NETS = ["urb_grid", "saint_arnoult", "provins", "ingolstadt_custom"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    shared = Path(__file__).resolve().parents[2] / "shared" / "networks"
    parser.add_argument("--networks-dir", default=str(shared))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--nets", nargs="*", default=DEFAULT_NETS)
    parser.add_argument("--drop-unroutable", action="store_true", help="leave out agents with no route")
    args = parser.parse_args()
    os.environ["URB_JAX_CACHE"] = tempfile.mkdtemp(prefix="urb-jax-bench-")
    from urb_jax.city.scenario import load_scenario
    from urb_jax.core.errors import NetworkError

    print(f"{'network':<20} {'agents':>7} {'ODs':>5} {'first build s':>14} {'cached load s':>14}")
    for name in args.nets:
        try:
            t0 = time.perf_counter()
            scn = load_scenario(name, networks_dir=args.networks_dir, workers=args.workers,
                                drop_unroutable=args.drop_unroutable)
            first = time.perf_counter() - t0
        except NetworkError as exc:
            print(f"{name:<20} skipped: {exc}")
            continue
        t0 = time.perf_counter()
        load_scenario(name, networks_dir=args.networks_dir, drop_unroutable=args.drop_unroutable)
        cached = time.perf_counter() - t0
        print(f"{name:<20} {scn.n_agents:>7} {scn.n_od:>5} {first:>14.2f} {cached:>14.3f}")


if __name__ == "__main__":
    main()
