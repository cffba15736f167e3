"""Run a list of experiments as one resumable job, then write their tables and figures.

A suite is a list of `SuiteRun`s (a catalogue entry expands into them): each is a `urb-jax train`
(its seeds trained together) or `urb-jax baseline`, with a fixed experiment id. Running the suite
again skips the runs that finished, resumes the ones that were stopped (`resume_train`: their
newest checkpoint), and starts the others; so a killed suite continues where it was. Every run
prints its own progress; the suite adds a line per run. Each human phase is simulated once per
results folder: a new run replays an earlier run's of the suite, or any other finished run's in
the folder, where they match (`urb_jax.runs.setup.first_reusable`).
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from urb_jax.core.atomic import write_bytes, write_text
from urb_jax.core.configio import find_config, loads_strict
from urb_jax.core.errors import ConfigError, UrbJaxError
from urb_jax.reporting.leaderboard import collect_folders
from urb_jax.reporting.paper import (
    EntryResults,
    ledger_json,
    ledger_path,
    load_paper_numbers,
    paper_markdown,
    read_ledger,
)
from urb_jax.reporting.provenance import PROVENANCE, provenance
from urb_jax.reporting.suite_report import (
    AGAINST_FIGURE,
    against_humans_figure,
    against_humans_points,
    baseline_comparisons,
    runs_tables,
    suite_figures,
    wall_times_table,
)
from urb_jax.reporting.travel_figures import PREFIX, NetworkFigure, network_figures
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.folder import CONFIG_FILE, run_status, run_writer, train_run_names
from urb_jax.runs.request import BaselineRequest, ResumeRequest, TrainRequest, request_fields
from urb_jax.runs.standing import seed_groups
from urb_jax.runs.train import resume_train, run_train

KINDS = ("train", "baseline")


@dataclass(frozen=True)
class SuiteRun:
    """One experiment of a suite: a `TrainRequest(**kwargs)` (kind train, with `seeds`) or a
    `BaselineRequest(**kwargs)` (kind baseline), under `exp_id`. `options`: what a Python caller
    (tests) hands the run besides its request: run_train's executor and stop_after_round,
    run_baseline's executor and task_overrides; a suite file has none."""

    kind: str
    exp_id: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"SuiteRun kind {self.kind!r}: use one of {KINDS}")

    def folder_names(self) -> list[str]:
        if self.kind == "baseline":
            return [self.exp_id]
        seeds = list(self.kwargs.get("seeds") or [0])
        return train_run_names(self.exp_id, alg="", mode="", net="", task_stem="", seeds=seeds)


STATES = {"done": "finished before, skipped",
          "recorded": "finished elsewhere (in the page's ledger), skipped",
          "running": "being written now by another process (running the suite would stop here; wait)",
          "stopped": "resuming", "new": "starting"}


def folders_left(results_dir: Path, run: SuiteRun, recorded: frozenset[str] | set[str] = frozenset()
                 ) -> list[str]:
    """The run's folders neither finished here nor in `recorded` (the paper page's ledger, finished on
    another machine): what running it still has to do. A seed finished anywhere is never run again."""
    return [n for n in run.folder_names() if n not in recorded and run_status(results_dir / n) != "done"]


def finished_here(results_dir: Path, names: list[str]) -> list[Path]:
    """The folders among `names` finished under results_dir, in order."""
    return [results_dir / n for n in names if run_status(results_dir / n) == "done"]


def status(results_dir: Path, run: SuiteRun, recorded: frozenset[str] | set[str] = frozenset()) -> str:
    """'done' (every folder finished here), 'recorded' (every folder finished here or in `recorded`:
    the paper page's ledger, finished on another machine), 'running' (a live process is writing one
    of the run's folders), 'stopped' (a folder left to do exists here, not finished, nobody writing
    it) or 'new' (nothing left to do here yet: all of the run, or the seeds the ledger lacks)."""
    names, left = run.folder_names(), folders_left(results_dir, run, recorded)
    if not left:
        return "done" if all(run_status(results_dir / n) == "done" for n in names) else "recorded"
    if any(run_writer(results_dir / name) is not None for name in names):
        return "running"
    if any(run_status(results_dir / n) is not None for n in left):
        return "stopped"
    return "new"


