"""The URB paper's tables next to ours (docs/paper.md).

The paper's numbers are data, `configs/paper/urb_paper.json`, typed by hand from the paper's LaTeX
source: per catalogue entry, its tables (one per network, a row per algorithm, the paper's columns
with the stds it prints), each naming the table label it was read from (`tab:kpis`, ...); URB's
README table, an older 3-run version, rides along as a second, labelled source. Every row carries
claims, the paper's conclusions as comparisons that hold on its own numbers, each with the label or
section that states it ("t_CAV > t_pre": the CAVs stayed slower than as humans; "t_CAV >
aon.t_CAV": slower than the same table's AON row; "WR > 0": some run beat the humans). Text claims
that cannot be judged here are listed with why. Ours are the entry's finished runs, aggregated over
seeds as the leaderboard does, in both trip measures (SUMO's trip duration, the published tables' measure, and
URB's current travel time; docs/metrics.md), and each claim is recomputed on them. Where ours
contradict a claim, the entry's `why_not` says why, with its evidence, or the page says that the
reason is not established yet.

The page keeps a ledger beside it (docs/paper_runs.json): one row per finished run it has shown
(its config keys, metrics and provenance: `reporting.provenance`; no path). A catalogue takes
longer than one machine lives, so each generation shows the runs finished here and the ledger's
runs finished elsewhere: the page fills in across machines and sessions instead of forgetting what
ran before.
"""

from __future__ import annotations

import copy
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from urb_jax.core.configio import configs_dir, loads_strict
from urb_jax.core.errors import ConfigError
from urb_jax.reporting import verdicts as V  # noqa: N812
from urb_jax.reporting.comparable import comparable_metrics, hybrid_note, is_hybrid
from urb_jax.reporting.cost import cost_markdown
from urb_jax.reporting.suite_report import runs_tables
from urb_jax.reporting.train_days import LEGEND, days_cell
from urb_jax.reporting.travel_figures import PREFIX, NetworkFigure

PAPER_FILE = ("paper", "urb_paper.json")
MEASURES = ("SUMO duration", "travel time")
# paper column -> our metric in each measure (duration, travel time); one metric where the
# quantity has no travel-time/duration pair
COLUMNS = {"t_pre": ("t_pre_duration", "t_pre"), "t_test": ("t_test_duration", "t_test"),
           "t_CAV": ("t_CAV_duration", "t_CAV"), "t_HDV_post": ("t_HDV_test_duration", "t_HDV_test"),
           "c_all": ("cost_of_learning",) * 2, "c_HDV": ("cost_of_learning_humans",) * 2,
           "c_CAV": ("cost_of_learning_CAVs",) * 2, "delta_V": ("delta_V",) * 2,
           "delta_L": ("delta_L",) * 2, "WR": ("WR",) * 2,
           "delta_pct": ("delta_pct_duration", "delta_pct")}
HEADS = {"t_pre": "t_pre", "t_test": "t_test", "t_CAV": "t_CAV", "t_HDV_post": "t_HDV^post", "c_all": "c_all",
         "c_HDV": "c_HDV", "c_CAV": "c_CAV", "delta_V": "ΔV", "delta_L": "ΔL", "WR": "WR %",
         "delta_pct": "Δ%t_pre"}
OPS = {"<": lambda a, b: a < b, ">": lambda a, b: a > b, "≈": lambda a, b: a == b}
NAMES = {"iql": "IQL", "ippo": "IPPO", "mappo": "MAPPO", "qmix": "QMIX", "vdn": "VDN", "iql_star": "IQL*",
         "ippo_star": "IPPO*", "human": "Human", "aon": "AON", "random": "Random",
         "iql_original": "IQL (Original)", "mappo_original": "MAPPO (Original)"}


def paper_file() -> Path:
    return configs_dir().joinpath(*PAPER_FILE)


def load_paper_numbers(path: str | Path | None = None) -> dict[str, Any]:
    """The paper's numbers, checked: every table has a source (a label of the paper, or an address
    for the README's tables) and a caption, every column is one of COLUMNS, every claim is well
    formed, names its source and holds on the paper's own numbers where the paper prints them."""
    path = Path(path) if path else paper_file()
    try:
        data = loads_strict(path.read_text(), path)
    except (OSError, ValueError) as exc:  # ValueError: bad JSON or UTF-8
        raise ConfigError(f"{path}: cannot read the paper's numbers ({exc}). "
                          "Fix: restore the file.") from None
    for i, c in enumerate(data.get("contradictions", [])):
        if not c.get("what") or not c.get("sources") or not all(_is_source(x) for x in c["sources"]):
            raise ConfigError(f"{path}: contradictions[{i}]: needs 'what' and 'sources' (labels of the "
                              "paper). Fix: add them.")
    for entry, e in data.get("entries", {}).items():
        _copy_tables(data, entry, e, path)
    for entry, e in data.get("entries", {}).items():
        where = f"{path}: entries.{entry}"
        for key, source in e.get("rows_from", {}).items():
            if source.partition(":")[0] not in data["entries"]:
                raise ConfigError(f"{where}.rows_from.{key}: {source!r} names no entry. Fix: 'ENTRY' or "
                                  "'ENTRY:ROW', with ENTRY one of the file's entries.")
        if e.get("status") in ("not found", "figure only"):
            if e.get("tables") or not e.get("notes"):
                raise ConfigError(f"{where}: '{e.get('status')}' has no tables and says why in 'notes'. "
                                  "Fix: write it so.")
            _check_text_claims(e, where)
            continue
        if e.get("status") != "found" or not e.get("tables"):
            raise ConfigError(f"{where}: status is 'found' (with tables), 'figure only' or 'not found'. "
                              "Fix: set it.")
        for i, t in enumerate(e["tables"]):
            _check_table(t, f"{where}.tables[{i}]")
        _check_text_claims(e, where)
        claims = {key for t in e["tables"] for alg, row in t["rows"].items()
                  for c in row.get("claims", []) for key in (claim_text(c), f"{alg}: {claim_text(c)}")}
        unknown = sorted(set(e.get("why_not", {})) - claims)
        if unknown:
            raise ConfigError(f"{where}.why_not: {unknown} are not claims of this entry's rows. "
                              f"Fix: key each explanation by a claim ('t_CAV > t_pre') or a row's claim "
                              f"('qmix: t_CAV < t_pre'), one of {sorted(claims)}.")
    return data


