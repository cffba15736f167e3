"""The URB paper's travel-time figures for the paper page: t/t_pre of CAVs and humans over the days.

The paper's `fig:travel_times_1` (Scenario 1, per network) and `fig:travel_times_2` (Scenario 2)
draw, per algorithm, the mean over five seeds of the CAVs' travel time over the pre-CAV human mean
(t/t_pre) on every day, with a 95% interval band, smoothed by a moving average of 150 days, the
humans' mean over all runs of the network as an orange dashed line, and the phases as patches.

A hybrid run's days are of two kinds. Its SUMO days are recorded per agent (records.parquet: the
human phase, its SUMO training days and the test days); its surrogate days are not, only each
round's mean predicted travel time over its surrogate days (rounds.csv: `sur_time_cav`,
`sur_time_hdv`). So the SUMO days are drawn as curves at their place among the training days (a
round is its surrogate days, then its SUMO days: `training.hybrid.trainer`), and the surrogate days
as dotted steps, one per round over the days it spans: what is recorded, nothing interpolated.
The moving average runs over the days of the axis (a trailing window of `window` days, within a
phase): over a SUMO-only run's days it is the paper's average; over a hybrid run's few SUMO days per
round it averages those of the window's round(s). The data functions are separate from the drawing
so that the tests check the numbers, not pixels.
"""

from __future__ import annotations

import io
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from urb_jax.core.atomic import write_bytes
from urb_jax.core.errors import UrbJaxError
from urb_jax.reporting.drift import ROUNDS_FILE
from urb_jax.reporting.records import read_records
from urb_jax.reporting.verdicts import t_ppf

GROUPS = ("CAV", "HDV")
SURROGATE = {"CAV": "sur_time_cav", "HDV": "sur_time_hdv"}
PREFIX = "travel_times_"  # the figures' file names: travel_times_<network>.png


@dataclass(frozen=True)
class Schedule:
    """A run's days in order: the human phase, then per round its surrogate days and then its SUMO
    days (rounds.csv), then the test days."""

    human_days: int
    rounds: tuple[tuple[int, int], ...]  # (surrogate days, SUMO days) per round

    @property
    def training_days(self) -> int:
        return sum(s + u for s, u in self.rounds)

    def sumo_positions(self) -> np.ndarray:
        """The day (1-based, human days first) of each SUMO training day, in order."""
        out: list[int] = []
        start = self.human_days
        for sur, sumo in self.rounds:
            out += range(start + sur + 1, start + sur + sumo + 1)
            start += sur + sumo
        return np.asarray(out, dtype=int)

    def surrogate_spans(self) -> list[tuple[int, int] | None]:
        """Each round's first and last surrogate day; None for a round without surrogate days."""
        out: list[tuple[int, int] | None] = []
        start = self.human_days
        for sur, sumo in self.rounds:
            out.append((start + 1, start + sur) if sur else None)
            start += sur + sumo
        return out


def schedule_of(cfg: dict, rounds: pd.DataFrame | None) -> Schedule:
    """A run's Schedule from its exp_config.json and rounds.csv (one round of its recorded days where
    rounds.csv is absent)."""
    human = int(cfg.get("human_days", 0))
    if rounds is None or rounds.empty:
        return Schedule(human, ((int(cfg.get("surrogate_training_days") or 0),
                                 int(cfg.get("sumo_training_days") or cfg.get("training_days") or 0)),))
    col = {c: rounds[c].fillna(0).astype(int) if c in rounds else pd.Series(0, index=rounds.index)
           for c in ("surrogate_days", "sumo_days")}
    return Schedule(human, tuple(zip(col["surrogate_days"], col["sumo_days"], strict=True)))


def seed_days(records: pd.DataFrame, t_pre: float, schedule: Schedule) -> pd.DataFrame:
    """One seed's recorded days: `x` (its day on the axis: human days, then the training days in the
    schedule's order, then the test days), `phase`, and the mean travel time over t_pre of its CAVs
    and its humans (agents by their kind on the last day: the paper's groups)."""
    last = records["day"].max()
    final = records[records["day"] == last].set_index("agent")["kind"]
    rec = records.assign(group=records["agent"].map(final))
    per_day = rec.groupby(["day", "group"])["travel_time"].mean().unstack().reindex(columns=list(GROUPS))
    phase = rec.groupby("day")["phase"].first()
    days = per_day.index.to_numpy()
    x = days.astype(int).copy()
    train = (phase == "train").to_numpy()
    positions = schedule.sumo_positions()
    if train.sum() != len(positions):
        raise ValueError(f"{int(train.sum())} SUMO training days recorded, {len(positions)} in its rounds")
    x[train] = positions
    test = (phase == "test").to_numpy()
    if test.any():
        first = days[test].min()
        x[test] = schedule.human_days + schedule.training_days + (days[test] - first) + 1
    out = pd.DataFrame({"x": x, "phase": phase.to_numpy()})
    for g in GROUPS:
        out[g] = per_day[g].to_numpy(dtype=float) / t_pre
    return out.sort_values("x").reset_index(drop=True)