def remaining(run: SuiteRun, left: list[str]) -> SuiteRun:
    """The part of a train run still to do: its seeds whose folders are `left` (a sub-list of
    run.folder_names()), named so that they write those folders (one seed left: the folder's own
    name, as train_run_names names a one-seed run). A seed's bytes do not depend on the seeds
    trained beside it where they are trained one at a time (`max_vmapped_seeds: 1`, docs/hybrid.md)."""
    if left == run.folder_names() or run.kind != "train":
        return run
    seeds = [s for s, n in zip(run.kwargs.get("seeds") or [0], run.folder_names(), strict=True) if n in left]
    part = SuiteRun(run.kind, left[0] if len(left) == 1 else run.exp_id, {**run.kwargs, "seeds": seeds},
                    run.options)
    assert part.folder_names() == left, (part.folder_names(), left)
    return part


def run_progress(results_dir: Path, run: SuiteRun, recorded: frozenset[str] | set[str] = frozenset()
                 ) -> list[str]:
    """Where an unfinished train run stands, a line per group of seeds (`standing.seed_groups`) that
    is left to do, and a line naming its seeds the ledger (`recorded`) holds; nothing for a
    baseline. What `--status` shows between the sessions of a long run."""
    if run.kind != "train":
        return []
    seeds = dict(zip(run.folder_names(), run.kwargs.get("seeds") or [0], strict=True))
    elsewhere = [n for n in seeds if n in recorded and run_status(results_dir / n) != "done"]
    lines = seed_groups(results_dir, {n: s for n, s in seeds.items() if n not in elsewhere})
    done = ", ".join(str(seeds[n]) for n in elsewhere)
    return lines + ([f"seed(s) {done}: finished elsewhere (the ledger)"] if elsewhere else [])


def finished_runs(results_dir: Path) -> list[str]:
    """The finished run folders under results_dir, by name."""
    return sorted(p.parent.name for p in results_dir.glob("*/exp_config.json")
                  if run_status(p.parent) == "done")


def run_suite(runs: list[SuiteRun], results_dir: str | Path, progress: bool = True,
              log: Callable[[str], None] = print, recorded: frozenset[str] | set[str] = frozenset(),
              day_store: bool = True) -> list[Path]:
    """Every run of the suite, finished ones skipped and stopped ones resumed; the folders finished
    here. `recorded`: run folder names finished elsewhere (the paper page's ledger), skipped too;
    `day_store`: the runs read and keep SUMO days in the shared day store (False: `--no-day-store`)."""
    results_dir = Path(results_dir)
    folders: list[Path] = []
    before = finished_runs(results_dir)  # other suites' runs too: catalogue entries share networks
    t0 = time.perf_counter()
    for i, run in enumerate(runs, 1):
        state = status(results_dir, run, recorded)
        log(f"suite: run {i}/{len(runs)} {run.exp_id} ({run.kind}): {STATES[state]}, "
            f"{time.perf_counter() - t0:.0f} s into the suite")
        if state == "recorded":  # its seeds finished here, if any, still make the report
            folders += finished_here(results_dir, run.folder_names())
            continue
        if state == "stopped":
            for line in run_progress(results_dir, run, recorded):
                log(f"suite:   {line}")
        if state == "running":
            writers = {w for name in run.folder_names() if (w := run_writer(results_dir / name)) is not None}
            raise UrbJaxError(f"{results_dir / run.exp_id}: run '{run.exp_id}' is being written by "
                              f"process {', '.join(map(str, sorted(writers)))}. Fix: wait for it to finish "
                              "(the suite skips it then), or leave it out with --only.")
        # A human phase depends on the network, demand, humans and env seed, not on the CAVs: a new
        # run replays the first earlier run's that matches (checked by the run itself) instead of
        # simulating it again, this suite's runs first, then the runs finished in the folder before
        # the suite started; the records are the same bytes.
        earlier = [f.name for f in folders]
        candidates = [] if "human_phase_from" in run.kwargs else \
            earlier + [name for name in before if name not in earlier]
        left = folders_left(results_dir, run, recorded)
        if 0 < len(left) < len(run.folder_names()):
            finished = [n for n in run.folder_names() if n not in left]
            log(f"suite:   {', '.join(finished)} finished (here or in the ledger); running {', '.join(left)}")
        if state == "stopped" and run.kind == "train":
            first = next(n for n in left if run_status(results_dir / n) is not None)
            resume_train(ResumeRequest(first, results_dir=str(results_dir), progress=progress,
                                       networks_dir=run.kwargs.get("networks_dir"), day_store=day_store),
                         executor=run.options.get("executor"))
        elif state != "done":  # a stopped baseline has no checkpoint: it starts again in its own folder
            part, again = remaining(run, left), state == "stopped"
            if run.kind == "train":
                run_train(TrainRequest(**part.kwargs, exp_id=part.exp_id, results_dir=str(results_dir),
                                       progress=progress, overwrite=again, day_store=day_store),
                          human_phase_candidates=candidates,
                          **part.options)
            else:
                run_baseline(BaselineRequest(**part.kwargs, exp_id=part.exp_id, results_dir=str(results_dir),
                                             progress=progress, overwrite=again, day_store=day_store),
                             human_phase_candidates=candidates, **part.options)
        folders += finished_here(results_dir, run.folder_names())
    return folders


