"""Wall time of S seeds trained together (vmap, one SUMO batch of S x P days per round) vs the
same S seeds one after another (`max_vmapped_seeds: 1`), side by side in one invocation.

The vmapped run simulates the human phase; the sequential run reuses it (`--human-phase-from`),
so the table compares the training walls (after the human phase) and also shows the totals.

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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--net", default="urb_grid")
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--alg", default="iql_star")
    ap.add_argument("--train-days", type=int, default=6000)
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--out", default="/tmp/multi_seed")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    from urb_jax.configio import find_config

    hyb = json.loads(find_config("hybrid", "default").read_text()) | {"max_vmapped_seeds": 1}
    (out / "sequential.json").write_text(json.dumps(hyb))
    seeds = a.seeds.split(",")
    base = [sys.executable, "-m", "urb_jax.cli", "train", "--alg", a.alg, "--net", a.net, "--train-days",
            str(a.train_days), "--seeds", a.seeds, "--results-dir", str(out / "results"), "--overwrite",
            "--no-progress"] + (["--networks-dir", a.networks_dir] if a.networks_dir else [])
    seq = ["--hybrid-conf", str(out / "sequential.json"), "--human-phase-from", f"vm_s{seeds[0]}"]
    runs = {"vm": [*base, "--id", "vm"], "seq": [*base, "--id", "seq", *seq]}
    rows = []
    for name, cmd in runs.items():  # in this order: the sequential run reuses vm's human phase
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        total = time.perf_counter() - t0
        cfgs = [json.loads((out / "results" / f"{name}_s{s}" / "exp_config.json").read_text()) for s in seeds]
        groups = {tuple(c["group"]): c["wall_time_s"] for c in cfgs}
        human = cfgs[0]["human_phase_s"]
        label = {"vm": "vmapped (together)", "seq": "sequential (max_vmapped_seeds 1)"}[name]
        rows.append((label, total, human, sum(groups.values()) - human, len(groups)))
    print(f"{a.alg} on {a.net}, {a.train_days} training days, seeds {a.seeds}")
    print("| run | process wall (s) | human phase (s) | training (s) | groups | training per seed (s) |")
    print("|---|---|---|---|---|---|")
    for name, total, human, train, g in rows:
        print(f"| {name} | {total:.0f} | {human:.0f} | {train:.0f} | {g} | {train / len(seeds):.0f} |")
    print(f"training speed-up (sequential / vmapped): {rows[1][3] / rows[0][3]:.2f}x")
    def metrics(run: str, s: str) -> bytes:
        return (out / "results" / f"{run}_s{s}" / "metrics" / "BenchmarkMetrics.csv").read_bytes()

    same = [metrics("vm", s) == metrics("seq", s) for s in seeds]
    print(f"metrics identical per seed (vmapped vs sequential): {same}")


if __name__ == "__main__":
    main()
