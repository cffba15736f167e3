"""The URB paper's tables next to ours (docs/paper.md).

The paper's numbers are data, `configs/paper/urb_paper.json`: per catalogue entry, its tables (one
per network, a row per algorithm, the paper's columns), each with the address it was read at, or
"not found" and what was searched. Every row carries claims, comparisons that hold on the paper's
own numbers ("t_CAV > t_pre": the CAVs stayed slower than as humans; "t_CAV > aon.t_CAV": slower
than the same table's AON row). Ours are the entry's finished runs, aggregated over seeds as the
leaderboard does, in both trip measures (SUMO's trip duration, the published tables' measure, and
URB's current travel time; docs/metrics.md), and each claim is recomputed on them. Where ours
contradict a claim, the entry's `why_not` says why, with its evidence, or the page says that the
reason is not established yet.

The page keeps a ledger beside it (docs/paper_runs.json): one row per finished run it has shown
(its config keys and metrics, no path). A catalogue takes longer than one machine lives, so each
generation shows the runs finished here and the ledger's runs finished elsewhere: the page fills in
across machines and sessions instead of forgetting what ran before.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from urb_jax.core.configio import configs_dir, loads_strict
from urb_jax.core.errors import ConfigError
from urb_jax.reporting.leaderboard import SHOWN, aggregate
from urb_jax.reporting.suite_report import runs_tables

PAPER_FILE = ("paper", "urb_paper.json")
MEASURES = ("SUMO duration", "travel time")
# paper column -> our metric in each measure (duration, travel time); one metric where the
# quantity has no travel-time/duration pair
COLUMNS = {"t_pre": ("t_pre_duration", "t_pre"), "t_test": ("t_test_duration", "t_test"),
           "t_CAV": ("t_CAV_duration", "t_CAV"), "t_HDV_post": ("t_HDV_test_duration", "t_HDV_test"),
           "c_all": ("cost_of_learning",) * 2, "c_HDV": ("cost_of_learning_humans",) * 2,
           "c_CAV": ("cost_of_learning_CAVs",) * 2, "delta_V": ("delta_V",) * 2,
           "delta_L": ("delta_L",) * 2, "WR": ("WR",) * 2}
HEADS = {"t_pre": "t_pre", "t_test": "t_test", "t_CAV": "t_CAV", "t_HDV_post": "t_HDV^post", "c_all": "c_all",
         "c_HDV": "c_HDV", "c_CAV": "c_CAV", "delta_V": "ΔV", "delta_L": "ΔL", "WR": "WR %"}
METRICS = list(dict.fromkeys([*SHOWN, *(m for pair in COLUMNS.values() for m in pair if m != "WR")]))
OPS = {"<": lambda a, b: a < b, ">": lambda a, b: a > b}
NAMES = {"iql": "IQL", "ippo": "IPPO", "mappo": "MAPPO", "qmix": "QMIX", "vdn": "VDN", "iql_star": "IQL*",
         "ippo_star": "IPPO*", "human": "Human", "aon": "AON", "random": "Random"}


def paper_file() -> Path:
    return configs_dir().joinpath(*PAPER_FILE)


def load_paper_numbers(path: str | Path | None = None) -> dict[str, Any]:
    """The paper's numbers, checked: every table has a source address and a caption, every column
    is one of COLUMNS, every claim is well formed and holds on the paper's own numbers."""
    path = Path(path) if path else paper_file()
    try:
        data = loads_strict(path.read_text(), path)
    except (OSError, ValueError) as exc:  # ValueError: bad JSON or UTF-8
        raise ConfigError(f"{path}: cannot read the paper's numbers ({exc}). "
                          "Fix: restore the file.") from None
    for entry, e in data.get("entries", {}).items():
        where = f"{path}: entries.{entry}"
        if e.get("status") == "not found":
            if e.get("tables") or not e.get("notes"):
                raise ConfigError(f"{where}: 'not found' has no tables and says why in 'notes'. "
                                  "Fix: write it so.")
            continue
        if e.get("status") != "found" or not e.get("tables"):
            raise ConfigError(f"{where}: status is 'found' (with tables) or 'not found'. Fix: set it.")
        for i, t in enumerate(e["tables"]):
            _check_table(t, f"{where}.tables[{i}]")
        claims = {key for t in e["tables"] for alg, row in t["rows"].items()
                  for c in row.get("claims", []) for key in (claim_text(c), f"{alg}: {claim_text(c)}")}
        unknown = sorted(set(e.get("why_not", {})) - claims)
        if unknown:
            raise ConfigError(f"{where}.why_not: {unknown} are not claims of this entry's rows. "
                              f"Fix: key each explanation by a claim ('t_CAV > t_pre') or a row's claim "
                              f"('qmix: t_CAV < t_pre'), one of {sorted(claims)}.")
    return data