def ledger_rows(folders: list[Path]) -> pd.DataFrame:
    """`collect_folders`' rows of finished `folders`, each with its provenance (commit, machine,
    versions, command and request, human-phase reuse, wall time, date: `reporting.provenance`) and
    no folder path: what the paper page's ledger keeps of a run, so that a row says who made it and
    `urb-jax suite ENTRY --verify` can make it again."""
    rows = collect_folders(folders)
    if rows.empty:
        return rows.drop(columns=["folder"], errors="ignore")
    configs = [Path(f) / CONFIG_FILE for f in rows["folder"]]
    found = [provenance(json.loads(c.read_text()), c) for c in configs]
    return rows.assign(**{PROVENANCE: found}).drop(columns=["folder"])


def recorded_runs(ledger: pd.DataFrame, entry: str) -> set[str]:
    """The run folder names the paper page's ledger (`read_ledger`) holds for catalogue entry `entry`."""
    return set(ledger.loc[ledger["entry"] == entry, "exp_id"])


def write_report(title: str, folders: list[Path], out_dir: str | Path, preamble: str = "") -> Path:
    """`out_dir/README.md` (the tables, figure links) and `out_dir/figures/*.png`, written atomically."""
    out_dir = Path(out_dir)
    figures = suite_figures(folders, out_dir / "figures")
    runs = collect_folders(folders)
    against = baseline_comparisons(runs)
    text = [f"# {title}", "", preamble, "", runs_tables(runs),
            *(["## Against the humans and the baselines", "", against, ""] if against else []),
            "## Wall time", "",
            "Each run's wall time where it was made (seeds trained together share one), from its "
            "exp_config.json:", "", wall_times_table(folders), "", "## Figures", ""]
    text += [f"![{p.stem}](figures/{p.name})" for p in figures]
    path = out_dir / "README.md"
    write_text(path, "\n".join(text) + "\n")
    return path


PAPER_HEADER = """# The URB paper next to urb-jax

Generated by `urb-jax suite --paper --results-dir {results}` from the finished runs under `{results}`
and the runs of earlier generations recorded in `{ledger}` (their metrics and provenance per seed, by
run id; a run finished under the results folder replaces its recorded row); do not edit by hand. To
fill it in, run catalogue entries (`urb-jax suite ENTRY --networks-dir DIR`, `urb-jax suite --list`;
resumable), on any machine, and generate it again. Entries and runs not finished show "not run yet".

The paper's numbers are `configs/paper/urb_paper.json`, typed from the paper's LaTeX source: each
table and claim names the table label or section it comes from (`tab:kpis`: Scenario 1, five seeded
runs, mean (std)). Where URB's GitHub README (an older, 3-run table) differs, its numbers are shown
as a second source. Ours are mean ± sample std over seeds, each number twice: in SUMO's trip
duration (the measure the published tables fit) and in URB's current travel time (docs/metrics.md,
"Two measures of a trip"). Every paper conclusion is judged on our per-seed values: holds, fails,
tie or not comparable (the rules are under the summary below).

| entry | paper's numbers | ours | provenance (commit, machine, versions, command, wall time) |
|---|---|---|---|
{summary}
"""


def paper_report(results_dir: str | Path, out: str | Path, allow_fewer: bool = False) -> Path:
    """`out` (docs/paper.md): every catalogue entry (the entries of configs/paper/urb_paper.json)
    from its finished runs, the paper's tables beside ours. The runs are those finished under
    results_dir and those the page's ledger (<out stem>_runs.json) recorded in earlier generations,
    on this machine or another; the ledger is written back with both. An entry with runs finished
    here also gets its suite report (RESULTS_DIR/suite_<entry>: tables, figures), whose figures are
    copied beside the page (<out stem>_figures/<entry>/, next to the figures copied before) and
    linked there. Written atomically, the ledger first. A generation that would show an entry with
    fewer finished runs than the page does now (its runs neither here nor in the ledger: a page
    made before the ledger existed, or a ledger replaced) is refused unless `allow_fewer`."""
    results_dir, out = Path(results_dir), Path(out)
    paper = load_paper_numbers()
    figures_dir = out.parent / f"{out.stem}_figures"
    ledger_file = ledger_path(out)
    ledger = read_ledger(ledger_file)
    results = [_entry_results(entry, results_dir, figures_dir, ledger, paper["entries"][entry].get("figure"))
               for entry in paper["entries"]]
    if not allow_fewer:
        _refuse_fewer(out, {r.entry: r.runs_done for r in results}, results_dir, ledger_file)
    summary = "\n".join(
        f"| `{r.entry}` | {paper['entries'][r.entry]['status']} | "
        f"{f'{r.runs_done} of {r.runs_planned} runs finished' if r.runs_done else 'not run yet'} | "
        f"{_provenance_cell(r.runs)} |"
        for r in results)
    rows = [t.assign(entry=r.entry) for r in results for t in (r.runs, r.partial) if not t.empty]
    write_text(ledger_file, ledger_json(pd.concat(rows, ignore_index=True) if rows else ledger.iloc[:0]))
    ledger_name = Path(os.path.relpath(ledger_file, out.parent)).as_posix()
    header = PAPER_HEADER.format(results=_as_run_from(results_dir), ledger=ledger_name, summary=summary)
    write_text(out, paper_markdown(results, paper, header))
    return out


