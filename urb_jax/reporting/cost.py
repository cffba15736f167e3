"""What the paper's runs cost next to what ours cost for the same experiment (docs/paper.md).

The paper times four experiments (`tab:comp_time`: 200 human and 6,000 training days, all in SUMO,
test phase omitted; the AON baseline's 200 human and 300 baseline days) on its hardware
(`tab:hardware`). Ours are the same experiments' runs of the catalogue entries that
configs/paper/urb_paper.json's `compute.ours` names (the hybrid trainer's, and the SUMO-only
control's): each run's recorded wall time (exp_config.json's `wall_time_s`, kept in the ledger's
provenance) with what it computed (its SUMO and surrogate training days) and the machine it ran on.
Seeds trained together in one program record the group's wall time on every seed, so the table
gives the group's wall and its share per seed, and the mean over seeds of that share.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from urb_jax.reporting.provenance import NOT_RECORDED
from urb_jax.reporting.train_days import days_cell

HOUR = 3600.0


@dataclass(frozen=True)
class Group:
    """Seeds of one run trained in one program: their names (sorted) and the wall seconds recorded."""

    seeds: tuple[str, ...]
    wall_s: float

    @property
    def per_seed_s(self) -> float:
        return self.wall_s / len(self.seeds)


@dataclass(frozen=True)
class OurCost:
    """Our runs of one paper row from one catalogue entry: their groups, the runs without a recorded
    wall time, what they trained and where."""

    entry: str
    what: str  # 'hybrid', 'SUMO only'
    seeds: int
    groups: tuple[Group, ...]
    shares_s: tuple[float, ...]  # each seed's share of its group's wall, seeds with a wall time
    unrecorded: int  # seeds without a recorded wall time
    days: str
    hardware: str

    @property
    def mean_per_seed_h(self) -> float | None:
        """The mean over the seeds with a wall time of each seed's share of its group's wall."""
        return float(np.mean(self.shares_s)) / HOUR if self.shares_s else None


def _prov(row: dict[str, Any]) -> dict[str, Any]:
    prov = row.get("provenance")
    return prov if isinstance(prov, dict) else {}


def _wall(row: dict[str, Any]) -> float | None:
    wall = _prov(row).get("wall_time_s")
    return float(wall) if isinstance(wall, int | float) else None


def groups_of(rows: pd.DataFrame) -> tuple[tuple[Group, ...], tuple[float, ...], int]:
    """The seed groups of `rows` (seeds trained together, from the provenance; a seed alone where it
    is not recorded) with their wall seconds, each row's share of its group's wall (seconds), and
    how many rows record no wall time."""
    groups: dict[tuple[str, ...], float] = {}
    shares: list[float] = []
    for row in rows.to_dict("records"):
        wall = _wall(row)
        if wall is None:
            continue
        together = _prov(row).get("seeds_trained_together")
        names = tuple(sorted(together)) if isinstance(together, list) and together else (str(row["exp_id"]),)
        groups.setdefault(names, wall)
        shares.append(wall / len(names))
    found = tuple(Group(k, w) for k, w in sorted(groups.items()))
    return found, tuple(shares), len(rows) - len(shares)


def hardware_of(rows: pd.DataFrame) -> str:
    """The distinct machines of `rows` as their provenance records them: CPU, cores, backend and
    device ('not recorded' where a row has none)."""
    seen: list[str] = []
    for row in rows.to_dict("records"):
        m = _prov(row).get("machine")
        if not isinstance(m, dict):
            text = NOT_RECORDED
        else:
            device = m.get("device")
            gpu = f", device {device}" if device and device != "cpu" else ", no GPU used"
            cores = f"{m.get('cpu_count', '?')} cores"
            text = f"{m.get('cpu', '?')}, {cores}, backend {m.get('backend', '?')}{gpu}"
        if text not in seen:
            seen.append(text)
    return "; ".join(seen) or NOT_RECORDED


def our_cost(entry: str, what: str, rows: pd.DataFrame) -> OurCost:
    """An OurCost of one paper row's runs from `entry`."""
    groups, shares, unrecorded = groups_of(rows)
    return OurCost(entry, what, len(rows), groups, shares, unrecorded, days_cell(rows), hardware_of(rows))


