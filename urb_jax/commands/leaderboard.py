"""`urb-jax leaderboard results/`: mean/std per metric over seeds, WR, as Markdown and CSV."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("leaderboard", help="aggregate finished runs over seeds (Markdown + CSV)")
    parser.add_argument("results_dir", nargs="?", default="results", help="results root (default ./results)")
    parser.add_argument("--out", default=None,
                        help="write <out>.md and <out>.csv (default: <results_dir>/leaderboard.{md,csv})")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from urb_jax.core.atomic import write_bytes
    from urb_jax.reporting.leaderboard import aggregate, collect, to_markdown

    table = aggregate(collect(args.results_dir))
    md = to_markdown(table)
    base = Path(args.out) if args.out else Path(args.results_dir) / "leaderboard"
    write_bytes(base.with_suffix(".md"), md.encode())
    write_bytes(base.with_suffix(".csv"), table.to_csv(index=False).encode())
    print(md, end="")
    print(f"wrote {base.with_suffix('.md')} and {base.with_suffix('.csv')}")
    return 0
