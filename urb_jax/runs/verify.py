"""`urb-jax suite ENTRY --verify [RUN_ID ...]`: make the ledger's recorded runs again and say, row by
row, whether they came out the same.

The paper page's ledger (docs/paper_runs.json) keeps runs finished on machines that are gone. A
rerun of the suite from the repository skips them (they are recorded), so nothing ever checked that
a row can be made again; and the same command has given one run two results on two hosts. This
reruns the rows asked for (all of the entry's by default), each as the suite would run it (its
seeds as the catalogue plans them, `remaining`), into a folder of their own (RESULTS_DIR/
verify_<entry>: never the recorded runs' folders; resumable like any suite), then compares every
metric of the ledger's row with the rerun's, exactly (the ledger holds the value read from the
run's BenchmarkMetrics.csv, the rerun's is read the same way), and sets the two provenances side by
side: commit, machine, date.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from urb_jax.core.errors import ConfigError
from urb_jax.reporting.comparable import METRIC_COLUMNS
from urb_jax.reporting.provenance import PROVENANCE, host
from urb_jax.runs.suite import SuiteRun, finished_here, ledger_rows, remaining, run_suite


@dataclass(frozen=True)
class RowCheck:
    """One ledger row against its rerun: the metrics that differ (name, recorded, rerun), both
    provenances, and whether the rerun finished at all."""

    exp_id: str
    recorded: Any
    rerun: Any = None
    differences: list[tuple[str, Any, Any]] = field(default_factory=list)
    finished: bool = True

    @property
    def identical(self) -> bool:
        return self.finished and not self.differences


def verify_folder(results_dir: str | Path, entry: str) -> Path:
    """Where --verify reruns an entry's rows: RESULTS_DIR/verify_<entry>, beside the recorded runs."""
    return Path(results_dir) / f"verify_{entry}"


def rows_to_verify(ledger: pd.DataFrame, entry: str, run_ids: list[str], ledger_file: str | Path
                   ) -> pd.DataFrame:
    """The ledger's rows of `entry` named in `run_ids` (all of them where it is empty), by exp_id;
    ConfigError naming the ledger file where the entry has none or an id is not one of its rows."""
    mine = ledger[ledger["entry"] == entry].set_index("exp_id", drop=False)
    unknown = sorted(set(run_ids) - set(mine.index))
    if mine.empty or unknown:
        raise ConfigError(f"{ledger_file}: no recorded row of entry '{entry}' for {unknown or 'any run'}. "
                          f"Fix: name run ids the ledger holds for it ({sorted(mine.index) or 'none yet'}), "
                          "or pass --ledger with the ledger that records them.")
    return mine.loc[run_ids] if run_ids else mine


def rerun_plan(runs: list[SuiteRun], ids: list[str]) -> list[SuiteRun]:
    """The suite's runs cut to the folders in `ids`, in the suite's order (`remaining`: a train run
    reruns only the seeds asked for); ConfigError for an id no run of the suite writes."""
    known = {n for r in runs for n in r.folder_names()}
    if set(ids) - known:
        raise ConfigError(f"run ids {sorted(set(ids) - known)}: the ledger records them but the suite "
                          "has no such run folders (renamed since?). Fix: name run ids of the suite.")
    return [remaining(r, [n for n in r.folder_names() if n in ids])
            for r in runs if set(r.folder_names()) & set(ids)]


def verify_rows(runs: list[SuiteRun], recorded: pd.DataFrame, out_dir: str | Path,
                log: Callable[[str], None] = print, progress: bool = False) -> list[RowCheck]:
    """Rerun the ledger rows `recorded` (`rows_to_verify`) of the suite `runs` into `out_dir`, then
    check each against its rerun."""
    ids = list(recorded["exp_id"])
    run_suite(rerun_plan(runs, ids), out_dir, progress=progress, log=log)
    made = ledger_rows(finished_here(Path(out_dir), ids))
    made = made.set_index("exp_id", drop=False) if not made.empty else made
    checks = []
    for exp_id, row in recorded.iterrows():
        if exp_id not in made.index:
            checks.append(RowCheck(str(exp_id), row.get(PROVENANCE), finished=False))
            continue
        again = made.loc[exp_id]
        checks.append(RowCheck(str(exp_id), row.get(PROVENANCE), again.get(PROVENANCE),
                               metric_differences(row, again)))
    return checks


def metric_differences(recorded: pd.Series, rerun: pd.Series) -> list[tuple[str, Any, Any]]:
    """(metric, recorded, rerun) for every metric the recorded row holds that the rerun does not
    equal exactly (NaN equals NaN; a metric the old row never recorded is not compared)."""
    out = []
    for name in METRIC_COLUMNS:
        was = recorded.get(name)
        if _absent(was):
            continue
        now = rerun.get(name)
        if not (_same(was, now)):
            out.append((name, was, now))
    return out


def _absent(v: Any) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def _same(a: Any, b: Any) -> bool:
    if _absent(a) or _absent(b):
        return _absent(a) and _absent(b)
    return bool(float(a) == float(b))


def report_lines(checks: list[RowCheck]) -> list[str]:
    """A line per row (identical, different with each metric, or not rerun), then where each
    different row's two runs were made."""
    out = []
    for c in checks:
        if not c.finished:
            out.append(f"{c.exp_id}: not rerun (its rerun did not finish); recorded: {host(c.recorded)}")
        elif c.identical:
            out.append(f"{c.exp_id}: identical")
        else:
            diffs = ", ".join(f"{m} {_num(a)} recorded, {_num(b)} rerun" for m, a, b in c.differences)
            out += [f"{c.exp_id}: different: {diffs}", f"  recorded: {host(c.recorded)}",
                    f"  rerun:    {host(c.rerun)}"]
    same = sum(c.identical for c in checks)
    out.append(f"verify: {same} of {len(checks)} rows identical")
    return out


def _num(v: Any) -> str:
    return "missing" if _absent(v) else f"{float(v)!r}"
