"""SUMO-measured CAV time vs training wall time for finished `urb-jax train` runs (e.g. --mode hybrid
and --mode sumo on the same network), from their rounds.csv: each round's SUMO days are played by
the current (exploring) policies, so their mean CAV time is the learning curve measured in SUMO.

Usage: python benchmarks/hybrid_vs_sumo.py RUN_FOLDER [RUN_FOLDER ...] [--plot out.png]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd


def curve(folder: Path) -> pd.DataFrame:
    d = pd.read_csv(folder / "rounds.csv")
    cfg = json.loads((folder / "exp_config.json").read_text())
    # Seeds trained together share each round's wall time: charge each seed its share.
    wall = (d.get("surrogate_s", 0.0) + d.get("sumo_s", 0.0)) / cfg.get("seeds_together", 1)
    return pd.DataFrame({"run": folder.name, "mode": cfg["mode"], "round": d["round"],
                         "train_wall_s": wall.cumsum(), "sumo_t_CAV": d["sumo_time_cav"]})


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--plot", type=Path, default=None)
    args = ap.parse_args()
    curves = [curve(f) for f in args.runs]
    for folder, c in zip(args.runs, curves, strict=True):
        m = pd.read_csv(folder / "metrics" / "BenchmarkMetrics.csv")
        print(f"\n{c['run'].iloc[0]} ({c['mode'].iloc[0]}): test t_CAV {m['t_CAV'].iloc[0]:.4f}, "
              f"t_pre {m['t_pre'].iloc[0]:.4f}")
        step = max(1, len(c) // 10)
        print(c.iloc[::step].round(3).to_string(index=False))
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4))
        for c in curves:
            ax.plot(c["train_wall_s"], c["sumo_t_CAV"], label=f"{c['run'].iloc[0]} ({c['mode'].iloc[0]})")
        ax.set_xlabel("training wall time per seed (s, after the human phase)")
        ax.set_ylabel("SUMO mean CAV time of the round's days (min)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)


if __name__ == "__main__":
    main()