def _check_table(t: dict[str, Any], where: str) -> None:
    if not str(t.get("source", "")).startswith("https://") or not t.get("caption") or not t.get("network"):
        raise ConfigError(f"{where}: a table needs 'network', 'caption' and a 'source' address. "
                          "Fix: add them.")
    for alg, row in t.get("rows", {}).items():
        bad = set(row["values"]) - set(COLUMNS)
        if bad:
            raise ConfigError(f"{where}.rows.{alg}: columns {sorted(bad)}. Fix: use some of {list(COLUMNS)}.")
        for claim in row.get("claims", []):
            held = _evaluate(claim, alg, lambda key, col: t["rows"].get(key, {}).get("values", {}).get(col))
            if held is None or not held[0]:
                raise ConfigError(f"{where}.rows.{alg}: claim {claim} does not hold on the paper's own "
                                  "numbers. Fix: state what the paper's numbers show.")


def _operand(term: str, row: str) -> tuple[str, str]:
    """'t_pre' -> (row, 't_pre'); 'aon.t_CAV' -> ('aon', 't_CAV')."""
    key, _, col = term.rpartition(".")
    return (key or row), col


def _evaluate(claim: list[str], row: str, value) -> tuple[bool, float, float] | None:
    """(holds, left, right) of a claim [left, op, right] on `value(row_key, column)`; None where a
    value is missing."""
    left, op, right = claim
    if op not in OPS or _operand(left, row)[1] not in COLUMNS or _operand(right, row)[1] not in COLUMNS:
        raise ConfigError(f"claim {claim}: use [column, '<' or '>', column or 'row.column'] with columns "
                          f"of {list(COLUMNS)}. Fix: rewrite it.")
    a, b = value(*_operand(left, row)), value(*_operand(right, row))
    if a is None or b is None or a != a or b != b:  # missing or NaN
        return None
    return OPS[op](a, b), float(a), float(b)


def row_key(alg: str) -> str:
    """The paper-table key of one of our rows: urb-jax's id, a baseline without 'baseline_'."""
    return alg.removeprefix("baseline_")


def our_rows(ours: pd.DataFrame, network: str) -> dict[str, pd.Series]:
    """Our aggregated rows (`aggregate`'s mean, std over seeds) on one network, by paper-table key."""
    if ours.empty:
        return {}
    table = ours[ours["network"] == network]
    return {row_key(str(r["alg"] or r["algorithm"])): r for _, r in table.iterrows()}


def our_value(row: pd.Series | None, column: str, measure: int) -> float | None:
    if row is None:
        return None
    metric = COLUMNS[column][measure]
    value = row.get("WR" if metric == "WR" else f"{metric}_mean")
    return None if value is None or value != value else float(value)


def _cell(row: pd.Series, column: str, measure: int) -> str:
    metric = COLUMNS[column][measure]
    if metric == "WR":
        return "n/a" if row.get("WR") != row.get("WR") else f"{row['WR']:.0f}"
    mean, std = row.get(f"{metric}_mean", math.nan), row.get(f"{metric}_std", math.nan)
    if mean != mean:
        return "n/a"
    return f"{mean:.4f}" + (f" ± {std:.4f}" if row["runs"] > 1 and std == std else "")


def claim_text(claim: list[str]) -> str:
    """A claim as urb_paper.json's `why_not` keys it: 't_CAV > aon.t_CAV' (every row's), or
    prefixed by a row, 'qmix: t_CAV < t_pre' (that row's)."""
    return " ".join(claim)


def _our_verdicts(claim: list[str], alg: str,
                  ours: dict[str, pd.Series]) -> list[tuple[bool, float, float] | None]:
    """The claim evaluated on ours, one `_evaluate` result per trip measure (MEASURES' order)."""
    return [_evaluate(claim, alg, lambda key, col, m=m: our_value(ours.get(key), col, m))
            for m in range(len(MEASURES))]


def claim_fails(claim: list[str], alg: str, ours: dict[str, pd.Series]) -> bool:
    """Ours contradict the claim in at least one trip measure."""
    return any(res is not None and not res[0] for res in _our_verdicts(claim, alg, ours))