def _copy_tables(data: dict[str, Any], entry: str, e: dict[str, Any], path: Path) -> None:
    """An entry judged against another entry's tables (`tables_from`: {entry, networks}) gets copies
    of them: the paper's numbers are typed once."""
    src = e.get("tables_from")
    if src is None:
        return
    other = data.get("entries", {}).get(src.get("entry"), {})
    tables = [copy.deepcopy(t) for t in other.get("tables", []) if t["network"] in src.get("networks", [])]
    if e.get("tables") or not tables:
        raise ConfigError(f"{path}: entries.{entry}.tables_from: names an entry and networks with tables, "
                          "and the entry has no tables of its own. Fix: correct it.")
    keep = src.get("rows")  # only these rows (e.g. one algorithm's run and the baselines)
    if keep is not None:
        unknown = sorted(set(keep) - {k for t in tables for k in t["rows"]})
        if unknown:
            raise ConfigError(f"{path}: entries.{entry}.tables_from.rows: {unknown} are not rows of "
                              f"{src.get('entry')}'s tables. Fix: name rows they have.")
        for t in tables:
            t["rows"] = {k: v for k, v in t["rows"].items() if k in keep}
    e["tables"] = tables


def _is_source(text: Any) -> bool:
    """A label of the paper (tab:..., sec:..., fig:...) or an address."""
    return isinstance(text, str) and bool(re.match(r"(tab|sec|fig):|https://", text))


def _check_text_claims(e: dict[str, Any], where: str) -> None:
    for i, c in enumerate(e.get("claims", [])):
        if not c.get("text") or not _is_source(c.get("source")) or not c.get("why"):
            raise ConfigError(f"{where}.claims[{i}]: a text claim needs 'text', a 'source' (a label of the "
                              "paper) and 'why' it cannot be judged here. Fix: add them.")


def _check_table(t: dict[str, Any], where: str) -> None:
    if not _is_source(t.get("source")) or not t.get("caption") or not t.get("network"):
        raise ConfigError(f"{where}: a table needs 'network', 'caption' and a 'source' (a label of the "
                          "paper: tab:..., sec:...; or an address). Fix: add them.")
    readme = t.get("readme")
    if readme is not None and not str(readme.get("source", "")).startswith("https://"):
        raise ConfigError(f"{where}.readme: needs the 'source' address it was read at. Fix: add it.")
    for alg, row in t.get("rows", {}).items():
        bad = (set(row["values"]) | set(row.get("sd", {}))) - set(COLUMNS)
        if bad or set(row.get("sd", {})) - set(row["values"]):
            raise ConfigError(f"{where}.rows.{alg}: columns {sorted(bad)} (or an sd without its value). "
                              f"Fix: use some of {list(COLUMNS)}.")
        for claim in row.get("claims", []):
            if not _is_source(claim.get("source")):
                raise ConfigError(f"{where}.rows.{alg}: claim {claim.get('claim')} has no 'source' (a label "
                                  "of the paper). Fix: add it.")
            held = _evaluate(claim["claim"], alg,
                             lambda key, col: t["rows"].get(key, {}).get("values", {}).get(col))
            if held is not None and not held[0]:
                raise ConfigError(f"{where}.rows.{alg}: claim {claim['claim']} does not hold on the paper's "
                                  "own numbers. Fix: state what the paper's numbers show.")


def _operand(term: str | float, row: str) -> tuple[str, str]:
    """'t_pre' -> (row, 't_pre'); 'aon.t_CAV' -> ('aon', 't_CAV'); a number -> ('', '')."""
    if not isinstance(term, str):
        return "", ""
    key, _, col = term.rpartition(".")
    return (key or row), col


def claim_parts(claim: list[Any]) -> tuple[str, str, str | float, float]:
    """[left, op, right] or [left, '≈', right, relative margin] -> (left, op, right, margin)."""
    ok = len(claim) in (3, 4) and claim[1] in OPS and isinstance(claim[0], str)
    ok = ok and (len(claim) == 4) == (claim[1] == "≈")
    ok = ok and (claim[0] != "WR" or (claim[1] != "≈" and isinstance(claim[2], int | float)))
    terms = [claim[0]] + ([claim[2]] if ok and isinstance(claim[2], str) else [])
    if not ok or any(_operand(x, "")[1] not in COLUMNS for x in terms):
        raise ConfigError(f"claim {claim}: use [column, '<' or '>', column, 'row.column' or a number], "
                          f"[column, '≈', column or 'row.column', relative margin] or ['WR', '<' or '>', "
                          f"percent], with columns of {list(COLUMNS)}. Fix: rewrite it.")
    return claim[0], claim[1], claim[2], float(claim[3]) if len(claim) == 4 else 0.0


