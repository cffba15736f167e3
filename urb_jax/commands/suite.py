"""`urb-jax suite FILE`: a suite of experiments, resumable, then its tables and figures."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "suite", help="run a suite file's experiments as one resumable job (finished runs are skipped, "
                      "stopped ones resumed), then write their tables and figures")
    parser.add_argument("suite", help='a suite id (configs/suites/<id>.json, e.g. nine_networks) or file: '
                                      '{"title", "runs": [{"kind": "train"|"baseline", "id", '
                                      '"args": {run_train / run_baseline arguments}}]}')
    parser.add_argument("--networks-dir", default=None,
                        help="folder of URB networks, for every run whose args do not name one")
    parser.add_argument("--only", default=None, help="comma-separated run ids: run (and report) just these")
    parser.add_argument("--results-dir", default="results")
    parser.add_argument("--out", default=None, help="report folder (default: RESULTS_DIR/suite_<file stem>)")
    parser.add_argument("--no-progress", action="store_true", help="plain progress lines only")
    parser.add_argument("--report-only", action="store_true", help="write the report of the finished runs")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from urb_jax.core.configio import find_config
    from urb_jax.experiment.suite import load_suite, run_suite, select, status, write_report

    spec = select(load_suite(find_config("suites", args.suite)), args.only, args.networks_dir)
    results = Path(args.results_dir)
    if args.report_only:
        folders = [results / n for r in spec.runs if status(results, r) == "done" for n in r.folder_names()]
    else:
        folders = run_suite(spec.runs, results, progress=not args.no_progress,
                            log=lambda line: print(line, flush=True))
    out = Path(args.out) if args.out else results / f"suite_{Path(args.suite).stem}"
    print(f"report: {write_report(spec.title, folders, out, spec.preamble)}")
    return 0
