"""SUMO day speed: one-shot CLI vs run_day (reused in-process worker) vs SumoPool(1|2 workers).

Every driver takes its free-flow fastest route (`scn.fft.argmin(1)`). CLI and run_day days are
interleaved (CLI, run_day, CLI, run_day, ...) so that machine load hits both alike; the table
reports medians. "'routerl' rule" is run_day with RouteRL's exact per-step stuck check (a speed
subscription on every vehicle: the cost of reading vehicles through libsumo every step). The
pool columns run the same batch on 1 and then 2 warm workers; "days in flight" is the sum of the
days' in-worker wall times over the batch wall time (2.0: both workers busy all the time, so a
2w/1w below 2 then means the CPUs were shared with other work).

    python benchmarks/sumo_speed.py [--networks urb_grid saint_arnoult provins ingolstadt_custom]

The CLI reference day and the "same rule" run_day apply SUMO's own teleport-and-remove stuck rule
(the CLI cannot apply ours), so a gridlocked network (rambouillet, gargenville) ends on both sides.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from urb_jax.city.scenario import load_scenario
from urb_jax.sumo_bridge import SumoConfig, SumoPool
from urb_jax.sumo_bridge.sim import Simulator

DEFAULT_NETS = ["urb_grid", "saint_arnoult", "provins", "ingolstadt_custom"]
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "networks"


def write_day_rou(path: Path, scn, choices) -> None:
    lines = ["<routes>", '<vType id="Human"/>', '<vType id="AV"/>']
    for od, k in sorted({(int(o), int(c)) for o, c in zip(scn.agent_od, choices, strict=True)}):
        lines.append(f'<route id="{od}_{k}" edges="{" ".join(scn.route_edge_ids(od, k))}"/>')
    for i in range(scn.n_agents):  # agents are sorted by departure already
        lines.append(
            f'<vehicle id="{scn.agent_id[i]}" type="Human" route="{scn.agent_od[i]}_{choices[i]}" '
            f'depart="{scn.agent_depart[i]}" departLane="first" departPos="base" departSpeed="0"/>'
        )
    lines.append("</routes>")
    path.write_text("\n".join(lines))


def cli_day(binary: str, scn, rou: Path, trip: Path, cfg: SumoConfig, seed: int) -> float:
    """One `sumo` CLI day with `cfg`'s options and its day cap (`--end`)."""
    t0 = time.perf_counter()
    subprocess.run([binary, "-n", scn.net_file, "-r", str(rou), "--tripinfo-output", str(trip),
                    "--no-warnings", "true", "--end", str(cfg.max_sim_time_s), *cfg.sumo_args(seed)],
                   check=True, timeout=3600)
    return time.perf_counter() - t0


def timed_days(scn, choices, configs: list[SumoConfig], log: Path, reps: int, cli=None):
    """(per config `reps` in-process day times, then the CLI's when `cli` is given; the first
    config's day). One warm Simulator: the configs share SUMO's options, so the pre-loaded next day
    serves them all; CLI days are interleaved so that machine load hits both alike."""
    sim = Simulator(configs[0], log_file=log)
    day = sim.run_day(scn, choices, seed=42)  # warm: libsumo started, routes written, next day loaded
    times: list[list[float]] = [[] for _ in range(len(configs) + (cli is not None))]
    for _ in range(reps):
        if cli is not None:
            times[-1].append(cli())
        for i, cfg in enumerate(configs):
            sim.config = cfg
            t0 = time.perf_counter()
            sim.run_day(scn, choices, seed=42)
            times[i].append(time.perf_counter() - t0)
    sim.close()
    return times, day