def _evaluate(claim: list[Any], row: str, value) -> tuple[bool, float, float] | None:
    """(holds, left, right) of a claim on `value(row_key, column)` point values; None where a value
    is missing."""
    left, op, right, margin = claim_parts(claim)
    a = value(*_operand(left, row))
    b = right if not isinstance(right, str) else value(*_operand(right, row))
    if a is None or b is None or a != a or b != b:  # missing or NaN
        return None
    if op == "≈":
        return abs(a - b) <= margin * abs(b) + 1e-12, float(a), float(b)
    return OPS[op](a, b), float(a), float(b)


def row_key(alg: str) -> str:
    """The paper-table key of one of our rows: urb-jax's id, a baseline without 'baseline_'."""
    return alg.removeprefix("baseline_")


# ---- our per-seed values

Seeds = dict[str, pd.DataFrame]  # paper-table key -> that row's per-seed runs on one network


def our_seeds(runs: pd.DataFrame, network: str) -> Seeds:
    """Our per-seed rows on one network, by paper-table key (seeds sorted by run id)."""
    if runs.empty or "network" not in runs:
        return {}
    table = runs[runs["network"] == network]
    keys = [row_key(str(a or b)) for a, b in zip(table.get("alg", table["algorithm"]), table["algorithm"],
                                                 strict=True)]
    return {k: g.sort_values("exp_id") for k, g in table.assign(_key=keys).groupby("_key", sort=False)}


def seed_values(rows: pd.DataFrame, column: str, measure: int) -> list[float] | None:
    """One value per seed of a paper column in a measure (MEASURES' order); WR: 1 where the seed's
    CAVs beat its t_pre, else 0; None where any seed lacks it (not recorded)."""
    def col(name: str) -> pd.Series:
        if name not in rows:
            return pd.Series([math.nan] * len(rows))
        return pd.to_numeric(rows[name], errors="coerce").reset_index(drop=True)

    if column == "WR":
        if measure == 1 and "winrate" in rows:
            vals = col("winrate")
        else:
            vals = (col(COLUMNS["t_CAV"][measure]) < col(COLUMNS["t_pre"][measure])).astype(float)
            vals[col(COLUMNS["t_CAV"][measure]).isna()] = math.nan
    elif column == "delta_pct":
        pre, cav = col(COLUMNS["t_pre"][measure]), col(COLUMNS["t_CAV"][measure])
        vals = (pre - cav) / pre * 100.0
    else:
        vals = col(COLUMNS[column][measure])
    return None if vals.isna().any() or vals.empty else [float(v) for v in vals]


# ---- verdicts on the paper's claims and cells

NOT_COMPARED = {"c_all", "c_HDV", "c_CAV"}  # the published costs follow neither URB's code nor ours
WHY_COST = ("the published costs follow a definition unlike ours (docs/metrics.md): their values are not "
            "compared, only the paper's claims about their sign")


def hybrid_cost(rows: pd.DataFrame, column: str) -> str | None:
    """'not comparable: hybrid (N SUMO of M training days)' where `column` is a cost of learning and
    `rows` a hybrid run's seeds: its costs cover its SUMO training days only, URB's every training
    day (`comparable`); None otherwise."""
    if column not in NOT_COMPARED or rows.empty:
        return None
    first = {k: v for k, v in rows.iloc[0].to_dict().items() if isinstance(k, str)}
    return hybrid_note(first) if is_hybrid(first) else None


@dataclass(frozen=True)
class Judged:
    """One claim of the paper, judged in both measures (the first, SUMO duration, is the paper's)."""

    entry: str
    network: str
    row: str
    text: str
    source: str
    verdicts: tuple[V.Verdict, ...]
    why: str = ""  # the entry's explanation, where ours do not confirm it


def _missing_row(key: str, ours: Seeds, paper: dict[str, Any]) -> V.Verdict | None:
    if key in ours:
        return None
    why = paper.get("not_comparable", {}).get(key)
    return V.not_comparable(why or f"not run yet ({NAMES.get(key, key)})")


def judge_claim(claim: list[Any], row: str, ours: Seeds, paper: dict[str, Any], measure: int) -> V.Verdict:
    """A claim of row `row` on our per-seed values in one measure."""
    left, op, right, margin = claim_parts(claim)
    lkey, lcol = _operand(left, row)
    for key in [lkey] + ([_operand(right, row)[0]] if isinstance(right, str) else []):
        missing = _missing_row(key, ours, paper)
        if missing:
            return missing
    hybrid = hybrid_cost(ours[lkey], lcol)
    if hybrid:
        return V.not_comparable(hybrid)
    lvals = seed_values(ours[lkey], lcol, measure)
    if lvals is None:
        return V.not_comparable("per-seed values not recorded")
    if lcol == "WR":
        return V.win_rate(round(sum(lvals)), len(lvals), op, float(right))
    if not isinstance(right, str):
        diff = V.welch(V.Sample.of(lvals), V.Sample(float(right), 0.0, 1))
        return V.direction(diff, op)
    rkey, rcol = _operand(right, row)
    rvals = seed_values(ours[rkey], rcol, measure)
    if rvals is None:
        return V.not_comparable("per-seed values not recorded")
    same = rkey == lkey and len(rvals) == len(lvals)
    diff = V.paired(lvals, rvals) if same else V.welch(V.Sample.of(lvals), V.Sample.of(rvals))
    if op == "≈":
        return V.equivalence(diff, margin * abs(sum(rvals) / len(rvals)))
    return V.direction(diff, op)


