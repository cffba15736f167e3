"""One row per multi-seed train run: mean t_CAV over its seeds, seeds at or below AON on the same
humans, both trip measures. Usage: python benchmarks/seed_table.py RESULTS_DIR [RESULTS_DIR ...]

Runs are grouped by their group id (the `--id` a `--seeds` run was started with: folders
`<id>_s<seed>`); a single-seed run is its own group. Prints a Markdown table.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd


def rows(results_dir: Path) -> list[dict]:
    out = []
    for cfg_path in sorted(results_dir.glob("*/exp_config.json")):
        cfg = json.loads(cfg_path.read_text())
        metrics = cfg_path.parent / "metrics" / "BenchmarkMetrics.csv"
        if cfg.get("status") != "done" or not metrics.is_file() or "aon_same_humans" not in cfg:
            continue
        m = pd.read_csv(metrics).iloc[0]
        aon = cfg["aon_same_humans"]
        out.append({"group": re.sub(r"_s\d+$", "", cfg_path.parent.name), "network": cfg["network"],
                    "algorithm": cfg.get("alg") or cfg["algorithm"], "alg_config": cfg.get("alg_config"),
                    "behaviour": cfg.get("av_behavior"), "credit": cfg.get("reward_credit", "group"),
                    "t_CAV": m["t_CAV"], "aon": aon["t_CAV"], "t_CAV_duration": m.get("t_CAV_duration"),
                    "aon_duration": aon.get("t_CAV_duration"), "wall_s": cfg.get("wall_time_s")})
    return out


def table(frames: list[dict]) -> str:
    df = pd.DataFrame(frames)
    lines = ["| run | network | algorithm (config) | behaviour, credit | seeds | t_CAV mean ± sd | AON | "
             "seeds <= AON | t_CAV (duration) | AON (duration) | wall s |", "|---|" * 1 + "---|" * 10]
    for group, g in df.groupby("group", sort=True):
        r = g.iloc[0]
        lines.append(
            f"| {group} | {r['network']} | {r['algorithm']} ({r['alg_config']}) | {r['behaviour']}, "
            f"{r['credit']} | {len(g)} | {g['t_CAV'].mean():.4f} ± {g['t_CAV'].std(ddof=0):.4f} | "
            f"{g['aon'].mean():.4f} | {int((g['t_CAV'] <= g['aon'] + 1e-9).sum())}/{len(g)} | "
            f"{np.nanmean(g['t_CAV_duration'].astype(float)):.4f} | "
            f"{np.nanmean(g['aon_duration'].astype(float)):.4f} | "
            f"{g['wall_s'].max():.0f} |")
    return "\n".join(lines)


def main() -> None:
    frames = [r for d in sys.argv[1:] for r in rows(Path(d))]
    print(table(frames) if frames else "no finished runs")


if __name__ == "__main__":
    main()
