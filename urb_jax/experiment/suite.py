"""Run a list of experiments as one resumable job, then write their tables and figures.

A suite is a list of `SuiteRun`s (a catalogue entry expands into them): each is a `urb-jax train`
(its seeds trained together) or `urb-jax baseline`, with a fixed experiment id. Running the suite
again skips the runs that finished, resumes the ones that were stopped (`resume_train`: their
newest checkpoint), and starts the others; so a killed suite continues where it was. Every run
prints its own progress; the suite adds a line per run. Each human phase is simulated once: a new
run replays an earlier run's of the suite where they match (`human_phase.first_reusable`).
"""

from __future__ import annotations

import inspect
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from urb_jax.core.atomic import write_text
from urb_jax.core.configio import find_config
from urb_jax.core.errors import ConfigError
from urb_jax.experiment.run import resume_train, run_baseline, run_train
from urb_jax.experiment.run_folder import CONFIG_FILE, train_run_names
from urb_jax.reporting.paper import EntryResults, load_paper_numbers, paper_markdown
from urb_jax.reporting.suite_report import suite_figures, suite_tables

KINDS = ("train", "baseline")


@dataclass(frozen=True)
class SuiteRun:
    """One experiment of a suite: `run_train(**kwargs)` (kind train, with `seeds`) or
    `run_baseline(**kwargs)` (kind baseline), under `exp_id`."""

    kind: str
    exp_id: str
    kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"SuiteRun kind {self.kind!r}: use one of {KINDS}")

    def folder_names(self) -> list[str]:
        if self.kind == "baseline":
            return [self.exp_id]
        seeds = list(self.kwargs.get("seeds") or [0])
        return train_run_names(self.exp_id, alg="", mode="", net="", task_stem="", seeds=seeds)


def status(results_dir: Path, run: SuiteRun) -> str:
    """'done' (every folder finished), 'stopped' (a folder exists, not finished) or 'new'."""
    states = []
    for name in run.folder_names():
        cfg = results_dir / name / CONFIG_FILE
        states.append(json.loads(cfg.read_text()).get("status") if cfg.is_file() else None)
    if all(s == "done" for s in states):
        return "done"
    return "stopped" if any(s is not None for s in states) else "new"


def run_suite(runs: list[SuiteRun], results_dir: str | Path, progress: bool = True,
              log: Callable[[str], None] = print) -> list[Path]:
    """Every run of the suite, finished ones skipped and stopped ones resumed; their folders."""
    results_dir = Path(results_dir)
    folders: list[Path] = []
    t0 = time.perf_counter()
    for i, run in enumerate(runs, 1):
        state = status(results_dir, run)
        log(f"suite: run {i}/{len(runs)} {run.exp_id} ({run.kind}): "
            f"{ {'done': 'finished before, skipped', 'stopped': 'resuming', 'new': 'starting'}[state] }, "
            f"{time.perf_counter() - t0:.0f} s into the suite")
        # A human phase depends on the network, demand, humans and env seed, not on the CAVs: a new
        # run replays the first earlier run's that matches (checked by the run itself) instead of
        # simulating it again; the records are the same bytes (tests/test_suite.py).
        earlier = [f.name for f in folders]
        shared = {} if "human_phase_from" in run.kwargs else {"human_phase_candidates": earlier}
        if state == "stopped" and run.kind == "train":
            resume_train(run.folder_names()[0], results_dir=str(results_dir), progress=progress,
                         executor=run.kwargs.get("executor"))
        elif state == "stopped":  # a baseline has no checkpoint: it starts again in its own folder
            run_baseline(exp_id=run.exp_id, results_dir=str(results_dir), progress=progress, overwrite=True,
                         **shared, **run.kwargs)
        elif state == "new" and run.kind == "train":
            run_train(exp_id=run.exp_id, results_dir=str(results_dir), progress=progress, **shared,
                      **run.kwargs)
        elif state == "new":
            run_baseline(exp_id=run.exp_id, results_dir=str(results_dir), progress=progress, **shared,
                         **run.kwargs)
        folders += [results_dir / name for name in run.folder_names()]
    return folders