def human_key(ours: Seeds) -> str | None:
    """Whose t_pre the Human row shows: any run's humans are the same drivers before the CAVs, so the
    group with the most seeds (then the first by name), whichever order the runs were read in (the
    results folder's or the ledger's)."""
    return min(ours, key=lambda k: (-len(ours[k]), k), default=None)


def judge_cell(table: dict[str, Any], row: str, column: str, ours: Seeds) -> V.Verdict:
    """Our value of one paper cell against the paper's mean/std/n (SUMO duration, its measure)."""
    prow = table["rows"][row]
    key = human_key(ours) if row == "human" else row
    if column in NOT_COMPARED:  # a hybrid run's costs are not URB's either way: say why first
        return V.not_comparable((key in ours and hybrid_cost(ours[key], column)) or WHY_COST)
    if key is None or key not in ours:
        return V.not_comparable("not run")
    vals = seed_values(ours[key], column, 0)
    if vals is None:
        return V.not_comparable("per-seed values not recorded")
    runs = prow.get("runs", table.get("runs")) if "runs" in prow else table.get("runs")
    value = prow["values"][column]
    if column == "WR":
        if not runs:
            return V.not_comparable("the paper's number of runs is not stated")
        return V.win_rates_agree(round(sum(vals)), len(vals), round(value * runs / 100), runs)
    sd = prow.get("sd", {}).get(column)
    paper = V.Sample(value, sd or 0.0, runs if sd is not None and runs else 1, rounding=0.005)
    return V.value_agrees(V.Sample.of(vals), paper)


# ---- the page

@dataclass(frozen=True)
class EntryResults:
    """One catalogue entry as far as it has run: its finished runs (`collect_folders` rows, here or
    from the ledger, one per seed), how many runs it has and how many finished, the seeds each train
    run plans, and links to the suite's figures."""

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
    # the paper's travel-time figure per network (reporting.travel_figures), for entries that have one
    travel: tuple[NetworkFigure, ...] = ()


SHORT = {V.HOLDS: "equal", V.FAILS: "differs", V.TIE: "tie", V.NOT_COMPARABLE: "·"}


def _entry_seeds(res: EntryResults, paper: dict[str, Any], network: str,
                 all_runs: dict[str, pd.DataFrame]) -> Seeds:
    seeds = our_seeds(res.runs, network)
    for key, source in paper.get("rows_from", {}).items():  # rows the paper took from another table
        other, _, row = source.partition(":")  # "entry" (the same row) or "entry:row"
        theirs = our_seeds(all_runs.get(other, pd.DataFrame()), network)
        if (row or key) in theirs:
            seeds[key] = theirs[row or key]
    return seeds


def judge_entry(res: EntryResults, paper: dict[str, Any], all_runs: dict[str, pd.DataFrame]) -> list[Judged]:
    """Every claim of an entry's rows and text, judged on our runs. Where ours contradict a claim,
    the entry's `why_not` says why (its row's key, else the claim's), or 'not established yet'; a
    tie shows its row's own explanation only."""
    out = []
    why_not = paper.get("why_not", {})
    for table in paper.get("tables", []):
        ours = _entry_seeds(res, paper, table["network"], all_runs)
        for alg, row in table["rows"].items():
            for c in row.get("claims", []):
                verdicts = tuple(judge_claim(c["claim"], alg, ours, paper, m) for m in range(len(MEASURES)))
                text, kind = claim_text(c), verdicts[0].kind
                why = ""
                if kind == V.FAILS:
                    why = why_not.get(f"{alg}: {text}", why_not.get(text, "not established yet."))
                elif kind == V.TIE:
                    why = why_not.get(f"{alg}: {text}", "")
                label = _claim_label(c["claim"], alg)
                out.append(Judged(res.entry, table["network"], alg, label, c["source"], verdicts, why))
    for c in paper.get("claims", []):
        out.append(Judged(res.entry, "", "", f"\"{c['text']}\"", c["source"], (V.not_comparable(c["why"]),)))
    return out


def claim_text(claim: dict[str, Any] | list[Any]) -> str:
    """A claim as urb_paper.json's `why_not` keys it: 't_CAV > aon.t_CAV' (every row's), or
    prefixed by a row, 'qmix: t_CAV < t_pre' (that row's)."""
    parts = claim["claim"] if isinstance(claim, dict) else claim
    return " ".join(f"{x:g}" if isinstance(x, float) else str(x) for x in parts[:3])


def _claim_label(claim: list[Any], row: str) -> str:
    left, op, right, margin = claim_parts(claim)
    if left == "WR":
        return f"WR {op} {right:g}%"
    label = f"{_term(left, row)} {op} {_term(right, row)}"
    return label + (f" (within {100 * margin:g}%)" if op == "≈" else "")


