"""What SUMO's emission device costs a day: one network's free-flow-fastest day, with and without
`--device.emissions.probability 1`, in interleaved blocks (off x B, on x B, off x B, ...) on one warm
Simulator so that machine load hits both alike. A day pre-loads the next with its own options, so the
first day of a block pays a second network load: it is run but not timed. Prints each timed day's
wall time and CPU time (this process's: libsumo runs in it; steadier than wall time on a shared
machine), their medians and the overhead.

    python benchmarks/emissions_cost.py [--net saint_arnoult] [--reps 5] [--networks-dir DIR]

"on" is `SumoConfig(emissions=True)`: the device, and the parsing of its output.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from urb_jax.city.scenario import load_scenario
from urb_jax.sumo_bridge import SumoConfig
from urb_jax.sumo_bridge.sim import Simulator

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "networks"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--net", default="saint_arnoult")
    p.add_argument("--networks-dir", default=str(SHARED) if SHARED.is_dir() else None)
    p.add_argument("--reps", type=int, default=5, help="blocks per config")
    p.add_argument("--block", type=int, default=3, help="timed days per block")
    args = p.parse_args()
    scn = load_scenario(args.net, networks_dir=args.networks_dir, drop_unroutable=True)
    choices = scn.fft.argmin(1)
    configs = {"off": SumoConfig(), "on": SumoConfig(emissions=True)}
    log = Path(tempfile.mkdtemp()) / "sumo.log"
    sim = Simulator(configs["off"], log_file=log)
    sim.run_day(scn, choices, seed=42)  # warm: libsumo started, routes written
    wall: dict[str, list[float]] = {k: [] for k in configs}
    cpu: dict[str, list[float]] = {k: [] for k in configs}
    for rep in range(args.reps):
        for name, cfg in configs.items():
            sim.config = cfg
            sim.run_day(scn, choices, seed=42)  # loads this config's day: untimed
            for _ in range(args.block):
                c0 = time.process_time()
                day = sim.run_day(scn, choices, seed=42)
                cpu[name].append(time.process_time() - c0)
                wall[name].append(day.wall_time)
                print(f"block {rep} {name}: wall {day.wall_time:.3f} s, cpu {cpu[name][-1]:.3f} s, "
                      f"load {os.getloadavg()[0]:.2f}", flush=True)
    sim.close()
    for what, t in (("wall", wall), ("cpu", cpu)):
        off, on = statistics.median(t["off"]), statistics.median(t["on"])
        low, high = min(t["off"]), min(t["on"])
        print(f"{args.net} ({scn.n_agents} agents, {len(t['on'])} days each) {what}: median off {off:.3f} s, "
              f"on {on:.3f} s, overhead {100 * (on / off - 1):+.1f}%; min off {low:.3f}, on {high:.3f} "
              f"({100 * (high / low - 1):+.1f}%)")


if __name__ == "__main__":
    main()