def moving_average(x: np.ndarray, y: np.ndarray, window: int) -> np.ndarray:
    """At each point, the mean of the points whose x lies in its trailing window (x - window, x]
    (NaN points left out). On consecutive days it is numpy's convolution with a window of `window`
    ones over `window` once `window` days are in (fewer at the start)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    ok = ~np.isnan(y)
    sums = np.concatenate([[0.0], np.cumsum(np.where(ok, y, 0.0))])
    counts = np.concatenate([[0], np.cumsum(ok)])
    lo = np.searchsorted(x, x - window, side="right")
    hi = np.arange(1, len(x) + 1)
    n = counts[hi] - counts[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (sums[hi] - sums[lo]) / np.maximum(n, 1), np.nan)


def smooth(days: pd.DataFrame, window: int) -> pd.DataFrame:
    """`seed_days` with each group's moving average taken within each phase (the phases' edges,
    the mutation and the test, stay sharp)."""
    out = days.copy()
    for _, idx in days.groupby("phase", sort=False).groups.items():
        part = days.loc[idx]
        for g in GROUPS:
            out.loc[idx, g] = moving_average(part["x"].to_numpy(), part[g].to_numpy(), window)
    return out


@dataclass(frozen=True)
class Band:
    """A curve over seeds: per x the mean and its 95% t-interval (lo = hi = mean for one seed)."""

    x: np.ndarray
    mean: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    seeds: int


def seed_band(seeds: list[pd.DataFrame], group: str) -> Band:
    """The mean of `group` over `seeds` (their `seed_days`, smoothed or not) at the days all of them
    recorded, with the 95% t-interval of the mean (sample std, n-1)."""
    table = pd.concat([s.set_index("x")[group].rename(i) for i, s in enumerate(seeds)], axis=1, join="inner")
    values = table.to_numpy(dtype=float)
    mean = values.mean(axis=1)
    n = values.shape[1]
    if n < 2:
        return Band(table.index.to_numpy(), mean, mean, mean, n)
    half = t_ppf(0.975, n - 1) * values.std(axis=1, ddof=1) / math.sqrt(n)
    return Band(table.index.to_numpy(), mean, mean - half, mean + half, n)


def surrogate_steps(rounds: list[pd.DataFrame], t_pres: list[float], schedule: Schedule,
                    group: str) -> list[tuple[int, int, float]]:
    """Per round with surrogate days: (first day, last day, the seeds' mean of the round's mean
    predicted travel time over t_pre), from each seed's rounds.csv; empty where not recorded."""
    col = SURROGATE[group]
    if not rounds or any(col not in r for r in rounds):
        return []
    values = np.mean([r[col].to_numpy(dtype=float) / t for r, t in zip(rounds, t_pres, strict=True)], axis=0)
    spans = schedule.surrogate_spans()
    return [(s[0], s[1], float(v)) for s, v in zip(spans, values, strict=False)
            if s is not None and not math.isnan(v)]


@dataclass(frozen=True)
class RunDays:
    """One seed of a run, read for the figure: its network, algorithm label, schedule, smoothed
    days, rounds.csv (None where absent) and t_pre."""

    network: str
    label: str
    schedule: Schedule
    days: pd.DataFrame
    rounds: pd.DataFrame | None
    t_pre: float


def read_run(folder: Path, window: int) -> RunDays:
    """A finished train run's folder as RunDays (records: day, phase, agent, kind, travel_time)."""
    cfg = json.loads((folder / "exp_config.json").read_text())
    t_pre = float(pd.read_csv(folder / "metrics" / "BenchmarkMetrics.csv")["t_pre"].iloc[0])
    rounds_file = folder / ROUNDS_FILE
    rounds = pd.read_csv(rounds_file) if rounds_file.is_file() else None
    schedule = schedule_of(cfg, rounds)
    records = read_records(folder, columns=["day", "phase", "agent", "kind", "travel_time"])
    days = smooth(seed_days(records, t_pre, schedule), window)
    label = str(cfg.get("alg") or cfg.get("algorithm"))
    return RunDays(str(cfg.get("network")), label, schedule, days, rounds, t_pre)


def humans_mean(runs: list[RunDays]) -> pd.Series:
    """The humans' t/t_pre per day averaged over every seed of every run on the network (the paper's
    orange line: 'averaged over all experiments in that instance'), days where any seed recorded."""
    parts = [r.days.set_index("x")["HDV"] for r in runs]
    return pd.concat(parts).groupby(level=0).mean().dropna()


def gapped(x: np.ndarray, *ys: np.ndarray) -> tuple[np.ndarray, ...]:
    """x and ys with a NaN point inserted after each day not followed by the next day: a line is
    not drawn across the surrogate days between two rounds' SUMO days (nothing was recorded there)."""
    x = np.asarray(x, dtype=float)
    breaks = np.flatnonzero(np.diff(x) > 1) + 1
    ys_out = (np.insert(np.asarray(y, dtype=float), breaks, np.nan) for y in ys)
    return (np.insert(x, breaks, np.nan), *ys_out)