def _as_run_from(path: Path) -> str:
    """`path` as the page names it: relative to the folder the command runs in, never absolute (the
    page is committed and read on other machines); its own name where no relative path exists."""
    try:
        return Path(os.path.relpath(path)).as_posix()
    except ValueError:  # another drive (Windows)
        return path.name


def _provenance_cell(runs: pd.DataFrame) -> str:
    """How many of an entry's seed runs the ledger can say how they were made: those finished before
    it kept provenance cannot be rerun from it (`suite --verify`) until they are run again."""
    if runs.empty:
        return ""
    recorded = runs["provenance"] if "provenance" in runs else pd.Series([None] * len(runs))
    kept = int(recorded.map(lambda p: isinstance(p, dict) and bool(p)).sum())
    if kept == len(runs):
        return f"every seed run ({kept})"
    if not kept:
        return (f"none of {len(runs)} seed runs: they finished before the ledger kept provenance (run "
                "them again to add it)")
    return (f"{kept} of {len(runs)} seed runs; the other {len(runs) - kept} finished before the ledger "
            "kept provenance (run them again to add it)")


# "| `entry` | status | N of M runs finished |", with or without the provenance column after it
_FINISHED = re.compile(r"^\| `([^`]+)` \| [^|]+ \| (\d+) of \d+ runs finished \|", re.MULTILINE)


def _refuse_fewer(out: Path, done: dict[str, int], results_dir: Path, ledger_file: Path) -> None:
    """ConfigError when the page at `out` shows more finished runs of an entry than `done`."""
    shown = {m[1]: int(m[2]) for m in _FINISHED.finditer(out.read_text())} if out.is_file() else {}
    fewer = {e: (n, done.get(e, 0)) for e, n in shown.items() if done.get(e, 0) < n}
    if fewer:
        what = ", ".join(f"{e} ({was} -> {now})" for e, (was, now) in sorted(fewer.items()))
        raise ConfigError(f"{out}: this generation would show fewer finished runs than the page does now: "
                          f"{what}; those runs are neither under {results_dir} nor in {ledger_file}. "
                          "Fix: run them under the results folder first (urb-jax suite ENTRY), point "
                          "--results-dir at where they are, or pass --allow-fewer to drop them.")