def _term(term: str | float, row: str) -> str:
    if not isinstance(term, str):
        return f"{term:g}"
    key, col = _operand(term, row)
    return HEADS[col] if key == row else f"{NAMES.get(key, key)} {HEADS[col]}"


def _judged_line(j: Judged, shown: set[str]) -> str:
    """A claim's line; an explanation already given for the row is referred to, not repeated."""
    first = j.verdicts[0]
    line = f"{j.text} [{j.source}]: **{first.kind}** ({first.detail})"
    if len(j.verdicts) > 1 and j.verdicts[1].kind != first.kind:
        line += f"; in travel time {j.verdicts[1]}"
    if not j.why:
        return line
    if j.why in shown:
        return line + " *Why ours differ:* as above."
    shown.add(j.why)
    return line + f" *Why ours differ:* {j.why}"


def entry_markdown(res: EntryResults, paper: dict[str, Any], all_runs: dict[str, pd.DataFrame]) -> str:
    """An entry's section: the paper's tables with ours under each row, every claim judged."""
    out = [f"## `{res.entry}`: {res.title}", ""]
    state = ("not run yet" if not res.runs_done else
             f"{res.runs_done} of {res.runs_planned} runs finished")
    out.append(f"Ours: {state}; {res.seeds_planned} seed(s) per train run planned. "
               f"Paper: {paper.get('paper_seeds', 'seeds not stated')}.")
    out.append("")
    if res.missing and res.runs_done:
        out += [f"Not finished yet: {', '.join(f'`{m}`' for m in res.missing)} "
                f"(`urb-jax suite {res.entry} --status`; `urb-jax suite {res.entry}` runs them).", ""]
    if not res.partial.empty:
        out += [f"Seeds finished of runs not finished yet (kept in the ledger, shown once their run is): "
                f"{', '.join(f'`{n}`' for n in sorted(res.partial['exp_id']))}.", ""]
    if paper.get("status") != "found":
        out += [f"**The paper's numbers: {paper.get('status', 'not found')}.** {paper.get('notes', '')}", ""]
        if not res.runs.empty:
            out += ["Ours (mean ± std over seeds):", "", runs_tables(res.runs)]
    else:
        out += [f"The paper concludes: {paper['conclusion']}. Measure: {paper['measure']}.", ""]
        if paper.get("notes"):
            out += [f"Note: {paper['notes']}", ""]
        judged = judge_entry(res, paper, all_runs)
        for table in paper["tables"]:
            ours = _entry_seeds(res, paper, table["network"], all_runs)
            out += _table_markdown(table, ours, [j for j in judged if j.network == table["network"]], paper)
        if paper.get("decomposes"):
            out += decomposition_markdown(res, paper, all_runs.get(paper["decomposes"], pd.DataFrame()))
        if paper.get("wiring") and paper.get("decomposes"):
            out += wiring_markdown(paper, all_runs.get(paper["decomposes"], pd.DataFrame()),
                                   all_runs.get(paper["wiring"], pd.DataFrame()))
    text = [c for c in paper.get("claims", [])]
    if text:
        out += ["Claims of the paper not judged here:", ""]
        out += [f"- \"{c['text']}\" [{c['source']}]: not comparable ({c['why']})." for c in text] + [""]
    if paper.get("figure"):
        out += travel_markdown(res.travel, paper["figure"])
    if res.figures:
        out += ["Figures (travel times over days per group, phases as patches; written by the suite):", ""]
        out += [f"![{Path(f).stem}]({f})" for f in res.figures] + [""]
    return "\n".join(out)


TRAVEL = """Our analogue of the paper's [{source}], per network: t/t_pre (a day's mean travel time
over the run's pre-CAV mean, t_pre) of the CAVs, per algorithm (solid: the mean over its seeds with the
95% t-interval of the mean as a band), and of the humans (orange dashed: averaged over every run of the
network, as the paper's), on every SUMO day recorded: the human phase, the training days and the test
days (patches). The training days are drawn in the order they ran: a hybrid round's surrogate days,
then its SUMO days. Smoothed as the paper's, by a moving average of {window} days (a trailing window of
days of the axis, within each phase: a hybrid run's few SUMO days per round are averaged over the
round(s) in the window). **Surrogate days** (dotted steps): a run does not record each surrogate day's
predictions, only each round's mean predicted travel time over its surrogate days (rounds.csv); each
step is that mean (over seeds, over t_pre), drawn over the days the round's surrogate days span."""


def travel_markdown(figures: tuple[NetworkFigure, ...], spec: dict[str, Any]) -> list[str]:
    """The entry's travel-time figures, one per network, with the caption (or why a network has none)."""
    out = [f"### Travel times over the days (the paper's [{spec['source']}])", "",
           TRAVEL.format(source=spec["source"], window=spec["window"]), ""]
    if not figures:
        return [*out, "No network of this entry has a figure yet: none of its runs is under the results "
                      "folder.", ""]
    for f in figures:
        out.append(f"- `{f.network}`: {f.note}.")
    out.append("")
    out += [f"![{PREFIX}{f.network}]({f.link})" for f in figures if f.link] + [""]
    return out