def _colors() -> list[str]:
    return ["tab:blue", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive",
            "tab:cyan", "tab:gray"]  # no orange: the humans' colour, as in the paper


def draw_network(network: str, runs: list[RunDays], path: Path, title: str) -> Path:
    """One network's figure: per algorithm its CAVs' band and surrogate steps, the humans' mean,
    the phases as patches."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4.8))
    H = max(r.schedule.human_days for r in runs)
    T = max(r.schedule.training_days for r in runs)
    last = max(float(r.days["x"].max()) for r in runs)
    for start, end, name, color in ((0.5, H + 0.5, "human phase", "#e8f0fe"),
                                    (H + 0.5, H + T + 0.5, "training", "#fff4e0"),
                                    (H + T + 0.5, last + 0.5, "test", "#e6f4ea")):
        if end > start:
            ax.axvspan(start, end, color=color, label=name, zorder=0)
    labels = sorted({r.label for r in runs})
    for label, color in zip(labels, _colors(), strict=False):
        seeds = [r for r in runs if r.label == label]
        band = seed_band([r.days for r in seeds], "CAV")
        x, mean, lo, hi = gapped(band.x, band.mean, band.lo, band.hi)
        ax.plot(x, mean, color=color, lw=1.2, marker="." if len(x) > len(band.x) else None, ms=2,
                label=f"{label} CAVs, SUMO days ({band.seeds} seeds)")
        ax.fill_between(x, lo, hi, color=color, alpha=0.2, lw=0)
        steps = surrogate_steps([r.rounds for r in seeds if r.rounds is not None],
                                [r.t_pre for r in seeds if r.rounds is not None], seeds[0].schedule, "CAV")
        if steps:
            ax.hlines([s[2] for s in steps], [s[0] for s in steps], [s[1] for s in steps], colors=color,
                      linestyles=":", lw=2.0, label=f"{label} CAVs, surrogate (round means)")
    humans = humans_mean(runs)
    if not humans.empty:
        hx, hy = gapped(humans.index.to_numpy(), humans.to_numpy())
        ax.plot(hx, hy, color="tab:orange", ls="--", lw=1.2, label="humans, SUMO days (all runs)")
    ax.axhline(1.0, color="black", lw=0.6, alpha=0.5)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("day (human phase, training days: surrogate and SUMO, test)")
    ax.set_ylabel("t / t_pre")
    ax.legend(fontsize=7, loc="best", ncol=2)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    write_bytes(path, buf.getvalue())  # atomically: a page never links half a figure
    return path


@dataclass(frozen=True)
class NetworkFigure:
    """One network's figure on the page: its file (relative to the page) or why there is none."""

    network: str
    link: str | None
    note: str


def is_train_run(folder: Path) -> bool:
    """A train run (it has training days and rounds), not a baseline."""
    cfg = json.loads((folder / "exp_config.json").read_text())
    return bool(cfg.get("train_args")) and not str(cfg.get("script", "")).startswith("urb-jax baseline")


def network_figures(entry: str, networks: list[str], folders: list[Path], out_dir: Path, page_dir: Path,
                    window: int) -> tuple[NetworkFigure, ...]:
    """Per network of the entry, its figure drawn into out_dir from the train runs among `folders`
    (the entry's finished runs under the results folder), linked relative to the page; a network
    with none of them keeps a figure an earlier generation drew (said so) or says why there is none."""
    runs, unread = [], []
    for folder in (f for f in folders if is_train_run(f)):
        try:
            runs.append(read_run(folder, window))
        except (UrbJaxError, OSError, ValueError, KeyError) as exc:  # one bad run: its curve, not the page
            unread.append(f"`{folder.name}` ({type(exc).__name__})")  # its message may name local paths
    out = []
    for net in networks:
        mine = [r for r in runs if r.network == net]
        path = out_dir / f"{PREFIX}{net}.png"
        if mine:
            n = len({r.label for r in mine})
            title = (f"{entry}, {net}: t/t_pre per day, {n} algorithm(s), mean over seeds, 95% band, "
                     f"moving average {window}")
            link = Path(os.path.relpath(draw_network(net, mine, path, title), page_dir)).as_posix()
            note = f"drawn from {len(mine)} seed run(s) under the results folder"
            out.append(NetworkFigure(net, link, note))
        elif path.is_file():
            link = Path(os.path.relpath(path, page_dir)).as_posix()
            out.append(NetworkFigure(net, link, "drawn by an earlier generation (its runs are not under "
                                                "this results folder)"))
        else:
            out.append(NetworkFigure(net, None, "not drawn: none of its train runs is under the results "
                                                "folder (the figure needs their day records; the ledger "
                                                "keeps metrics only)"))
    if unread:
        out.append(NetworkFigure("(left out)", None, "runs whose day records or rounds could not be read: "
                                 + "; ".join(sorted(unread))))
    return tuple(out)
