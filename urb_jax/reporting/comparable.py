"""Which of a run's metrics mean what URB's columns of the same name mean.

URB's t_train, costs of learning (cost_of_learning, _humans, _CAVs) and time lost (avg_time_lost,
avg_human_time_lost, avg_CAV_time_lost) are computed over every training day. A hybrid run
(`--mode hybrid`: most training days on the surrogate) records only its SUMO training days, some
16-40 of thousands, the last and best trained ones: its values there are 3-30x smaller than URB's,
and a urb-jax row on URB's leaderboard would look better for a reason unrelated to learning. So a
hybrid run keeps those values under names of their own (`<column>_sumo_days`) and leaves URB's
columns empty (NaN) in every URB-facing output: BenchmarkMetrics.csv, the leaderboard, export-urb
and the paper page. A `--mode sumo` run (every training day in SUMO) and a baseline keep URB's
columns: their values mean what URB's mean. docs/metrics.md, "Comparable columns".
"""

from __future__ import annotations

import math
from typing import Any

from urb_jax.reporting.metrics import BENCHMARK_COLUMNS

# URB's columns that a hybrid run's SUMO days cannot stand for -> the name its value is kept under
SUMO_DAYS = {c: f"{c}_sumo_days" for c in (
    "t_train", "cost_of_learning", "cost_of_learning_humans", "cost_of_learning_CAVs",
    "avg_time_lost", "avg_human_time_lost", "avg_CAV_time_lost")}
# every metric a run's row can hold (BenchmarkMetrics.csv's columns and `urb-jax optimum`'s gap)
METRIC_COLUMNS = [*BENCHMARK_COLUMNS, *SUMO_DAYS.values(), "optimality_gap"]
# the columns of a run's leaderboard row that say how many training days ran where
DAYS_COLUMNS = ("sumo_training_days", "surrogate_training_days")


def is_hybrid(cfg: dict[str, Any]) -> bool:
    """A run some of whose training days ran on the surrogate (exp_config.json's
    `surrogate_training_days` > 0); a ledger row from before that key was kept: its `script` says
    `--mode hybrid`."""
    days = cfg.get("surrogate_training_days")
    if days is None or (isinstance(days, float) and math.isnan(days)):
        return " --mode hybrid " in f"{cfg.get('script') or ''} "
    return float(days) > 0


def comparable_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """A hybrid run's metrics with URB's SUMO-days-only columns moved to their `_sumo_days` names
    and left NaN (idempotent: a row already moved stays as it is)."""
    out = dict(metrics)
    for urb, ours in SUMO_DAYS.items():
        kept = out.get(ours)
        if kept is None or (isinstance(kept, float) and math.isnan(kept)):
            out[ours] = out.get(urb, math.nan)
        out[urb] = math.nan
    return out


def hybrid_note(row: dict[str, Any]) -> str:
    """What a URB column of a hybrid row shows instead of a value: 'not comparable: hybrid (N SUMO
    of M training days)', the days from the row's DAYS_COLUMNS (an older ledger row lacks them)."""
    sumo, sur = (row.get(c) for c in DAYS_COLUMNS)
    if sumo is None or sur is None or any(isinstance(x, float) and math.isnan(x) for x in (sumo, sur)):
        return "not comparable: hybrid (its SUMO training days not recorded)"
    return f"not comparable: hybrid ({int(sumo)} SUMO of {int(sumo) + int(sur)} training days)"