DECOMPOSITION = """Per algorithm, in the paper's measure (t_CAV in SUMO trip duration, minutes): the paper's
mean (its sd, 5 runs), ours trained every training day in SUMO (this entry) and ours hybrid (`{hybrid}`),
each mean ± sample sd (ddof=1) [95% t-interval] (seeds). Then the two shares of the gap, each a Welch
difference [95% interval] with its two-sided p: **implementation** = paper − ours in SUMO only (what
our implementation changes under the paper's own protocol), **surrogate** = ours in SUMO only − ours
hybrid (what training on the surrogate changes; "tie" where the interval covers 0). WR: runs whose
CAVs beat their t_pre, with the Clopper-Pearson 95% interval."""


def decomposition_markdown(res: EntryResults, paper: dict[str, Any], hybrid_runs: pd.DataFrame) -> list[str]:
    """The gap between the paper's t_CAV and ours hybrid, split into our implementation's share (the
    paper against ours in SUMO only) and the surrogate's (ours in SUMO only against ours hybrid)."""
    out = ["### The gap to the paper, split: implementation and surrogate", "",
           DECOMPOSITION.format(hybrid=paper["decomposes"]), ""]
    head = ["algorithm", "network", "paper", "ours, SUMO only", "ours, hybrid", "implementation",
            "surrogate", "WR SUMO only", "WR hybrid"]
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for table in paper["tables"]:
        net = table["network"]
        sumo, hybrid = our_seeds(res.runs, net), our_seeds(hybrid_runs, net)
        for alg, row in table["rows"].items():
            if alg in paper.get("rows_from", {}) or "t_CAV" not in row["values"]:
                continue  # baselines: no training days to decompose
            out.append("| " + " | ".join([f"**{NAMES.get(alg, alg)}**", net,
                                          *_decomposition_cells(row, sumo.get(alg), hybrid.get(alg))]) + " |")
    return [*out, ""]


WIRING = """The implementation's share, split, per algorithm: ours hybrid trained on URB's TorchRL frames and
raw observations (`{wiring}`) against ours hybrid (`{hybrid}`), both mean ± sample sd [95% t-interval]
(seeds). **URB's wiring** = ours on URB's wiring − ours (what the wiring changes; both runs hybrid, so
the surrogate's share does not enter), **left** = the paper − ours on URB's wiring (what URB's wiring
does not explain; "tie" where the interval covers 0)."""


def wiring_markdown(paper: dict[str, Any], hybrid_runs: pd.DataFrame, wiring_runs: pd.DataFrame) -> list[str]:
    """The implementation's share of the gap split into URB's TorchRL wiring (our learners on URB's
    frames and raw observations) and what is left, per algorithm of the paper's tables."""
    out = ["### The implementation's share, split: URB's wiring and the rest", "",
           WIRING.format(wiring=paper["wiring"], hybrid=paper["decomposes"]), ""]
    head = ["algorithm", "network", "paper", "ours, URB's wiring", "ours", "URB's wiring", "left",
            "WR URB's wiring"]
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for table in paper["tables"]:
        net = table["network"]
        wiring, hybrid = our_seeds(wiring_runs, net), our_seeds(hybrid_runs, net)
        for alg, row in table["rows"].items():
            if alg in paper.get("rows_from", {}) or "t_CAV" not in row["values"]:
                continue
            out.append("| " + " | ".join([f"**{NAMES.get(alg, alg)}**", net,
                                          *_wiring_cells(row, wiring.get(alg), hybrid.get(alg))]) + " |")
    return [*out, ""]


def _wiring_cells(row: dict[str, Any], wiring: pd.DataFrame | None, hybrid: pd.DataFrame | None) -> list[str]:
    paper, cells = _paper_sample(row)
    wiring_s, hybrid_s = _t_cav(wiring), _t_cav(hybrid)
    cells += [_sample_cell(s) for s in (wiring_s, hybrid_s)]
    cells.append(_share(V.welch(wiring_s, hybrid_s)) if wiring_s and hybrid_s else "not run yet")
    cells.append(_share(V.welch(paper, wiring_s)) if wiring_s else "not run yet")
    return [*cells, _wins(wiring)]


def _paper_sample(row: dict[str, Any]) -> tuple[V.Sample, list[str]]:
    """The paper's t_CAV as a sample (its sd and 5 runs where printed) and its cell."""
    mean, sd = row["values"]["t_CAV"], row.get("sd", {}).get("t_CAV")
    paper = V.Sample(mean, sd or 0.0, 5 if sd is not None else 1, rounding=0.005)  # printed to 2 decimals
    return paper, [f"{_paper_num(mean)} ({'sd not printed' if sd is None else f'{sd:g}'})"]


def _decomposition_cells(row: dict[str, Any], sumo: pd.DataFrame | None, hybrid: pd.DataFrame | None
                         ) -> list[str]:
    paper, cells = _paper_sample(row)
    sumo_s, hybrid_s = _t_cav(sumo), _t_cav(hybrid)
    cells += [_sample_cell(s) for s in (sumo_s, hybrid_s)]
    cells.append(_share(V.welch(paper, sumo_s)) if sumo_s else "not run yet")
    cells.append(_share(V.welch(sumo_s, hybrid_s)) if sumo_s and hybrid_s else "not run yet")
    cells += [_wins(r) for r in (sumo, hybrid)]
    return cells


def _t_cav(rows: pd.DataFrame | None) -> V.Sample | None:
    vals = None if rows is None else seed_values(rows, "t_CAV", 0)
    return V.Sample.of(vals) if vals else None