def _entry_results(entry: str, results_dir: Path, figures_dir: Path, ledger: pd.DataFrame,
                   figure: dict[str, Any] | None = None) -> EntryResults:
    """An entry's finished runs: those under results_dir, then the ledger's rows of the entry's other
    runs. Figures of the runs here are copied to figures_dir/<entry>/ (next to the page, so the
    page's links hold wherever the results folder is); every figure there is linked. An entry with
    the paper's travel-time `figure` gets it drawn there per network from its runs here."""
    spec = load_suite(find_config("suites", entry))
    planned = list(dict.fromkeys(name for r in spec.runs for name in r.folder_names()))
    done_here = finished_here(results_dir, planned)  # seeds of unfinished runs too
    here = ledger_rows(done_here)
    elsewhere = set(planned) - {f.name for f in done_here}
    before = ledger[(ledger["entry"] == entry) & ledger["exp_id"].isin(elsewhere)]
    parts = [t for t in (here, before.drop(columns=["entry"])) if not t.empty]
    rows = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=["exp_id"])
    done = [r for r in spec.runs if set(r.folder_names()) <= set(rows["exp_id"])]
    shown_names = {n for r in done for n in r.folder_names()}
    shown = rows["exp_id"].isin(shown_names)
    runs, partial = rows[shown].reset_index(drop=True), rows[~shown].reset_index(drop=True)
    folders = [f for f in done_here if f.name in shown_names]
    if folders:
        report = write_report(spec.title, folders, results_dir / f"suite_{entry}", spec.preamble)
        for png in sorted((report.parent / "figures").glob("*.png")):
            write_bytes(figures_dir / entry / png.name, png.read_bytes())
    if not runs.empty:  # every shown run, the ledger's too (the suite report's has those here only)
        (figures_dir / entry).mkdir(parents=True, exist_ok=True)
        against_humans_figure(against_humans_points(runs), figures_dir / entry / f"{AGAINST_FIGURE}.png")
    travel: tuple[NetworkFigure, ...] = ()
    if figure:
        nets = list(dict.fromkeys(str(r.kwargs["net"]) for r in spec.runs if r.kind == "train"))
        travel = network_figures(entry, nets, folders, figures_dir / entry, figures_dir.parent,
                                 int(figure["window"]))
    figures = [os.path.relpath(p, figures_dir.parent) for p in sorted((figures_dir / entry).glob("*.png"))
               if not p.name.startswith(PREFIX)]
    seeds = [len(r.kwargs.get("seeds") or [0]) for r in spec.runs if r.kind == "train"]
    missing = [r.exp_id for r in spec.runs if r not in done]
    return EntryResults(entry, spec.title, runs, len(spec.runs), len(done), max(seeds, default=1), figures,
                        missing, partial, travel)


# The request fields a suite file may give each kind (the commands' own flags, as Python names).
ALLOWED_ARGS = {"train": request_fields(TrainRequest), "baseline": request_fields(BaselineRequest)}


@dataclass(frozen=True)
class SuiteSpec:
    """A suite file: {"title", "preamble"?, "runs": [{"kind", "id", "args": {...}}, ...]}."""

    title: str
    preamble: str
    runs: list[SuiteRun]


def load_suite(path: str | Path) -> SuiteSpec:
    """A suite file, validated: every run's kind, id and argument names (TrainRequest's or
    BaselineRequest's fields); unique ids."""
    path = Path(path)
    try:
        raw = loads_strict(path.read_text(), path)
    except (OSError, ValueError) as exc:  # ValueError: bad JSON or UTF-8
        raise ConfigError(f"{path}: cannot read a suite file ({exc}). Fix: pass a JSON file with "
                          '{"title": ..., "runs": [{"kind": "train", "id": ..., "args": {...}}]}.') from None
    unknown = set(raw) - {"title", "preamble", "runs"}
    if unknown or "runs" not in raw:
        raise ConfigError(f"{path}: keys {sorted(unknown) or 'no runs'}. Fix: use title, preamble and runs.")
    runs, seen = [], set()
    for i, r in enumerate(raw["runs"]):
        where = f"{path}: runs[{i}]"
        kind, exp_id, args = r.get("kind"), r.get("id"), r.get("args", {})
        if kind not in KINDS or not exp_id or set(r) - {"kind", "id", "args"}:
            raise ConfigError(f"{where}: needs 'kind' (one of {KINDS}), 'id' and 'args', and nothing else. "
                              "Fix: write it so.")
        bad = set(args) - ALLOWED_ARGS[kind]
        if bad:
            raise ConfigError(f"{where}: args {sorted(bad)} are not {kind} arguments. Fix: use some of "
                              f"{sorted(ALLOWED_ARGS[kind])}.")
        if exp_id in seen:
            raise ConfigError(f"{where}: id '{exp_id}' is used twice. Fix: give every run its own id.")
        seen.add(exp_id)
        runs.append(SuiteRun(kind, exp_id, dict(args)))
    return SuiteSpec(str(raw.get("title", path.stem)), str(raw.get("preamble", "")), runs)


def select(spec: SuiteSpec, only: str | None, networks_dir: str | None) -> SuiteSpec:
    """The suite's runs named in `only` (comma-separated ids; None: all), each given
    `networks_dir` where its args name none."""
    runs = spec.runs
    if only:
        wanted = [x.strip() for x in only.split(",") if x.strip()]
        missing = sorted(set(wanted) - {r.exp_id for r in runs})
        if missing:
            raise ConfigError(f"--only {missing}: not runs of this suite. Fix: use some of "
                              f"{[r.exp_id for r in runs]}.")
        runs = [r for r in runs if r.exp_id in wanted]
    if networks_dir:
        runs = [SuiteRun(r.kind, r.exp_id, {"networks_dir": networks_dir, **r.kwargs}, r.options)
                for r in runs]
    return SuiteSpec(spec.title, spec.preamble, runs)