def claim_line(claim: list[str], alg: str, ours: dict[str, pd.Series]) -> str:
    """'t_CAV > t_pre: holds in SUMO duration (3.3512 > 3.1585), does not hold in travel time (...)'."""
    left, op, right = claim
    label = f"{_term(left, alg)} {op} {_term(right, alg)}"
    parts = []
    for name, res in zip(MEASURES, _our_verdicts(claim, alg, ours), strict=True):
        if res is None:
            missing = [k for k in {_operand(left, alg)[0], _operand(right, alg)[0]} if k not in ours]
            parts.append(f"not run yet ({', '.join(NAMES.get(k, k) for k in sorted(missing))})" if missing
                         else f"n/a in {name}")
            continue
        holds, a, b = res
        verdict, sign = ("holds", op) if holds else ("**does not hold**", _not(op))
        parts.append(f"{verdict} in {name} ({a:.4f} {sign} {b:.4f})")
    if parts[0] == parts[1]:  # e.g. 'not run yet' twice
        parts = parts[:1]
    return f"{label}: " + "; ".join(parts)


def _term(term: str, row: str) -> str:
    key, col = _operand(term, row)
    return HEADS[col] if key == row else f"{NAMES.get(key, key)} {HEADS[col]}"


def _not(op: str) -> str:
    return {"<": "≥", ">": "≤"}[op]


@dataclass(frozen=True)
class EntryResults:
    """One catalogue entry as far as it has run: its finished runs (`collect_folders` rows, here or
    from the ledger), how many runs it has and how many finished, the seeds each train run plans,
    and links to the suite's figures."""

    entry: str
    title: str
    runs: pd.DataFrame
    runs_planned: int
    runs_done: int
    seeds_planned: int
    figures: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)  # run ids not finished yet
    # the finished seeds of runs not finished yet: kept in the ledger (a machine's end loses nothing),
    # not in the tables (a run is shown with all its seeds)
    partial: pd.DataFrame = field(default_factory=pd.DataFrame)


def entry_markdown(res: EntryResults, paper: dict[str, Any]) -> str:
    """An entry's section: the paper's tables with ours under each row, a conclusion line per row."""
    out = [f"## `{res.entry}`: {res.title}", ""]
    state = ("not run yet" if not res.runs_done else
             f"{res.runs_done} of {res.runs_planned} runs finished")
    out.append(f"Ours: {state}; {res.seeds_planned} seed(s) per train run planned. "
               f"Paper: {paper.get('paper_seeds', 'seeds not stated in what was found')}.")
    out.append("")
    if res.missing and res.runs_done:
        out += [f"Not finished yet: {', '.join(f'`{m}`' for m in res.missing)} "
                f"(`urb-jax suite {res.entry} --status`; `urb-jax suite {res.entry}` runs them).", ""]
    if not res.partial.empty:
        out += [f"Seeds finished of runs not finished yet (kept in the ledger, shown once their run is): "
                f"{', '.join(f'`{n}`' for n in sorted(res.partial['exp_id']))}.", ""]
    runs = res.runs
    if paper.get("status") != "found":
        out += [f"**The paper's numbers: not found.** {paper.get('notes', '')}", ""]
        if not runs.empty:
            out += ["Ours (mean ± std over seeds):", "", runs_tables(runs)]
    else:
        out += [f"The paper concludes: {paper['conclusion']}. Measure: {paper['measure']}.", ""]
        if paper.get("notes"):
            out += [f"Note: {paper['notes']}", ""]
        ours = aggregate(runs, METRICS) if not runs.empty else pd.DataFrame()
        for table in paper["tables"]:
            out += _table_markdown(table, our_rows(ours, table["network"]), paper.get("why_not", {}))
    if res.figures:
        out += ["Figures (travel times over days per group, phases as patches; written by the suite):", ""]
        out += [f"![{Path(f).stem}]({f})" for f in res.figures] + [""]
    return "\n".join(out)


def _table_markdown(table: dict[str, Any], ours: dict[str, pd.Series], why_not: dict[str, str]) -> list[str]:
    cols = list(COLUMNS)
    out = [f"### {table['name']} (`{table['network']}`)", "",
           f"Paper: \"{table['caption']}\", [source]({table['source']})"
           + "".join(f", [also]({u})" for u in table.get("also_at", [])) + ".", ""]
    head = ["algorithm", "numbers", "runs", *(HEADS[c] for c in cols)]
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    extra = [k for k in ours if k not in table["rows"]]
    for alg in [*table["rows"], *extra]:
        name = NAMES.get(alg, alg)
        row = table["rows"].get(alg)
        if row is not None:
            vals = row["values"]
            out.append("| " + " | ".join([f"**{name}**", "paper", str(table.get("runs", "?")),
                                          *(_paper_num(vals.get(c)) for c in cols)]) + " |")
            name = ""
        if alg == "human":
            continue  # the human row is t_pre itself; ours is in the conclusions
        r = ours.get(alg)
        if r is None:
            out.append("| " + " | ".join([name, "ours", "", "not run yet", *[""] * (len(cols) - 1)]) + " |")
            continue
        for m, measure in enumerate(MEASURES):
            out.append("| " + " | ".join([name, f"ours, {measure}", str(int(r["runs"])),
                                          *(_cell(r, c, m) for c in cols)]) + " |")
            name = ""
    out += ["", "Does the paper's conclusion hold here?", ""]
    for alg, row in table["rows"].items():
        out.append(_conclusion(alg, row, ours, why_not))
    for alg in extra:
        out.append(f"- **{NAMES.get(alg, alg)}**: ours only (not in the paper's table).")
    return [*out, ""]


