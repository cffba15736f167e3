"""Print the baseline comparison table of docs/results_baselines.md from finished runs.

Usage: python benchmarks/baseline_table.py [results_dir]

For each results/<model>_<net>_config1_s<seed>/ run: t_pre, t_CAV, t_HDV_test, WR and wall time
next to the paper's values, plus `t_CAV_pre` (the CAV group's own mean over the pre days) and
the 5-95% range of that group mean over 1000 other random draws of the same CAV share: t_CAV
compares a *subset* of agents with everyone's t_pre, so the draw alone moves it;
t_CAV - t_CAV_pre is what the policy changed for the CAVs themselves.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from urb_jax.reporting.metrics import PRE_WINDOW
from urb_jax.reporting.records import read_records

PAPER = {  # network: (t_pre, AON t_CAV, random t_CAV), minutes (URB paper)
    "saint_arnoult": (3.15, 3.01, 3.58),
    "provins": (2.80, 2.76, 3.04),
    "ingolstadt_custom": (4.21, 4.37, 4.81),
}


def main(results_dir: str = "results") -> None:
    rows = []
    for cfg_path in sorted(Path(results_dir).glob("*/exp_config.json")):
        cfg = json.loads(cfg_path.read_text())
        net, model = cfg.get("network"), cfg.get("baseline_model")
        bm_path = cfg_path.parent / "metrics" / "BenchmarkMetrics.csv"
        if net not in PAPER or cfg.get("task_config") != "config1" or not bm_path.is_file():
            continue
        m = pd.read_csv(bm_path).iloc[0]
        H = cfg["human_learning_episodes"]
        rec = read_records(cfg_path.parent, columns=["day", "agent", "kind", "travel_time"])
        pre = rec[(rec.day > H - PRE_WINDOW) & (rec.day <= H)].groupby("agent")["travel_time"].mean()
        last = rec[rec.day == rec.day.max()]
        cav = last.loc[last.kind == "CAV", "agent"].to_numpy()
        rng = np.random.default_rng(0)
        draws = [pre.iloc[rng.choice(len(pre), len(cav), replace=False)].mean() for _ in range(1000)]
        p_pre, p_aon, p_rand = PAPER[net]
        p_cav = p_aon if model == "aon" else p_rand
        rows.append({
            "network": net, "model": model, "t_pre": m.t_pre, "paper t_pre": p_pre,
            "d_pre %": 100 * (m.t_pre / p_pre - 1), "t_CAV": m.t_CAV, "paper t_CAV": p_cav,
            "d_CAV %": 100 * (m.t_CAV / p_cav - 1), "t_HDV_test": m.t_HDV_test, "WR": int(m.winrate),
            "t_CAV_pre": pre[cav].mean(), "t_CAV - t_CAV_pre": m.t_CAV - pre[cav].mean(),
            "draw 5-95%": f"{np.percentile(draws, 5):.2f}-{np.percentile(draws, 95):.2f}",
            "wall s": cfg.get("wall_time_s"),
        })
    table = pd.DataFrame(rows)
    if not len(table):
        print("no finished config1 runs")
        return
    print("| " + " | ".join(table.columns) + " |")
    print("|" + "---|" * len(table.columns))
    for _, r in table.iterrows():
        print("| " + " | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in r) + " |")


if __name__ == "__main__":
    main(*sys.argv[1:])
