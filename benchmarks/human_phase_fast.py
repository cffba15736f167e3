"""The fast human phase against URB's all-SUMO one: wall time, t_pre and the humans' final choices.

Per network, three human phases of H days (task config1, deterministic Gawron humans):
  A  every day in SUMO (URB; `human_surrogate_days: 0`), SUMO seed = env seed;
  B  A with another SUMO seed: SUMO's own noise, i.e. how far two faithful phases land apart;
  C  the first S days on the surrogate fitted to the varied calibration days, the rest in SUMO.
C is as faithful as SUMO's own noise allows when |t_pre(C) - t_pre(A)| is within |t_pre(B) - t_pre(A)|
(or within 0.5%), and the share of humans whose final route differs from A's is within B's.
SUMO days are kept under --out/days (a rerun reads them back; resumable), rows in --out/rows.json.

    python benchmarks/human_phase_fast.py --networks-dir ../shared/networks \
        --networks saint_arnoult provins ingolstadt_custom --surrogate-days 150 --out /tmp/hpf
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from urb_jax.city.scenario import load_scenario
from urb_jax.core.progress import Progress
from urb_jax.game.config import load_task_config
from urb_jax.sumo_bridge import ARRIVED, MemoExecutor, SumoPool
from urb_jax.training.human_phase import run_human_phase
from urb_jax.training.hybrid.plan import load_hybrid_config

WINDOW = 50  # t_pre: the last 50 human days


class Reseeded:
    """An executor whose days all run with one SUMO seed (variant B)."""

    def __init__(self, executor, seed: int) -> None:
        self.executor, self.seed = executor, seed

    def run_days(self, scenario, choices, seeds, is_cav=None):
        return self.executor.run_days(scenario, choices, [self.seed] * len(seeds), is_cav)


def phase_row(scn, task, hyb, executor, env_seed: int) -> dict:
    t0 = time.perf_counter()
    bar = Progress(task.human_learning_episodes + hyb.calib_varied_days, False)
    human = run_human_phase(scn, task, hyb, executor, env_seed, bar, calibrate=True)
    wall = time.perf_counter() - t0
    last = human.records[-WINDOW:]
    tt = [np.nanmean(r.result.travel_time) for r in last]
    dur = [np.nanmean(np.where(r.result.status == ARRIVED, r.result.duration, np.nan)) for r in last]
    return {"wall_s": round(wall, 1), "sumo_human_days": len(human.records), "t_pre": float(np.mean(tt)),
            "t_pre_duration": float(np.mean(dur) / 60.0), "daily": [float(x) for x in tt],
            "final": human.records[-1].choices.tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--networks", nargs="+", default=["saint_arnoult", "provins", "ingolstadt_custom"])
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--surrogate-days", type=int, default=150)
    ap.add_argument("--varied-days", type=int, default=None,
                    help="calibration varied days (default: the hybrid config's)")
    ap.add_argument("--env-seed", type=int, default=42)
    ap.add_argument("--out", default="/tmp/human_phase_fast")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows_file = out / "rows.json"
    rows = json.loads(rows_file.read_text()) if rows_file.is_file() else {}
    task, _ = load_task_config("config1")
    base, _ = load_hybrid_config("default")
    if args.varied_days is not None:
        base = dataclasses.replace(base, calib_varied_days=args.varied_days)
    print(f"load average {os.getloadavg()[0]:.1f}; H = {task.human_learning_episodes}, "
          f"S = {args.surrogate_days}, varied days {base.calib_varied_days}", flush=True)
    pool = SumoPool(2)
    try:
        for net in args.networks:
            scn = load_scenario(net, networks_dir=args.networks_dir, drop_unroutable=True)
            # Each variant its own day store: a wall time never includes another variant's days.
            variants = {"C": (args.surrogate_days, args.env_seed), "A": (0, args.env_seed),
                        "B": (0, args.env_seed + 1)}
            for name, (s_days, sumo_seed) in variants.items():
                key = f"{net}:{name}:{s_days}:{base.calib_varied_days}"
                if key not in rows:
                    memo = MemoExecutor(pool, store_dir=out / "days" / key.replace(":", "-"))
                    ex = memo if sumo_seed == args.env_seed else Reseeded(memo, sumo_seed)
                    hyb = dataclasses.replace(base, human_surrogate_days=s_days)
                    rows[key] = phase_row(scn, task, hyb, ex, args.env_seed)
                    rows_file.write_text(json.dumps(rows))
                r = rows[key]
                print(f"{net:18s} {name} S={s_days:3d} wall {r['wall_s']:7.1f} s  SUMO human days "
                      f"{r['sumo_human_days']:3d}  t_pre {r['t_pre']:.4f} "
                      f"(duration {r['t_pre_duration']:.4f})",
                      flush=True)
    finally:
        pool.close()
    table(rows, args)


def table(rows: dict, args) -> None:
    print("\n| network | t_pre A (all SUMO) | B (SUMO seed +1) | C (fast) | abs(C-A) | abs(B-A) | "
          "final routes C≠A | B≠A | daily mean abs(C-A), last 50 | wall A | wall C | speed-up |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for net in args.networks:
        got = {k.split(":")[1]: v for k, v in rows.items() if k.startswith(f"{net}:")
               and (k.split(":")[1] != "C" or k.split(":")[2] == str(args.surrogate_days))}
        if len(got) < 3:
            continue
        a, b, c = got["A"], got["B"], got["C"]
        fa, fb, fc = (np.asarray(x["final"]) for x in (a, b, c))
        daily = np.mean(np.abs(np.asarray(c["daily"]) - np.asarray(a["daily"])))
        print(f"| {net} | {a['t_pre']:.4f} | {b['t_pre']:.4f} | {c['t_pre']:.4f} | "
              f"{abs(c['t_pre'] - a['t_pre']):.4f} | {abs(b['t_pre'] - a['t_pre']):.4f} | "
              f"{np.mean(fc != fa):.1%} | {np.mean(fb != fa):.1%} | "
              f"{daily:.4f} | {a['wall_s']:.0f} s | {c['wall_s']:.0f} s | {a['wall_s'] / c['wall_s']:.1f}x |")


if __name__ == "__main__":
    sys.exit(main())
