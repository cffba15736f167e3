"""The sample-efficiency curve: final SUMO t_CAV against the SUMO training days (and the wall time)
a run spent, for the hybrid trainer and for training every day in SUMO, St. Arnoult Scenario 1.

Reads finished runs under RESULTS: the `sample_efficiency` catalogue entry (hybrid runs with 0, 1,
4, 16 and 64 SUMO days a round) and the `scenario1_sumo` entry's SUMO-only runs, whose kept round
checkpoints `urb-jax snapshots` has tested (snapshots.csv in each run's first folder). Writes a
Markdown page and a figure; every number is in SUMO trip duration (the published tables' measure),
5 seeds, mean ± sample sd (ddof=1) with the 95% t-interval.

    urb-jax suite scenario1_sumo --networks-dir DIR; urb-jax suite sample_efficiency --networks-dir DIR
    urb-jax snapshots sumo_s1_saint_arnoult_iql_s0          (and _qmix_s0)
    python benchmarks/sample_efficiency.py --results-dir results --out docs/sample_efficiency.md
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from urb_jax.core.atomic import write_text
from urb_jax.reporting import verdicts as V  # noqa: N812
from urb_jax.reporting.paper import load_paper_numbers

ALGS = {"iql": "IQL", "qmix": "QMIX"}
HYBRID_TAGS = ("sur", "p1", "p4", "p16", "p64")
SEEDS = range(5)


@dataclass(frozen=True)
class Point:
    """One point of a curve: the runs (seeds) after the same training, their SUMO days and wall time."""

    label: str
    sumo_days: float
    wall_s: float
    t_cav: V.Sample
    wins: int

    def interval(self) -> tuple[float, float]:
        return V.welch(self.t_cav, V.Sample(0.0, 0.0, 1)).interval(0.95)


def hybrid_points(results: Path, alg: str) -> list[Point]:
    """The sample_efficiency runs of `alg` whose every seed is done, by SUMO training days."""
    points = []
    for tag in HYBRID_TAGS:
        folders = [results / f"se_saint_arnoult_{alg}_{tag}_s{s}" for s in SEEDS]
        configs = [_done_config(f) for f in folders]
        if None in configs:
            continue
        metrics = [pd.read_csv(f / "metrics" / "BenchmarkMetrics.csv").iloc[0] for f in folders]
        t_cav = [float(m["t_CAV_duration"]) for m in metrics]
        wins = sum(float(m["t_CAV_duration"]) < float(m["t_pre_duration"]) for m in metrics)
        days = sum(c["sumo_training_days"] for c in configs) / len(configs)
        wall = configs[0]["wall_time_s"]  # the seeds trained together: one wall time
        points.append(Point(f"hybrid, {tag}", days, wall, V.Sample.of(t_cav), wins))
    return sorted(points, key=lambda p: p.sumo_days)


def sumo_only_points(results: Path, alg: str) -> list[Point]:
    """The SUMO-only run's tested snapshots (snapshots.csv), one point per kept round."""
    path = results / f"sumo_s1_saint_arnoult_{alg}_s0" / "snapshots.csv"
    if not path.is_file():
        return []
    table = pd.read_csv(path)
    t_pre = [float(pd.read_csv(results / f"sumo_s1_saint_arnoult_{alg}_s{s}" / "metrics" /
                               "BenchmarkMetrics.csv").iloc[0]["t_pre_duration"]) for s in SEEDS]
    points = []
    for r, rows in table.groupby("round"):
        rows = rows.sort_values("seed")
        t_cav = rows["t_CAV_duration"].tolist()
        wins = sum(t < p for t, p in zip(t_cav, t_pre, strict=True))
        points.append(Point(f"SUMO only, round {r}", float(rows["sumo_training_days"].mean()),
                            float(rows["wall_s"].iloc[0]), V.Sample.of(t_cav), wins))
    return points


def _done_config(folder: Path) -> dict | None:
    path = folder / "exp_config.json"
    if not path.is_file():
        return None
    config = json.loads(path.read_text())
    return config if config.get("status") == "done" else None


