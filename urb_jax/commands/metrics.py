"""`urb-jax metrics`: recompute a finished run's metrics from its records.

Runs written before a metric column existed (e.g. the `*_duration` columns) get it without
re-simulating anything; the result is what `urb-jax train` / `baseline` would write today. Their
exp_config.json gains today's URB-facing keys too (names and phases, `urb_jax.reporting.urb_names`),
so URB's leaderboard reads older runs right."""

from __future__ import annotations

import argparse

SHOWN = ("t_pre", "t_CAV", "t_pre_duration", "t_CAV_duration", "winrate")


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "metrics", help="recompute metrics/BenchmarkMetrics.csv of finished runs from their records")
    parser.add_argument("runs", nargs="+", help="run folders (results/<exp_id>)")
    parser.set_defaults(func=run)


def recompute(folder: str) -> dict[str, float]:
    """Rewrite FOLDER/metrics/{Benchmark,Vector}Metrics.csv (atomically) from records.parquet."""
    from pathlib import Path

    from urb_jax.reporting.comparable import is_hybrid
    from urb_jax.reporting.records import finished_run_config, write_run_config, write_run_metrics
    from urb_jax.reporting.urb_names import names_of, phase_keys

    cfg = finished_run_config(folder)
    metrics, records = write_run_metrics(Path(folder), int(cfg["human_days"]), int(cfg["training_days"]),
                                         hybrid=is_hybrid(cfg))
    cfg.update(names_of(cfg), **phase_keys(records, int(cfg["human_days"])))
    write_run_config(folder, cfg)
    return metrics


def run(args: argparse.Namespace) -> int:
    for folder in args.runs:
        m = recompute(folder)
        print(f"{folder}: " + ", ".join(f"{k} {m[k]:.4f}" for k in SHOWN))
    return 0
