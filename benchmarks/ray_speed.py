"""SUMO days/s: RayExecutor (local Ray, N actors) vs SumoPool (N workers), side by side.

Both executors are started (start-up time reported), warmed with one day per worker, then run the
same batches alternately (pool, ray, pool, ray, ...) so machine load hits both alike; the table
reports medians over `--reps` batches. Each batch is `--days` days with random route choices
(seed 42, as the trainer's days). "days in flight" is the sum of in-worker day times over the
batch wall time (N: every worker busy all the time; lower: dispatch overhead or idle workers).

    python benchmarks/ray_speed.py [--networks saint_arnoult] [--workers 2] [--days 8] [--reps 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from urb_jax.city.scenario import load_scenario
from urb_jax.sumo_bridge import SumoPool
from urb_jax.sumo_bridge.ray_executor import RayExecutor

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "networks"


def bench(name: str, networks_dir: Path | None, workers: int, days: int, reps: int, work: Path) -> dict:
    scn = load_scenario(name, networks_dir=networks_dir)
    rng = np.random.default_rng(0)
    seeds = [42] * days
    t0 = time.perf_counter()
    pool = SumoPool(workers, log_dir=work / f"pool-{name}")
    t_pool = time.perf_counter() - t0
    t0 = time.perf_counter()
    ray_ex = RayExecutor(workers, log_dir=work / f"ray-{name}")  # starts Ray if not running
    t_ray = time.perf_counter() - t0
    rates: dict[str, list[float]] = {"pool": [], "ray": []}
    flight: dict[str, list[float]] = {"pool": [], "ray": []}
    try:
        warm = rng.integers(0, scn.k, size=(workers, scn.n_agents))
        same = [a.same_as(b) for a, b in zip(pool.run_days(scn, warm, seeds[:workers]),
                                              ray_ex.run_days(scn, warm, seeds[:workers]), strict=True)]
        assert all(same), "Ray and pool days differ"
        for _ in range(reps):
            batch = rng.integers(0, scn.k, size=(days, scn.n_agents))
            for label, ex in (("pool", pool), ("ray", ray_ex)):
                t0 = time.perf_counter()
                out = ex.run_days(scn, batch, seeds)
                wall = time.perf_counter() - t0
                rates[label].append(days / wall)
                flight[label].append(sum(r.wall_time for r in out) / wall)
    finally:
        pool.close()
        ray_ex.close()
    p, r = statistics.median(rates["pool"]), statistics.median(rates["ray"])
    return {"network": name, "agents": scn.n_agents, "pool_start": t_pool, "ray_start": t_ray,
            "pool": p, "ray": r, "ratio": r / p, "pool_flight": statistics.median(flight["pool"]),
            "ray_flight": statistics.median(flight["ray"])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--networks", nargs="+", default=["saint_arnoult"])
    ap.add_argument("--networks-dir", default=str(SHARED) if SHARED.is_dir() else None)
    ap.add_argument("--workers", type=int, default=2, help="pool workers = Ray actors")
    ap.add_argument("--days", type=int, default=8, help="days per batch")
    ap.add_argument("--reps", type=int, default=5, help="batches per executor (alternating)")
    args = ap.parse_args()
    load0 = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory(prefix="ray-speed-") as d:
        for name in args.networks:
            nd = None if name == "urb_grid" else args.networks_dir
            rows.append(bench(name, Path(nd) if nd else None, args.workers, args.days, args.reps, Path(d)))
    load = os.getloadavg()
    n = args.workers
    print(f"\ncpus={os.cpu_count()} load average at start {load0[0]:.1f}, at end {load[0]:.1f} "
          f"workers=actors={n} days/batch={args.days} reps={args.reps} (medians)\n")
    print(f"| network | agents | pool start (s) | Ray start (s) | pool {n}w (days/s) | Ray {n}a (days/s) "
          "| Ray/pool | pool days in flight | Ray days in flight |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['network']} | {r['agents']} | {r['pool_start']:.1f} | {r['ray_start']:.1f} "
              f"| {r['pool']:.2f} | {r['ray']:.2f} | {r['ratio']:.2f} | {r['pool_flight']:.2f} "
              f"| {r['ray_flight']:.2f} |")


if __name__ == "__main__":
    main()