def references(results: Path, alg: str) -> dict[str, float]:
    """t_pre (pre-CAV humans) and AON on the same humans, from the first finished run of `alg` (the
    SUMO-only run, else the default hybrid one: the same human phase), and the paper's t_CAV
    (tab:kpis)."""
    refs: dict[str, float] = {}
    for name in (f"sumo_s1_saint_arnoult_{alg}_s0", f"se_saint_arnoult_{alg}_p4_s0"):
        config = _done_config(results / name)
        if config is not None:
            refs["AON, same humans"] = config.get("aon_same_humans", {}).get("t_CAV_duration", float("nan"))
            metrics = pd.read_csv(results / name / "metrics" / "BenchmarkMetrics.csv").iloc[0]
            refs["t_pre (humans before the CAVs)"] = float(metrics["t_pre_duration"])
            break
    table = next(t for t in load_paper_numbers()["entries"]["scenario1"]["tables"]
                 if t["network"] == "saint_arnoult")
    refs["paper (tab:kpis)"] = table["rows"][alg]["values"]["t_CAV"]
    return refs


MARGIN = 0.01  # min: "at the final level" means within ±0.6 s of it (TOST, 90% interval)


def answers(alg: str, series: dict[str, list[Point]]) -> list[str]:
    """The page's two questions, per algorithm, against SUMO only's final point (6,000 training days
    in SUMO): the fewest SUMO days at which each curve is at that level (Welch TOST within ±MARGIN,
    or significantly below it), and the hybrid runs (all 6,000 training days) that end significantly
    above it (Welch, one-sided 5%)."""
    sumo, hybrid = series["SUMO only"], series["hybrid"]
    if not sumo:
        return []
    final = sumo[-1]

    def at_level(p: Point) -> bool:
        d = V.welch(p.t_cav, final.t_cav)
        return V.equivalence(d, MARGIN).kind == V.HOLDS or (d.diff < 0 and d.p_less() < 0.05)

    def worse(p: Point) -> str | None:
        d = V.welch(p.t_cav, final.t_cav)
        return f"{p.label} ({d.diff:+.4f}, p = {d.p_greater():.3f})" if d.p_greater() < 0.05 else None

    def first(points: list[Point]) -> str:
        hit = next((p for p in points if at_level(p)), None)
        return "never" if hit is None else f"{hit.sumo_days:,.0f} SUMO days ({_wall(hit.wall_s)})"

    bad = [w for p in hybrid if (w := worse(p))]
    return [f"**{ALGS[alg]}**: SUMO only ends at {final.t_cav.mean:.4f} after {final.sumo_days:,.0f} SUMO "
            f"days ({_wall(final.wall_s)}). At that level (within ±{MARGIN} min, Welch TOST, or below it): "
            f"SUMO only from {first(sumo)}, the hybrid from {first(hybrid)}. Hybrid runs that end "
            f"significantly above it: {', '.join(bad) if bad else 'none'}.", ""]


def table_markdown(alg: str, points: list[Point], refs: dict[str, float]) -> list[str]:
    out = [f"## {ALGS[alg]}", "",
           "| run | SUMO training days | wall time | t_CAV (duration, min) | 95% interval | WR |",
           "|---|---|---|---|---|---|"]
    for p in points:
        lo, hi = p.interval()
        out.append(f"| {p.label} | {p.sumo_days:,.0f} | {_wall(p.wall_s)} | {p.t_cav.mean:.4f} ± "
                   f"{p.t_cav.sd:.4f} ({p.t_cav.n}) | [{lo:.4f}, {hi:.4f}] | {p.wins}/{p.t_cav.n} |")
    out += ["", "References: " + "; ".join(f"{k} {v:.4f}" for k, v in refs.items()) + ".", ""]
    return out


