"""Adapting humans: do hybrid and `--mode sumo` give the same human trajectory? Prints a table.

Usage:
  python benchmarks/adapt_humans.py --net saint_arnoult --alg iql_star --networks-dir ../shared/networks \\
      --task-conf TASK.json --train-days 1000 --results-dir DIR

TASK.json is a task config with `"should_humans_adapt": true` (e.g. config1 with it set). Runs the
two modes (a finished run folder is reused, so the script resumes), then puts side by side, per
hybrid round (a window of URB-equivalent days), the humans' mean time t_HDV: `--mode sumo`'s SUMO
days in that window, the hybrid population's surrogate days (rounds.csv `population_time_hdv`)
and its SUMO days; then the test phase's t_HDV of both.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from urb_jax.reporting.records import read_records


def run(args: argparse.Namespace, mode: str) -> Path:
    exp_id = f"{args.net}_{args.alg}_{mode}"
    folder = Path(args.results_dir) / exp_id
    if (folder / "metrics" / "BenchmarkMetrics.csv").is_file():
        return folder
    cmd = [sys.executable, "-m", "urb_jax.commands.cli", "train", "--alg", args.alg, "--net", args.net,
           "--task-conf", args.task_conf, "--train-days", str(args.train_days), "--mode", mode,
           "--id", exp_id, "--results-dir", args.results_dir, "--no-progress", "--overwrite"]
    if args.networks_dir:
        cmd += ["--networks-dir", args.networks_dir]
    subprocess.run(cmd, check=True)
    return folder


def hdv_by_day(folder: Path) -> pd.Series:
    rec = read_records(folder, columns=["day", "phase", "kind", "travel_time"])
    rec = rec[(rec["phase"] != "human") & (rec["kind"] == "HDV")]
    return rec.groupby("day")["travel_time"].mean()


def human_routes(folder: Path) -> tuple[pd.Series, pd.Series]:
    """(last human day's, first test day's) route of each agent that is human after mutation."""
    rec = read_records(folder, columns=["day", "phase", "agent", "kind", "action"])
    last = rec[rec["phase"] == "human"]["day"].max()
    first = rec[rec["phase"] == "test"]["day"].min()
    test = rec[rec["day"] == first].set_index("agent")
    hdv = test.index[test["kind"] == "HDV"]
    before = rec[rec["day"] == last].set_index("agent")["action"]
    return before.loc[hdv], test["action"].loc[hdv]


def moved(folder: Path) -> float:
    before, after = human_routes(folder)
    return float((before != after).mean())


def same_routes(a: Path, b: Path) -> float:
    return float((human_routes(a)[1] == human_routes(b)[1]).mean())


def table(sumo: Path, hybrid: Path) -> str:
    cfg_s, cfg_h = (json.loads((f / "exp_config.json").read_text()) for f in (sumo, hybrid))
    H = int(cfg_s["human_days"])
    per_day = hdv_by_day(sumo)  # URB day d after mutation = record day H + d
    rounds = pd.read_csv(hybrid / "rounds.csv")
    per_round = int(rounds["surrogate_days"].iloc[0] + rounds["sumo_days"].iloc[0])
    lines = ["| hybrid round | URB days | t_HDV mode sumo (SUMO days) | hybrid population (surrogate days) "
             "| hybrid SUMO days | abs diff, surrogate days | abs diff, SUMO days |",
             "|---|---|---|---|---|---|---|"]
    diffs_sur, diffs_sumo = [], []
    train_days = int(cfg_s["sumo_training_days"])
    for _, r in rounds.iterrows():
        lo, hi = int(r["round"] - 1) * per_round + 1, min(int(r["round"]) * per_round, train_days)
        if lo > train_days:
            break
        ref = per_day.loc[H + lo:H + hi].mean()
        d1, d2 = abs(r["population_time_hdv"] - ref), abs(r["sumo_time_hdv"] - ref)
        diffs_sur.append(d1)
        diffs_sumo.append(d2)
        lines.append(f"| {int(r['round'])} | {lo}-{hi} | {ref:.4f} | {r['population_time_hdv']:.4f} | "
                     f"{r['sumo_time_hdv']:.4f} | {d1:.4f} | {d2:.4f} |")
    m_s, m_h = (pd.read_csv(f / "metrics" / "BenchmarkMetrics.csv").iloc[0] for f in (sumo, hybrid))
    lines.append("")
    lines.append(f"t_pre {m_s['t_pre']:.4f} (both); test t_HDV: mode sumo {m_s['t_HDV_test']:.4f}, hybrid "
                 f"{m_h['t_HDV_test']:.4f} (diff {abs(m_s['t_HDV_test'] - m_h['t_HDV_test']):.4f}); "
                 f"human change t_pre -> test: {m_s['t_HDV_test'] - m_s['t_pre']:+.4f} (mode sumo)")
    lines.append(f"max abs diff per window: surrogate days {np.max(diffs_sur):.4f}, SUMO days "
                 f"{np.max(diffs_sumo):.4f}; t_CAV test: mode sumo {m_s['t_CAV']:.4f}, hybrid "
                 f"{m_h['t_CAV']:.4f}; human learning days: mode sumo {cfg_s['sumo_training_days']}, hybrid "
                 f"{cfg_h['surrogate_training_days'] + cfg_h['sumo_training_days']}")
    lines.append(f"humans on another route on the first test day than on the last human day: mode sumo "
                 f"{moved(sumo):.1%}, hybrid {moved(hybrid):.1%}; the same route in both runs on the first "
                 f"test day: {same_routes(sumo, hybrid):.1%}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--net", required=True)
    ap.add_argument("--alg", default="iql_star")
    ap.add_argument("--task-conf", required=True)
    ap.add_argument("--train-days", type=int, default=1000)
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--results-dir", default="results/adapt_humans")
    args = ap.parse_args()
    sumo, hybrid = run(args, "sumo"), run(args, "hybrid")
    print(table(sumo, hybrid))


if __name__ == "__main__":
    main()