def _sample_cell(s: V.Sample | None) -> str:
    if s is None:
        return "not run yet"
    lo, hi = V.welch(s, V.Sample(0.0, 0.0, 1)).interval(0.95)
    return f"{s.mean:.4f} ± {s.sd:.4f} [{lo:.4f}, {hi:.4f}] ({s.n})"


def _share(d: V.Difference) -> str:
    lo, hi = d.interval(0.95)
    tie = " **tie**" if lo <= 0.0 <= hi else ""
    p = "< 0.001" if d.p_two() < 0.001 else f"= {d.p_two():.3f}"
    return f"{d.diff:+.4f} [{lo:+.4f}, {hi:+.4f}], p {p}{tie}"


def _wins(rows: pd.DataFrame | None) -> str:
    vals = None if rows is None else seed_values(rows, "WR", 0)
    if not vals:
        return "not run yet"
    k, n = round(sum(vals)), len(vals)
    lo, hi = V.clopper_pearson(k, n)
    return f"{k}/{n} [{100 * lo:.0f}%, {100 * hi:.0f}%]"


def _columns(table: dict[str, Any]) -> list[str]:
    present = {c for r in table["rows"].values() for c in r["values"]}
    return [c for c in COLUMNS if c in present] or ["t_pre", "t_CAV", "WR"]


def _paper_cell(row: dict[str, Any], col: str) -> str:
    v = row["values"].get(col)
    if v is None:
        return ""
    sd = row.get("sd", {}).get(col)
    return _paper_num(v) + (f" ({sd:g})" if sd is not None else "")


def _our_cell(rows: pd.DataFrame, col: str, measure: int) -> str:
    hybrid = hybrid_cost(rows, col)
    if hybrid:
        return hybrid
    vals = seed_values(rows, col, measure)
    if vals is None:
        return "n/a"
    if col == "WR":
        return f"{100 * sum(vals) / len(vals):.0f} ({round(sum(vals))}/{len(vals)})"
    s = V.Sample.of(vals)
    return f"{s.mean:.4f}" + (f" ± {s.sd:.4f}" if s.n > 1 else "")


def _table_markdown(table: dict[str, Any], ours: Seeds, judged: list[Judged],
                    paper: dict[str, Any]) -> list[str]:
    cols = _columns(table)
    out = [f"### {table['name']} (`{table['network']}`)", "",
           f"Paper: \"{table['caption']}\" [{table['source']}]."]
    readme = table.get("readme")
    if readme:
        also = "".join(f", [also]({u})" for u in readme.get("also_at", []))
        out[-1] += (f" README: URB's GitHub README table ({readme['runs']} runs), "
                    f"[source]({readme['source']}){also}, shown where it differs.")
    out.append("")
    head = ["algorithm", "numbers", "runs", "training days", *(HEADS[c] for c in cols)]
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    extra = [k for k in ours if k not in table["rows"]]
    for alg in [*table["rows"], *extra]:
        name = NAMES.get(alg, alg)
        row = table["rows"].get(alg)
        if row is not None:
            runs = row.get("runs", table.get("runs")) if "runs" in row else table.get("runs")
            numbers = f"paper [{table['source']}]" + ("" if row["values"] else ": no numbers")
            out.append("| " + " | ".join([f"**{name}**", numbers,
                                          str(runs or "not stated"), "",
                                          *(_paper_cell(row, c) for c in cols)]) + " |")
            name = ""
            old = readme["values"].get(alg, {}) if readme else {}
            differ = [c in old and c in row["values"] and old[c] != row["values"][c] for c in cols]
            if readme and any(differ):
                out.append("| " + " | ".join(["", "README", str(readme["runs"]), "", *(
                    _paper_num(old[c]) if d else "" for c, d in zip(cols, differ, strict=True))]) + " |")
        key = human_key(ours) if alg == "human" else alg
        r = ours.get(key) if key else None
        if r is None:
            why = "not comparable (see below)" if alg in paper.get("not_comparable", {}) else "not run yet"
            out.append("| " + " | ".join([name, "ours", "", "", why,
                                          *[""] * (len(cols) - 1)]) + " |")
            continue
        mine = ["t_pre"] if alg == "human" else cols  # the human row is t_pre itself
        days = "" if alg == "human" else days_cell(r)
        for m, measure in enumerate(MEASURES):
            out.append("| " + " | ".join([name, f"ours, {measure}", str(len(r)), days if m == 0 else "", *(
                _our_cell(r, c, m) if c in mine else "" for c in cols)]) + " |")
            name = ""
        if row is not None and row["values"]:
            cells = [SHORT[judge_cell(table, alg, c, ours).kind] if c in row["values"] and c in mine else ""
                     for c in cols]
            out.append("| " + " | ".join(["", "ours vs paper", "", "", *cells]) + " |")
    out += ["", LEGEND, "",
            "The paper's conclusions, judged on ours (SUMO duration; travel time where it differs):", ""]
    for alg, row in table["rows"].items():
        claims = [j for j in judged if j.row == alg]
        if not claims:
            continue
        out.append(f"- **{NAMES.get(alg, alg)}** (paper: {row['conclusion']}):")
        shown: set[str] = set()
        out += [f"  - {_judged_line(j, shown)}" for j in claims]
    for alg in extra:
        out.append(f"- **{NAMES.get(alg, alg)}**: ours only (not in the paper's table).")
    return [*out, ""]


