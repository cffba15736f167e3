"""Where an unfinished train run stands, read from its folders without loading any array.

A run whose seeds train in several groups (`hybrid.max_vmapped_seeds`: Ingolstadt's QMIX, a seed at
a time) takes many sessions; `urb-jax suite ENTRY --status` and a resuming suite say, a line per
group, how far each got (its newest checkpoint's meta.json, or its rounds.csv once finished) and,
at the pace measured so far, how long the rest takes here.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, NamedTuple, cast

import pandas as pd

from urb_jax.runs.folder import CONFIG_FILE, ROUNDS_FILE, run_status, seed_groups_of
from urb_jax.training.checkpoints import checkpoint_meta
from urb_jax.training.human_phase import HUMAN_FILE
from urb_jax.training.hybrid.clock import fmt_duration


def seed_groups(results_dir: Path, seeds: dict[str, int]) -> list[str]:
    """A line per group of seeds trained together, of the train run whose folders (under
    results_dir) and seeds are `seeds` (folder name -> seed): its rounds checkpointed of those
    planned, when the last was saved, and what the rounds left take at the pace of its rounds so
    far (a group not started: at the pace of the first group measured, where the groups are the
    same size); then the run's total left where there are several groups."""
    groups = [[g for g in group if g in seeds] or group  # the suite's seeds (an entry may list fewer now)
              for group in seed_groups_of(results_dir, list(seeds))]
    labels = ["seed" + ("s " if len(g) > 1 else " ") + ", ".join(str(seeds[n]) for n in g) for g in groups]
    paces = [p for label, g in zip(labels, groups, strict=True)
             if (p := _pace(results_dir, label, g)) is not None]
    lines, left = [], []
    for label, group in zip(labels, groups, strict=True):
        text, seconds = _group_progress(results_dir, group, paces[0] if paces else None)
        lines.append(f"{label}: {text}")
        left.append(seconds)
    if len(groups) > 1 and None not in left:
        known = cast("list[float]", left)  # no None in it
        lines.append(f"the run: about {fmt_duration(sum(known))} left, plus the test days")
    return lines


class _Pace(NamedTuple):
    """A group's measured rounds: whose, its seed count, seconds a round (surrogate leg and SUMO days),
    rounds planned."""

    label: str
    n_seeds: int
    per_round: float
    rounds: int


def _pace(results_dir: Path, label: str, group: list[str]) -> _Pace | None:
    """A group's pace from its rounds so far: a finished group's rounds.csv, else its checkpoint's
    rounds log (with the rounds planned, where the checkpoint records them); None where neither says."""
    rounds_csv = results_dir / group[0] / ROUNDS_FILE
    if run_status(results_dir / group[0]) == "done" and rounds_csv.is_file():
        rows = pd.read_csv(rounds_csv).to_dict("records")
        total = len(rows)
    else:
        meta = checkpoint_meta(results_dir / group[0])
        if meta is None or meta.get("rounds_total") is None or not meta["rounds"]:
            return None
        rows, total = meta["rounds"][0], meta["rounds_total"]
    return _Pace(label, len(group), _per_round(rows), total) if rows else None


def _per_round(rows: list[dict[str, Any]]) -> float:
    """Mean seconds a round (its surrogate leg and SUMO days) over rounds.csv rows; a leg a round
    did not run (a SUMO-only run's surrogate leg, a short last round without an iteration: missing,
    or NaN in rounds.csv) counts 0."""
    return sum(_seconds(row, "surrogate_s") + _seconds(row, "sumo_s") for row in rows) / len(rows)


def _seconds(row: dict[str, Any], key: str) -> float:
    """A leg's seconds in a rounds row; 0 where the round did not run the leg."""
    value = row.get(key)
    return 0.0 if value is None or value != value else float(value)  # value != value: NaN


def _group_progress(results_dir: Path, group: list[str], pace: _Pace | None) -> tuple[str, float | None]:
    """One group's line for `seed_groups` and the seconds its rounds left take (0 done, None
    unknown): at its own pace, or before its first round at `pace` (the run's first measured)."""
    first = results_dir / group[0]
    started = (first / CONFIG_FILE).is_file()
    if started and all(run_status(results_dir / name) == "done" for name in group):
        return "done", 0.0
    meta = checkpoint_meta(first) if started else None
    if meta is None:
        return _at_pace(_before_training(first), None, group, pace)
    done, total = meta["rounds_done"], meta.get("rounds_total")
    saved = time.strftime("%Y-%m-%d %H:%M", time.localtime(meta["saved_at"]))
    if total is None:  # a checkpoint written before meta.json recorded the plan
        return f"{done} rounds done, checkpoint saved {saved} (the checkpoint does not say of how many)", None
    text = f"{done} of {total} rounds done, checkpoint saved {saved}"
    if done == total:
        return text + "; the test days are left", 0.0
    rows = meta["rounds"][0] if meta["rounds"] else []
    if not rows:
        return _at_pace(text, total - done, group, pace)
    seconds = _per_round(rows) * (total - done)
    return (f"{text}; its rounds took {fmt_duration(_per_round(rows))} each here, so the {total - done} "
            f"left about {fmt_duration(seconds)}, then the test days"), seconds


def _before_training(first: Path) -> str:
    """A group without a round checkpoint, by its first folder."""
    if not (first / CONFIG_FILE).is_file():
        return "not started"
    if (first / HUMAN_FILE).is_file():
        return "no round checkpoint yet: its training starts from its saved human phase"
    return "no checkpoint yet: its human phase and calibration come first"


def _at_pace(text: str, left: int | None, group: list[str], pace: _Pace | None) -> tuple[str, float | None]:
    """`text` with the time its `left` rounds (None: all of them) take at `pace`, where the paced
    group has as many seeds; without such a pace, the time is unknown."""
    if pace is None or pace.n_seeds != len(group):
        return text, None
    n = pace.rounds if left is None else left
    seconds = pace.per_round * n
    what = f"its {n} rounds take" if left is None else f"the {n} left take"
    return (f"{text}; at the pace of {pace.label} {what} about {fmt_duration(seconds)}, then the test "
            "days"), seconds