def write_report(title: str, folders: list[Path], out_dir: str | Path, preamble: str = "") -> Path:
    """`out_dir/README.md` (the tables, figure links) and `out_dir/figures/*.png`, written atomically."""
    out_dir = Path(out_dir)
    figures = suite_figures(folders, out_dir / "figures")
    text = [f"# {title}", "", preamble, "", suite_tables(folders), "## Figures", ""]
    text += [f"![{p.stem}](figures/{p.name})" for p in figures]
    path = out_dir / "README.md"
    write_text(path, "\n".join(text) + "\n")
    return path


PAPER_HEADER = """# The URB paper next to urb-jax

Generated by `urb-jax suite --paper --results-dir {results}` from the finished runs under `{results}`;
do not edit by hand. To fill it in, run catalogue entries (`urb-jax suite ENTRY --networks-dir DIR`,
`urb-jax suite --list`; resumable) and generate it again. Entries and runs not finished show "not
run yet". The paper's numbers, each table with the address it was read at, are
`configs/paper/urb_paper.json`; an entry whose tables were not found says so and shows ours alone.

Ours are mean ± std over seeds, each number twice: in SUMO's trip duration (the measure the
published tables fit) and in URB's current travel time (docs/metrics.md, "Two measures of a
trip"). Under each table, every paper row's conclusion (comparisons that hold on the paper's own
numbers) is recomputed on ours in both measures.

| entry | paper's numbers | ours |
|---|---|---|
{summary}
"""


def paper_report(results_dir: str | Path, out: str | Path) -> Path:
    """`out` (docs/paper.md): every catalogue entry (the entries of configs/paper/urb_paper.json)
    from its finished runs under results_dir, the paper's tables beside ours. An entry with
    finished runs also gets its suite report (RESULTS_DIR/suite_<entry>: tables, figures), which
    the page links. Written atomically."""
    results_dir, out = Path(results_dir), Path(out)
    paper = load_paper_numbers()
    results = [_entry_results(entry, results_dir, out.parent) for entry in paper["entries"]]
    summary = "\n".join(
        f"| `{r.entry}` | {paper['entries'][r.entry]['status']} | "
        f"{f'{r.runs_done} of {r.runs_planned} runs finished' if r.runs_done else 'not run yet'} |"
        for r in results)
    write_text(out, paper_markdown(results, paper, PAPER_HEADER.format(results=results_dir, summary=summary)))
    return out


def _entry_results(entry: str, results_dir: Path, page_dir: Path) -> EntryResults:
    spec = load_suite(find_config("suites", entry))
    done = [r for r in spec.runs if status(results_dir, r) == "done"]
    folders = [results_dir / name for r in done for name in r.folder_names()]
    figures: list[str] = []
    if folders:
        report = write_report(spec.title, folders, results_dir / f"suite_{entry}", spec.preamble)
        figures = [os.path.relpath(p, page_dir) for p in sorted((report.parent / "figures").glob("*.png"))]
    seeds = [len(r.kwargs.get("seeds") or [0]) for r in spec.runs if r.kind == "train"]
    return EntryResults(entry, spec.title, folders, len(spec.runs), len(done), max(seeds, default=1), figures)


# Keyword arguments a suite file may give each kind (the commands' own flags, as Python names).
_NOT_FROM_FILES = {"exp_id", "results_dir", "progress", "executor", "day_fn", "stop_after_round", "overwrite",
                   "human_phase_candidates"}
ALLOWED_ARGS = {kind: set(inspect.signature(fn).parameters) - _NOT_FROM_FILES
                for kind, fn in (("train", run_train), ("baseline", run_baseline))}


@dataclass(frozen=True)
class SuiteSpec:
    """A suite file: {"title", "preamble"?, "runs": [{"kind", "id", "args": {...}}, ...]}."""

    title: str
    preamble: str
    runs: list[SuiteRun]


def load_suite(path: str | Path) -> SuiteSpec:
    """A suite file, validated: every run's kind, id and argument names (run_train's or
    run_baseline's keywords); unique ids."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
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
        runs = [SuiteRun(r.kind, r.exp_id, {"networks_dir": networks_dir, **r.kwargs}) for r in runs]
    return SuiteSpec(spec.title, spec.preamble, runs)
