"""Wall time of S seeds trained together (vmap, one SUMO batch of S x P days per round) vs the
same S seeds one after another (`max_vmapped_seeds: 1`), side by side in one invocation.

The first run simulates the human phase, the second reuses it (`--human-phase-from`), so the
table compares the training walls (after the human phase) and also shows the totals.

    python benchmarks/multi_seed_speed.py --net saint_arnoult --networks-dir ../shared/networks \
        --alg iql_star --train-days 6000 --seeds 0,1,2,3,4 --out /tmp/multi_seed
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

VM, SEQ = "vmapped (together)", "sequential (max_vmapped_seeds 1)"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--net", default="urb_grid")
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--alg", default="iql_star")
    ap.add_argument("--train-days", type=int, default=6000)
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--out", default="/tmp/multi_seed")
    ap.add_argument("--seq-first", action="store_true",
                    help="run the sequential run first (it simulates the human phase; vmapped reuses it)")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    from urb_jax.core.configio import find_config

    hyb = json.loads(find_config("hybrid", "default").read_text()) | {"max_vmapped_seeds": 1}
    (out / "sequential.json").write_text(json.dumps(hyb))
    seeds = a.seeds.split(",")
    base = [sys.executable, "-m", "urb_jax.commands.cli", "train", "--alg", a.alg, "--net", a.net,
            "--train-days", str(a.train_days), "--seeds", a.seeds, "--results-dir", str(out / "results"),
            "--overwrite", "--no-progress"] + (["--networks-dir", a.networks_dir] if a.networks_dir else [])
    runs = {"vm": [*base, "--id", "vm"],
            "seq": [*base, "--id", "seq", "--hybrid-conf", str(out / "sequential.json")]}
    first, second = ("seq", "vm") if a.seq_first else ("vm", "seq")
    runs = {first: runs[first], second: [*runs[second], "--human-phase-from", f"{first}_s{seeds[0]}"]}
    rows = []
    for name, cmd in runs.items():  # the second run reuses the first one's human phase
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        total = time.perf_counter() - t0
        cfgs = [json.loads((out / "results" / f"{name}_s{s}" / "exp_config.json").read_text()) for s in seeds]
        groups = {tuple(c["group"]): c["wall_time_s"] for c in cfgs}
        human = cfgs[0]["human_phase_s"]
        label = {"vm": VM, "seq": SEQ}[name]
        # rounds.csv times are the group's; count each group once (its first seed).
        firsts = {c["group"][0] for c in cfgs}
        rounds = pd.concat([pd.read_csv(out / "results" / f / "rounds.csv") for f in firsts])
        sur, sumo = rounds["surrogate_s"].sum(), rounds["sumo_s"].sum()
        train = sum(groups.values()) - human
        rows.append((label, total, human, train, len(groups), sur, sumo, train - sur - sumo))
    print(f"{a.alg} on {a.net}, {a.train_days} training days, seeds {a.seeds}")
    print("| run | process wall (s) | human phase (s) | training (s) | groups | per seed (s) "
          "| rounds: surrogate (s) | rounds: SUMO + updates + refit (s) | calibration + test (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, total, human, train, g, sur, sumo, rest in rows:
        print(f"| {name} | {total:.0f} | {human:.0f} | {train:.0f} | {g} | {train / len(seeds):.0f} "
              f"| {sur:.0f} | {sumo:.0f} | {rest:.0f} |")
    train = {r[0]: r[3] for r in rows}
    print(f"training speed-up (sequential / vmapped): {train[SEQ] / train[VM]:.2f}x")

    def metrics(run: str, s: str) -> bytes:
        return (out / "results" / f"{run}_s{s}" / "metrics" / "BenchmarkMetrics.csv").read_bytes()

    same = [metrics("vm", s) == metrics("seq", s) for s in seeds]
    print(f"metrics identical per seed (vmapped vs sequential): {same}")


if __name__ == "__main__":
    main()
