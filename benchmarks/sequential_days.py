"""The human phase's SUMO pattern: one-day batches one after another (each day's choices depend on
the last day's result), in-process (`InProcessExecutor`) and on a `SumoPool` of 2 workers, and
the pool's usual batch of several days for comparison. Wall seconds per day, medians over the
days; the in-process days' CPU seconds too (robust to other work on the machine).

    python benchmarks/sequential_days.py [--networks saint_arnoult provins] [--days 20]

It uses only the executors' public API, so the same script times another checkout:
`PYTHONPATH=/path/to/other/checkout python benchmarks/sequential_days.py` (alternate the two to
compare them on a busy machine).
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
from urb_jax.sumo_bridge import InProcessExecutor, SumoPool

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "networks"


def one_day_batches(executor, scn, days: np.ndarray, seed: int) -> tuple[list[float], list[float]]:
    """Wall and CPU (this process) seconds of each one-day batch, run one after another."""
    walls, cpus = [], []
    for c in days:
        t0, c0 = time.perf_counter(), time.process_time()
        executor.run_days(scn, c[None], [seed])
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return walls, cpus


def bench(name: str, networks_dir: Path | None, n_days: int, log_dir: Path) -> dict[str, float]:
    scn = load_scenario(name, networks_dir=networks_dir, drop_unroutable=True)
    rng = np.random.default_rng(0)
    days = rng.integers(0, scn.k, size=(n_days, scn.n_agents))  # [D, N] a new day each time
    ex = InProcessExecutor(log_file=log_dir / f"{name}-inproc.log")
    ex.run_days(scn, days[:1], [42])  # warm: libsumo started, routes written, next day loaded
    walls, cpus = one_day_batches(ex, scn, days, 42)
    ex.close()
    with SumoPool(2, log_dir=log_dir / f"{name}-pool") as pool:
        pool.run_days(scn, days[:2], [42, 42])  # warm both workers
        pwalls, _ = one_day_batches(pool, scn, days, 42)
        t0 = time.perf_counter()
        pool.run_days(scn, days, [42] * n_days)
        batch = (time.perf_counter() - t0) / n_days
    return {"inproc_s": statistics.median(walls), "inproc_cpu_s": statistics.median(cpus),
            "pool_seq_s": statistics.median(pwalls), "pool_batch_s": batch}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--networks", nargs="+", default=["saint_arnoult", "provins"])
    ap.add_argument("--networks-dir", default=str(SHARED) if SHARED.is_dir() else None)
    ap.add_argument("--days", type=int, default=20, help="one-day batches per executor")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    rows = {}
    with tempfile.TemporaryDirectory(prefix="seq-days-") as d:
        for name in args.networks:
            nets = None if name == "urb_grid" else Path(args.networks_dir)
            rows[name] = bench(name, nets, args.days, Path(d))
    print(f"load average {load0:.1f} -> {os.getloadavg()[0]:.1f}; days={args.days}; "
          f"import {Path(__import__('urb_jax').__file__).parent.parent}")
    print("| network | in-process day (s) | its CPU (s) | pool 2w, one-day batches (s/day) "
          "| pool 2w, one batch (s/day) |")
    print("|---|---|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {r['inproc_s']:.3f} | {r['inproc_cpu_s']:.3f} | {r['pool_seq_s']:.3f} "
              f"| {r['pool_batch_s']:.3f} |")


if __name__ == "__main__":
    main()
