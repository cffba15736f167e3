"""`urb-jax suite FILE`: a suite of experiments, resumable, then its tables and figures."""

from __future__ import annotations

import argparse
import sys

from urb_jax.commands.common import add_day_store_flag


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "suite", help="run a suite file's experiments as one resumable job (finished runs are skipped, "
                      "stopped ones resumed), then write their tables and figures")
    parser.add_argument("suite", nargs="?",
                        help='a suite id (configs/suites/<id>.json, e.g. scenario1; see --list) or a file: '
                             '{"title", "runs": [{"kind": "train"|"baseline", "id", '
                             '"args": {run_train / run_baseline arguments}}]}')
    parser.add_argument("--networks-dir", default=None,
                        help="folder of URB networks, for every run whose args do not name one")
    parser.add_argument("--only", default=None, help="comma-separated run ids: run (and report) just these")
    parser.add_argument("--results-dir", default="results")
    parser.add_argument("--out", default=None, help="report folder (default: RESULTS_DIR/suite_<file stem>); "
                                                       "with --paper the page (default: docs/paper.md)")
    parser.add_argument("--no-progress", action="store_true", help="plain progress lines only")
    add_day_store_flag(parser)
    parser.add_argument("--report-only", action="store_true", help="write the report of the finished runs")
    parser.add_argument("--paper", action="store_true",
                        help="write docs/paper.md: every paper catalogue entry's finished runs under "
                             "RESULTS_DIR beside the paper's tables (configs/paper/urb_paper.json), a line "
                             "per row on whether the paper's conclusion holds; runs nothing")
    parser.add_argument("--allow-fewer", action="store_true",
                        help="with --paper: write the page even where it would show fewer finished runs "
                             "of an entry than it does now (refused by default: results would be lost)")
    parser.add_argument("--ledger", default="docs/paper_runs.json",
                        help="the paper page's ledger (default docs/paper_runs.json): a catalogue entry's "
                             "runs it records as finished on another machine are skipped; 'none' runs "
                             "them here too. --paper reads and writes the ledger beside its page "
                             "(paper_runs.json next to --out), not this one")
    parser.add_argument("--status", action="store_true",
                        help="say which runs are finished here, finished elsewhere (the ledger), being "
                             "written by another process now, stopped or new, and exit; without a suite, "
                             "a line per catalogue entry")
    parser.add_argument("--verify", nargs="*", metavar="RUN_ID", default=None,
                        help="rerun the entry's runs the ledger (--ledger) records, all or the RUN_IDs "
                             "named, into RESULTS_DIR/verify_<entry> (never the recorded runs' folders; "
                             "resumable), and say row by row: identical, or different with each metric "
                             "and both runs' commit and machine; exit 1 where a row differs")
    parser.add_argument("--list", action="store_true",
                        help="list the shipped suites (the paper's catalogue and the others) and exit")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from urb_jax.core.configio import find_config
    from urb_jax.runs.suite import load_suite, paper_report, run_suite, select, status, write_report

    if args.paper:
        print(f"paper: {paper_report(args.results_dir, args.out or 'docs/paper.md', args.allow_fewer)}")
        return 0
    if args.status:
        return _status(args)
    if args.verify is not None:
        return _verify(args)
    if args.list or not args.suite:
        return _list(args.list)
    spec = select(load_suite(find_config("suites", args.suite)), args.only, args.networks_dir)
    results = Path(args.results_dir)
    if args.report_only:
        folders = [results / n for r in spec.runs if status(results, r) == "done" for n in r.folder_names()]
    else:
        folders = run_suite(spec.runs, results, progress=not args.no_progress,
                            log=lambda line: print(line, flush=True),
                            recorded=_recorded(args).get(args.suite, set()), day_store=not args.no_day_store)
    out = Path(args.out) if args.out else results / f"suite_{Path(args.suite).stem}"
    print(f"report: {write_report(spec.title, folders, out, spec.preamble)}")
    return 0