def _wall(seconds: float) -> str:
    if seconds != seconds:  # NaN: not recorded
        return "n/a"
    return f"{seconds / 60:.1f} min" if seconds < 7200 else f"{seconds / 3600:.2f} h"


def plot(curves: dict[str, dict[str, list[Point]]], refs: dict[str, dict[str, float]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(curves), 2, figsize=(11, 4.2 * len(curves)), squeeze=False)
    for row, (alg, series) in enumerate(curves.items()):
        for col, (x_of, xlabel) in enumerate(((lambda p: p.sumo_days, "SUMO training days (per seed)"),
                                              (lambda p: p.wall_s, "wall time of the 5 seeds (s)"))):
            ax = axes[row][col]
            for (name, points), style in zip(series.items(), ("o-", "s--"), strict=False):
                pts = [p for p in points if x_of(p) == x_of(p) and (col == 0 or x_of(p) > 0)]
                if not pts:
                    continue
                xs = [max(x_of(p), 1.0) for p in pts]
                ys = [p.t_cav.mean for p in pts]
                err = [[y - p.interval()[0] for y, p in zip(ys, pts, strict=True)],
                       [p.interval()[1] - y for y, p in zip(ys, pts, strict=True)]]
                ax.errorbar(xs, ys, yerr=err, fmt=style, capsize=3, label=name)
            for (name, value), color in zip(refs[alg].items(), ("grey", "black", "tab:red"), strict=False):
                ax.axhline(value, color=color, linestyle=":", linewidth=1, label=name)
            ax.set_xscale("log")
            ax.set_xlabel(xlabel + (" (0 drawn at 1)" if col == 0 else ""))
            ax.set_ylabel("t_CAV, SUMO duration (min)")
            ax.set_title(f"{ALGS[alg]}, St. Arnoult: 95% intervals over 5 seeds")
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results-dir", default="results")
    ap.add_argument("--out", default="docs/sample_efficiency.md")
    args = ap.parse_args()
    results, out = Path(args.results_dir), Path(args.out)
    figure = out.with_suffix(".png")
    curves: dict[str, dict[str, list[Point]]] = {}
    refs = {}
    body, summary = [], []
    for alg in ALGS:
        series = {"hybrid": hybrid_points(results, alg), "SUMO only": sumo_only_points(results, alg)}
        if not any(series.values()):
            body += [f"## {ALGS[alg]}", "", "Not run yet.", ""]
            continue
        curves[alg], refs[alg] = series, references(results, alg)
        summary += answers(alg, series)
        points = sorted([*series["SUMO only"], *series["hybrid"]], key=lambda p: (p.sumo_days, p.label))
        body += table_markdown(alg, points, refs[alg])
    if curves:
        plot(curves, refs, figure)
    rel = results.as_posix()  # as given: run it from where the results folder is `results`
    head = ["# Sample efficiency: what a SUMO training day buys", "",
            f"Generated by `python benchmarks/sample_efficiency.py --results-dir {rel}` from the finished "
            "runs of the `sample_efficiency` entry (hybrid: the SUMO days a round varied, the rest of "
            "the 6,000 training days on the surrogate) and the `scenario1_sumo` entry (every training "
            "day in SUMO; its kept checkpoints tested with `urb-jax snapshots`, the same test days and "
            "keys as the run's own test). St. Arnoult, Scenario 1, URB's algorithm config1 (task config1 "
            "for IQL, config2 for QMIX), 5 seeds; t_CAV in SUMO trip duration, mean ± sample sd (seeds), "
            "95% t-interval; WR: seeds whose CAVs beat their t_pre. Wall time: what each run recorded for "
            "its 5 seeds trained together on this machine (2 CPU cores, shared with other work); a SUMO-only "
            "snapshot's is the run's wall time when that checkpoint was saved; a hybrid run that reused "
            "another run's human phase did not simulate it.", "",
            f"![sample efficiency]({figure.name})", ""]
    write_text(out, "\n".join([*head, *summary, *body]))
    print(f"-> {out}, {figure}")


if __name__ == "__main__":
    main()