def matching_runs(runs: pd.DataFrame, network: str, algorithm: str) -> pd.DataFrame:
    """`runs`' rows of a paper row: its network and algorithm (urb-jax's id, a baseline without
    'baseline_'), sorted by run id."""
    if runs.empty or "network" not in runs:
        return runs.iloc[:0]
    algs = runs.get("alg", runs["algorithm"])
    ids = pd.Series([_row_key(a, b) for a, b in zip(algs, runs["algorithm"], strict=True)], index=runs.index)
    return runs[(runs["network"] == network) & (ids == algorithm)].sort_values("exp_id")


def _row_key(alg: Any, algorithm: Any) -> str:
    """urb-jax's id (URB's name where a run has none), a baseline's without 'baseline_'."""
    name = alg if isinstance(alg, str) and alg else algorithm
    return str(name).removeprefix("baseline_")


def _hours(seconds: float) -> str:
    return f"{seconds / HOUR:.2f}"


def wall_cell(cost: OurCost) -> str:
    """'group of 5 seeds trained together: 3.19 h (0.64 h per seed)', one per group; single seeds
    as 'run: 1.20 h'; and how many seeds record no wall time."""
    parts = []
    for g in cost.groups:
        if len(g.seeds) > 1:
            parts.append(f"{len(g.seeds)} seeds trained together: {_hours(g.wall_s)} h "
                         f"({_hours(g.per_seed_s)} h per seed)")
        else:
            parts.append(f"`{g.seeds[0]}`: {_hours(g.wall_s)} h")
    if cost.unrecorded:
        parts.append(f"{cost.unrecorded} seed(s): wall time {NOT_RECORDED}")
    return "; ".join(parts) or NOT_RECORDED


PAPER_DAYS = {"aon": "200 human + 300 baseline days, all in SUMO"}
PAPER_TRAIN = "200 human + 6,000 training days, all in SUMO (test phase omitted)"


def cost_markdown(compute: dict[str, Any], all_runs: dict[str, pd.DataFrame], names: dict[str, str]) -> str:
    """The section: per paper row its hours and, under it, ours from each entry `compute.ours` names."""
    hw = compute["hardware"]
    paper_hw = f"{hw['CPU']}; {hw['GPU']}; {hw['RAM']}; SUMO {hw['SUMO version']} [{hw['source']}]"
    out = ["## What the paper's runs cost, and ours", "",
           f"The paper: \"{compute['caption']}\" [{compute['source']}], on {paper_hw}. Ours: the same "
           "experiment (network, algorithm, 200 human and 6,000 asked training days) from "
           + ", ".join(f"`{o['entry']}` ({o['what']})" for o in compute.get("ours", []))
           + ": each run's recorded wall time (exp_config.json), which covers the whole run, the human "
           "phase (or its reuse from an earlier run), training and the 100 test days, while the paper's "
           "omits the test phase. Seeds trained together in one program record the group's wall time: "
           "the table gives the group's and its share per seed; \"mean\" is the mean over seeds of that "
           "share. Hardware is what each run's provenance records.", "",
           "| network | algorithm | side | days computed | hardware | wall time | mean per seed (h) |",
           "|---|---|---|---|---|---|---|"]
    for r in compute["runs"]:
        alg = names.get(r["algorithm"], r["algorithm"])
        days = PAPER_DAYS.get(r["algorithm"], PAPER_TRAIN)
        out.append(f"| {r['network']} | {alg} | paper [{compute['source']}] | {days} | "
                   f"{hw['CPU']}; {hw['GPU']} [{hw['source']}] | ~{r['hours']:g} h | ~{r['hours']:g} |")
        for o in compute.get("ours", []):
            rows = matching_runs(all_runs.get(o["entry"], pd.DataFrame()), r["network"], r["algorithm"])
            if rows.empty:
                out.append(f"| | | ours, `{o['entry']}` ({o['what']}) | not run yet | | | |")
                continue
            c = our_cost(o["entry"], o["what"], rows)
            mean = "n/a" if c.mean_per_seed_h is None else f"{c.mean_per_seed_h:.2f}"
            out.append(f"| | | ours, `{c.entry}` ({c.what}), {c.seeds} seed(s) | {c.days} | {c.hardware} | "
                       f"{wall_cell(c)} | {mean} |")
    return "\n".join([*out, ""])