def _recorded(args: argparse.Namespace) -> dict[str, set[str]]:
    """Catalogue entry -> its runs the page's ledger records (empty with --ledger none or without
    a ledger file; a suite that is not a catalogue entry has none)."""
    from pathlib import Path

    from urb_jax.reporting.paper import load_paper_numbers, read_ledger
    from urb_jax.runs.suite import recorded_runs

    if args.ledger.lower() == "none" or not Path(args.ledger).is_file():
        return {}
    ledger = read_ledger(args.ledger)
    return {entry: recorded_runs(ledger, entry) for entry in load_paper_numbers()["entries"]}


def _verify(args: argparse.Namespace) -> int:
    """--verify: rerun the ledger's rows of the entry (all, or the run ids given) beside the results
    folder and compare them with what the ledger recorded."""
    from pathlib import Path

    from urb_jax.core.configio import find_config
    from urb_jax.core.errors import ConfigError
    from urb_jax.reporting.paper import read_ledger
    from urb_jax.runs.suite import load_suite, select
    from urb_jax.runs.verify import report_lines, rows_to_verify, verify_folder, verify_rows

    if not args.suite or args.ledger.lower() == "none" or not Path(args.ledger).is_file():
        raise ConfigError(f"--verify: needs a catalogue entry and its ledger (--ledger {args.ledger}). Fix: "
                          "run `urb-jax suite ENTRY --verify` where the ledger file exists.")
    rows = rows_to_verify(read_ledger(args.ledger), args.suite, list(args.verify), args.ledger)
    spec = select(load_suite(find_config("suites", args.suite)), None, args.networks_dir)
    out = verify_folder(args.results_dir, Path(args.suite).stem)
    print(f"verify: rerunning {len(rows)} recorded row(s) of {args.suite} into {out}", flush=True)
    checks = verify_rows(spec.runs, rows, out, log=lambda line: print(line, flush=True),
                         progress=not args.no_progress)
    for line in report_lines(checks):
        print(line)
    return 0 if all(c.identical for c in checks) else 1


def _status(args: argparse.Namespace) -> int:
    """--status: each run of the suite (finished here, recorded in the ledger, stopped, new), or
    without a suite a line per catalogue entry."""
    from pathlib import Path

    from urb_jax.core.configio import find_config
    from urb_jax.reporting.paper import load_paper_numbers
    from urb_jax.runs.suite import STATES, load_suite, run_progress, select, status

    results, recorded = Path(args.results_dir), _recorded(args)

    def summary(states: list[str]) -> str:
        return f"{len(states)} runs: " + ", ".join(f"{states.count(k)} {k}" for k in STATES)

    if not args.suite:
        for entry in load_paper_numbers()["entries"]:
            runs = load_suite(find_config("suites", entry)).runs
            print(f"{entry:28s} {summary([status(results, r, recorded.get(entry, set())) for r in runs])}")
        return 0
    spec = select(load_suite(find_config("suites", args.suite)), args.only, args.networks_dir)
    mine = recorded.get(args.suite, set())
    states = [status(results, r, mine) for r in spec.runs]
    for r, state in zip(spec.runs, states, strict=True):
        print(f"{r.exp_id:40s} {state:9s} {STATES[state]}")
        partly = state == "new" and set(r.folder_names()) & mine  # some seeds finished elsewhere
        for line in run_progress(results, r, mine) if state in ("running", "stopped") or partly else []:
            print(f"{'':40s}   {line}")
    print(summary(states) + (f" (ledger {args.ledger})" if mine else ""))
    return 0


def _list(asked: bool) -> int:
    """Every shipped suite: id, title, and what it runs (train runs x seeds, baselines)."""
    from urb_jax.core.configio import configs_dir
    from urb_jax.runs.suite import load_suite

    for path in sorted((configs_dir() / "suites").glob("*.json")):
        spec = load_suite(path)
        trains = [r for r in spec.runs if r.kind == "train"]
        folders = sum(len(r.folder_names()) for r in trains)
        print(f"{path.stem:28s} {spec.title}\n{'':28s} {len(trains)} train runs ({folders} seed folders), "
              f"{len(spec.runs) - len(trains)} baselines")
    if not asked:
        print("urb-jax suite: name a suite (one of the above) or a suite file.", file=sys.stderr)
    return 0 if asked else 2
