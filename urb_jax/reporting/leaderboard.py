"""Aggregate runs over seeds: mean and std per metric, WR in %, as Markdown and CSV.

Runs are grouped as URB's leaderboard generator groups them (`urb_names.URB_COLLAPSE_FIELDS`:
exp type, env and task config, network, algorithm, script, algorithm config), with URB's names:
`algorithm` is URB's (iql_torchrl, iql, ... ; a baseline's model), `script` says who ran it, so a
urb-jax row never merges with a row of URB's own runs, nor a hybrid run with a `--mode sumo` one,
nor runs that differ in their `--set` overrides (`script` ends with them). A hybrid run's t_train,
costs of learning and time lost cover its SUMO training days only: their URB columns are empty
(N/A) and the values are kept as `<column>_sumo_days` (`comparable`, docs/metrics.md).
Older urb-jax runs are read under their current names (`urb_names.names_of`). Each run
contributes the first row of its BenchmarkMetrics.csv.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from urb_jax.core.errors import UrbJaxError
from urb_jax.reporting.comparable import DAYS_COLUMNS, comparable_metrics, is_hybrid
from urb_jax.reporting.train_days import ASKED
from urb_jax.reporting.urb_names import leaderboard_fields

KEYS = ["network", "algorithm", "script", "alg_config", "task_config", "env_config", "exp_type"]
SHOWN = ["t_pre", "t_CAV", "t_HDV_test", "t_test", "cost_of_learning", "delta_V", "delta_L",
         "CAV_advantage", "Effect_of_change", "Effect_of_remaining",
         "t_pre_duration", "t_CAV_duration",  # the published tables' measure (docs/metrics.md)
         "optimality_gap"]  # the run's objective minus the optimum reference's (urb-jax optimum)


def collect(results_dir: str | os.PathLike) -> pd.DataFrame:
    """One row per finished run under results_dir (config keys + metrics)."""
    rows = collect_folders(sorted(p.parent for p in Path(results_dir).glob("*/exp_config.json")))
    if rows.empty:
        raise UrbJaxError(
            f"{results_dir}: no finished runs (exp_config.json + metrics/BenchmarkMetrics.csv)."
        )
    return rows


def collect_folders(folders: list[Path]) -> pd.DataFrame:
    """One row per finished run among `folders` (config keys, metrics and its folder)."""
    rows = []
    for folder in folders:
        cfg_path = Path(folder) / "exp_config.json"
        metrics_path = cfg_path.parent / "metrics" / "BenchmarkMetrics.csv"
        if not (cfg_path.is_file() and metrics_path.is_file()):
            continue
        cfg = json.loads(cfg_path.read_text())
        rows.append({"exp_id": cfg_path.parent.name, "folder": str(cfg_path.parent), **_fields(cfg),
                     "env_seed": cfg.get("env_seed"), **_metrics(cfg, cfg_path.parent)})
    return pd.DataFrame(rows)


def _fields(cfg: dict[str, Any]) -> dict[str, Any]:
    """A run's leaderboard fields (URB's names, '?' where unknown), its seed where it has one, and
    its training days in SUMO and on the surrogate (`comparable.DAYS_COLUMNS`) and the days it asked
    for where recorded."""
    fields = leaderboard_fields(cfg)
    seed = fields.pop("torch_seed")
    out = {k: ("?" if v is None else v) for k, v in fields.items()}
    days = {k: cfg[k] for k in DAYS_COLUMNS if cfg.get(k) is not None}
    asked = (cfg.get("train_args") or {}).get("train_days")
    if days and asked is not None:  # what it asked for: more trained was a round-up (reporting.train_days)
        days[ASKED] = asked
    return {**out, **({"torch_seed": seed} if seed is not None else {}), **days}


def _metrics(cfg: dict[str, Any], folder: Path) -> dict[str, Any]:
    """The run's BenchmarkMetrics row, a hybrid run's SUMO-days-only columns under their own names
    (also for runs written before they were: `comparable_metrics`), and `urb-jax optimum`'s gap."""
    metrics = pd.read_csv(folder / "metrics" / "BenchmarkMetrics.csv").iloc[0].to_dict()
    metrics = comparable_metrics(metrics) if is_hybrid(cfg) else metrics
    optimum = folder / "optimum.json"  # `urb-jax optimum RUN`: the SUMO-checked reference
    if optimum.is_file():
        metrics["optimality_gap"] = json.loads(optimum.read_text())["optimality_gap"]
    return metrics


def aggregate(runs: pd.DataFrame, metrics: Sequence[str] = SHOWN) -> pd.DataFrame:
    """Mean and sample std (ddof=1; 0 for one run) over seeds per group of each of `metrics`; WR = %
    of runs with winrate 1."""
    out = []
    for key, g in runs.groupby(KEYS, sort=True):
        row = dict(zip(KEYS, key, strict=True))
        row["alg"] = g["alg"].iloc[0]  # urb-jax's id (empty for URB's own runs)
        row["runs"] = len(g)
        row["WR"] = float(100.0 * g["winrate"].mean()) if g["winrate"].notna().any() else np.nan
        for m in metrics:
            if m in g:
                vals = pd.to_numeric(g[m], errors="coerce")
                row[f"{m}_mean"] = vals.mean()
                sd = vals.std(ddof=1) if vals.count() > 1 else 0.0
                row[f"{m}_std"] = sd if vals.notna().any() else np.nan
        out.append(row)
    return pd.DataFrame(out)


def label(row: pd.Series) -> str:
    """URB's algorithm name, with urb-jax's --alg id where they differ ("iql (--alg iql_star)")."""
    alg, urb = str(row.get("alg") or ""), str(row["algorithm"])
    return urb if not alg or alg in (urb, f"baseline_{urb}") else f"{urb} (--alg {alg})"


def to_markdown(table: pd.DataFrame) -> str:
    head = ["network", "algorithm", "script", "alg_config", "task", "runs", "WR %", *SHOWN]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in table.iterrows():
        cells = [str(r["network"]), label(r), str(r["script"]), str(r["alg_config"]), str(r["task_config"]),
                 str(r["runs"]),
                 "N/A" if pd.isna(r["WR"]) else f"{r['WR']:.0f}"]
        for m in SHOWN:
            mean, std = r.get(f"{m}_mean", np.nan), r.get(f"{m}_std", np.nan)
            cells.append("N/A" if pd.isna(mean) else f"{mean:.3f} ± {std:.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