def _conclusion(alg: str, row: dict[str, Any], ours: dict[str, pd.Series], why_not: dict[str, str]) -> str:
    """The row's conclusion line; where ours contradict a claim, why (the entry's `why_not`, or
    'not established yet': the page says so rather than leave the difference unexplained)."""
    head = f"- **{NAMES.get(alg, alg)}** (paper: {row['conclusion']})"
    if alg == "human":
        pre = [our_value(next(iter(ours.values()), None), "t_pre", m) for m in range(2)]
        if pre[0] is None and pre[1] is None:
            return f"{head}: not run yet."
        return f"{head}: ours t_pre " + ", ".join(
            f"{v:.4f} in {name}" for v, name in zip(pre, MEASURES, strict=True) if v is not None) + "."
    if alg not in ours:
        return f"{head}: not run yet."
    line = f"{head}: " + "; ".join(claim_line(c, alg, ours) for c in row["claims"]) + "."
    failed = [claim_text(c) for c in row["claims"] if claim_fails(c, alg, ours)]
    whys = dict.fromkeys(why_not.get(f"{alg}: {c}", why_not.get(c, "not established yet.")) for c in failed)
    return line + "".join(f" *Why ours differ:* {why}" for why in whys)


def _paper_num(x: float | None) -> str:
    return "" if x is None else f"{x + 0.0:g}"  # + 0.0: the paper's -0.0 prints as 0


def paper_markdown(results: list[EntryResults], paper: dict[str, Any], header: str) -> str:
    """docs/paper.md: a header, then every catalogue entry's section."""
    entries = paper["entries"]
    missing = {"status": "not found", "notes": "no entry in the data file."}
    body = [entry_markdown(r, entries.get(r.entry, missing)) for r in results]
    return "\n".join([header, *body])


# ---- the ledger: the runs the page has shown, wherever they ran

LEDGER_KEYS = ("entry", "exp_id")


def ledger_path(page: str | Path) -> Path:
    """docs/paper.md -> docs/paper_runs.json."""
    page = Path(page)
    return page.parent / f"{page.stem}_runs.json"


def read_ledger(path: str | Path) -> pd.DataFrame:
    """The ledger's rows (entry, exp_id, the run's config keys and metrics); empty when absent."""
    path = Path(path)
    if not path.is_file():
        return pd.DataFrame(columns=list(LEDGER_KEYS))
    try:
        rows = json.loads(path.read_text())["runs"]
    except (OSError, ValueError, KeyError, TypeError):
        rows = None
    if not isinstance(rows, list) or not all(isinstance(r, dict) and set(LEDGER_KEYS) <= set(r)
                                             for r in rows):
        raise ConfigError(f"{path}: not a runs ledger (key 'runs': rows with 'entry' and 'exp_id'). "
                          "Fix: restore it from git (git checkout -- FILE), or move it away to start a new "
                          "one (the page then shows only the runs finished here).")
    return pd.DataFrame(rows, columns=list(dict.fromkeys([*LEDGER_KEYS, *(k for r in rows for k in r)])))


def ledger_json(rows: pd.DataFrame) -> str:
    """The ledger file's text: rows sorted by entry and run, NaN as null, no folder path."""
    rows = rows.drop(columns=["folder"], errors="ignore").sort_values(list(LEDGER_KEYS), kind="stable")
    records = [{k: _plain(v) for k, v in r.items() if not _missing(v)} for r in rows.to_dict("records")]
    return json.dumps({"runs": records}, indent=1, sort_keys=True) + "\n"


def _plain(v: Any) -> Any:
    return v.item() if isinstance(v, np.generic) else v


def _missing(v: Any) -> bool:
    return v is None or (isinstance(v, float | np.floating) and math.isnan(v))