def _paper_num(x: float | None) -> str:
    return "" if x is None else f"{x + 0.0:g}"  # + 0.0: the paper's -0.0 prints as 0


STATISTICS = """How the claims are judged (urb_jax/reporting/verdicts.py). Ours are per-seed values; their std
is the sample std (ddof=1). A claim of direction (t_CAV > t_pre) **holds** where a one-sided test
at 5% (paired for a row against its own t_pre, Welch's t-test against another row, one-sample
against a number) finds it, **fails** where the same test finds the opposite, and is a **tie**
where the difference is inside the seed spread. A claim of equality (≈) holds where the 90%
interval of the difference lies inside its margin (TOST at 5%), fails where the difference is
significant (two-sided 5%) and not equivalent, and ties otherwise. A win-rate claim (WR > 0) is
judged by the Clopper-Pearson interval of our wins (one-sided 95% bounds; the page prints the 95%
interval: 0 of 5 runs gives [0%, 52%]). With one run on each side (the baselines) there is no
spread: the difference is judged by its value, and the verdict says so. **Not comparable**: the row
did not run, the entry runs other algorithms than the paper's, or the paper gives no number.

Under each of our rows, "ours vs paper" compares each cell with the paper's (SUMO duration):
**equal** where Welch's t-test of our seeds against the paper's mean, std and runs puts the 90%
interval of the difference inside ±1% of the paper's value (at least ±0.01, a unit of its last
digit; the printed numbers' rounding counts as variance), **differs** where the difference is
significant (two-sided 5%) and not equal, **tie** otherwise; win rates by Fisher's exact test
(differs where p < 5%, else tie: five runs cannot show two win rates equal). The paper does not say
whether its std divides by n or n-1; it is read as the sample std. The cost columns are not
compared (their published definition is unlike ours; docs/metrics.md)."""


def summary_markdown(judged: list[Judged]) -> str:
    """The page's summary: how many of the paper's conclusions hold, fail, tie, or are not comparable
    here (SUMO duration, the paper's measure), and why not comparable."""
    count = {k: sum(j.verdicts[0].kind == k for j in judged) for k in V.VERDICTS}
    out = ["## Summary: the paper's conclusions, judged here", "",
           f"Of the paper's {len(judged)} conclusions (claims of its tables and text, each with its "
           f"source), in SUMO duration (the paper's measure): **{count[V.HOLDS]} hold**, **{count[V.FAILS]} "
           f"fail**, **{count[V.TIE]} tie** (not significant either way, or not shown equal), "
           f"**{count[V.NOT_COMPARABLE]} cannot be compared here**.", ""]
    if count[V.FAILS]:
        out += ["Where ours contradict the paper:", ""]
        out += [f"- `{j.entry}` {_where(j)}: {j.text} [{j.source}]"
                for j in judged if j.verdicts[0].kind == V.FAILS]
        out.append("")
    reasons: dict[str, int] = {}
    for j in judged:
        if j.verdicts[0].kind == V.NOT_COMPARABLE:
            reason = f"`{j.entry}`: {j.verdicts[0].detail}"
            reasons[reason] = reasons.get(reason, 0) + 1
    if reasons:
        out += ["Why some cannot be compared:", ""]
        out += [f"- {reason} ({n})" for reason, n in reasons.items()] + [""]
    return "\n".join([*out, STATISTICS, ""])


def _where(j: Judged) -> str:
    return f"{j.network} {NAMES.get(j.row, j.row)}".strip()


def _demand_markdown(demand: dict[str, Any]) -> str:
    ours = [r for r in demand["regions"] if r["network"]]
    rows = ", ".join(f"{r['region']} {r['trips']} trips / {r['od_pairs']} OD pairs" for r in ours)
    return "\n".join(["## The networks' demand", "",
                      f"The paper's demand table [{demand['source']}], for the networks urb-jax ships: "
                      f"{rows}. "
                      f"{demand['check']}", ""])


def paper_markdown(results: list[EntryResults], paper: dict[str, Any], header: str) -> str:
    """docs/paper.md: a header, a summary of the verdicts, then every catalogue entry's section."""
    entries = paper["entries"]
    missing = {"status": "not found", "notes": "no entry in the data file."}
    all_runs = {r.entry: r.runs for r in results}
    judged = [j for r in results for j in judge_entry(r, entries.get(r.entry, missing), all_runs)]
    body = [entry_markdown(r, entries.get(r.entry, missing), all_runs) for r in results]
    extra = []
    if "compute" in paper:
        extra.append(cost_markdown(paper["compute"], all_runs, NAMES))
    if "demand" in paper:
        extra.append(_demand_markdown(paper["demand"]))
    return "\n".join([header, summary_markdown(judged), _contradictions_markdown(paper), *body, *extra])


def _contradictions_markdown(paper: dict[str, Any]) -> str:
    items = paper.get("contradictions", [])
    if not items:
        return ""
    out = ["## Where the paper contradicts itself", "",
           "Checked against the paper's LaTeX source (tests/test_paper_tex.py); each with the labels it "
           "rests on:", ""]
    out += [f"- {c['what']} [{', '.join(c['sources'])}]" for c in items]
    return "\n".join([*out, ""])


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
    rows = [comparable_metrics(r) if is_hybrid(r) else r for r in rows]  # rows kept before the split
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