def bench_network(name: str, networks_dir: Path | None, reps: int, pool_days: int, binary: str,
                  work: Path) -> dict[str, float | str | int]:
    scn = load_scenario(name, networks_dir=networks_dir, drop_unroutable=True)
    choices = scn.fft.argmin(1)
    cfg = SumoConfig()
    rou, trip = work / f"{name}.rou.xml", work / f"{name}.trip.xml"
    write_day_rou(rou, scn, choices)
    # The floor: the CLI cannot run our stuck rule, so both sides of that ratio use SUMO's own
    # (`--time-to-teleport N --time-to-teleport.remove`); with no rule a gridlocked day never ends.
    floor = SumoConfig(stuck_rule="sumo")
    (floor_t, cli_t), _ = timed_days(scn, choices, [floor], work / f"{name}-floor.log", reps,
                                cli=lambda: cli_day(binary, scn, rou, trip, floor, 42))
    (lib_t, exact_t), out_day = timed_days(scn, choices, [cfg, SumoConfig(stuck_rule="routerl")],
                                           work / f"{name}.log", reps)
    batch = np.repeat(choices[None], pool_days, axis=0)
    rates = {}
    for n_workers in (1, 2):
        with SumoPool(n_workers, config=cfg, log_dir=work / f"logs-{name}-{n_workers}") as pool:
            pool.run_days(scn, batch[:n_workers], [42] * n_workers)  # warm every worker
            t0 = time.perf_counter()
            out = pool.run_days(scn, batch, [42] * pool_days)
            wall = time.perf_counter() - t0
            rates[n_workers] = pool_days / wall
            overlap = sum(r.wall_time for r in out) / wall  # days in flight on average
    cli, lib, same = statistics.median(cli_t), statistics.median(lib_t), statistics.median(floor_t)
    return {
        "network": name, "agents": scn.n_agents, "mean_tt_min": float(out_day.travel_time.mean()),
        "removed": out_day.n_removed, "cli_s": cli, "run_day_s": lib, "same_rule_ratio": same / cli,
        "ratio": lib / cli, "exact_ratio": statistics.median(exact_t) / cli,
        "pool1_dps": rates[1], "pool2_dps": rates[2], "pool_speedup": rates[2] / rates[1],
        "overlap": overlap,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--networks", nargs="+", default=DEFAULT_NETS)
    ap.add_argument("--networks-dir", default=str(SHARED) if SHARED.is_dir() else None)
    ap.add_argument("--reps", type=int, default=5, help="CLI and run_day days per network")
    ap.add_argument("--pool-days", type=int, default=8, help="days per pool batch")
    args = ap.parse_args()
    import sumo

    binary = os.path.join(sumo.SUMO_HOME, "bin", "sumo")
    rows = []
    load0 = os.getloadavg()  # other work on the machine skews every column (the pool ones most)
    shm = "/dev/shm" if os.path.isdir("/dev/shm") else None
    with tempfile.TemporaryDirectory(prefix="sumo-speed-", dir=shm) as d:
        for name in args.networks:
            nd = None if name == "urb_grid" else args.networks_dir
            nets = Path(nd) if nd else None
            rows.append(bench_network(name, nets, args.reps, args.pool_days, binary, Path(d)))
            r = rows[-1]
            print(f"  done {name}: cli {r['cli_s']:.3f}s run_day {r['run_day_s']:.3f}s", flush=True)
    load = os.getloadavg()
    print(f"\ncpus={os.cpu_count()} load average at start {load0[0]:.1f}, at end {load[0]:.1f} "
          f"reps={args.reps} pool_days={args.pool_days} (medians; days/s over one batch)\n")
    print("CLI and 'same rule' days: SUMO's teleport rule (--time-to-teleport 600 "
          "--time-to-teleport.remove); run_day: urb-jax's default stuck rule; "
          "'routerl': RouteRL's literal.\n")
    print("| network | agents | mean tt (min) | removed | CLI day (s) | run_day same rule/CLI | run_day (s) "
          "| run_day/CLI | 'routerl' rule/CLI | pool 1w (days/s) | pool 2w (days/s) | 2w/1w "
          "| 2w days in flight |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['network']} | {r['agents']} | {r['mean_tt_min']:.2f} | {r['removed']} "
              f"| {r['cli_s']:.3f} | {r['same_rule_ratio']:.2f} "
              f"| {r['run_day_s']:.3f} | {r['ratio']:.2f} | {r['exact_ratio']:.2f} "
              f"| {r['pool1_dps']:.2f} | {r['pool2_dps']:.2f} "
              f"| {r['pool_speedup']:.2f} | {r['overlap']:.2f} |")


if __name__ == "__main__":
    main()
