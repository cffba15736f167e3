"""An experiment suite's results in the paper's layout: one table per (network, task) with a row per
algorithm (mean ± sample std over seeds, both trip measures), each trained run against the humans
and the baselines (`baseline_comparisons`), and one figure per row group: the mean
travel time of CAVs, humans and everyone over the days, averaged over seeds, with the phases as
background patches, as the URB paper's figures show them."""

from __future__ import annotations

import json
import textwrap
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd

from urb_jax.reporting.drift import ERROR_COLUMN, ROUNDS_FILE, TRUSTED, late_day_error
from urb_jax.reporting.leaderboard import KEYS, aggregate, collect_folders
from urb_jax.reporting.records import plot_phases, read_records
from urb_jax.reporting.train_days import LEGEND, days_cell
from urb_jax.reporting.urb_names import overrides_of, with_overrides
from urb_jax.reporting.verdicts import Sample, order, paired, welch

TABLE_COLUMNS = [("t_pre", "t_pre"), ("t_CAV", "t_CAV"), ("t_HDV_test", "t_HDV"), ("t_test", "t_all"),
                 ("cost_of_learning", "c_all"), ("delta_V", "ΔV"), ("delta_L", "ΔL"),
                 ("t_pre_duration", "t_pre (dur.)"), ("t_CAV_duration", "t_CAV (dur.)")]


def runs_tables(runs: pd.DataFrame) -> str:
    """Markdown: a table per (network, task config), a row per algorithm, mean ± sample std over seeds,
    of runs read by `collect_folders` (or a ledger's rows)."""
    if runs.empty:
        return ""
    table = aggregate(runs)
    seeds = dict(iter(runs.groupby(KEYS, sort=True)))
    out = []
    for (net, task), g in table.groupby(["network", "task_config"], sort=True):
        out.append(f"### {net}, task {task}\n")
        head = ["algorithm", "seeds", "training days", "WR %", *[name for _, name in TABLE_COLUMNS]]
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        names = [run_label(r) for _, r in g.iterrows()]
        for (_, r), name in zip(g.iterrows(), names, strict=True):
            if names.count(name) > 1:  # e.g. one algorithm with two configs or trainers: say which
                name = qualified_label(r)
            days = days_cell(seeds[tuple(r[k] for k in KEYS)])
            cells = [name, str(int(r["runs"])), days, _num(r.get("WR"), 0)]
            for col, _ in TABLE_COLUMNS:
                mean, std = r.get(f"{col}_mean", np.nan), r.get(f"{col}_std", np.nan)
                cells.append(_num(mean) + (f" ± {std:.4f}" if r["runs"] > 1 and std == std else ""))
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join([*out, LEGEND, ""])


BASELINE_PREFIX = "baseline_"
AGAINST = (("t_pre", "the humans before (t_pre)"), ("baseline_aon", "AON"), ("baseline_random", "random"))
AGAINST_TEXT = (
    "Each trained run's t_CAV (travel time, per seed) against what its CAVs could have had instead: the "
    "humans' own mean before the CAVs came (t_pre; per-seed differences, a one-sample t-test) and the "
    "AON and random baselines of the same network and task (each one run, counted as a constant; "
    "Welch's t-test). **lower** / **higher**: significant at 5% two-sided; **tie**: the difference is "
    "inside the seeds' spread. Differences in minutes with their 95% t-interval. The surrogate's late "
    "day error: how far the surrogate the policies trained on predicted the run's own SUMO training "
    "days in the last half of its rounds (rounds.csv `surrogate_mean_error`, mean over seeds); beyond "
    f"±{TRUSTED:.0%} the surrogate did not follow the network and the result rests on the SUMO days.")


def baseline_comparisons(runs: pd.DataFrame) -> str:
    """Markdown: a row per trained run (its seeds) of each (network, task) with baselines, its t_CAV
    against t_pre, AON's and random's, each a verdict (`verdicts.order`); "" where there is none."""
    if runs.empty or "t_CAV" not in runs:
        return ""
    head = ["network, task", "run", "seeds", "t_CAV", "surrogate's late day error",
            *[name for _, name in AGAINST]]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    labels = run_labels(runs)
    for (net, task), group in runs.groupby(["network", "task_config"], sort=True):
        alg = group["alg"].fillna("").astype(str)
        base = {name: pd.to_numeric(g["t_CAV"], errors="coerce").dropna().tolist()
                for name, g in group[alg.str.startswith(BASELINE_PREFIX)].groupby(alg)}
        for key, seeds in group[~alg.str.startswith(BASELINE_PREFIX)].groupby(KEYS, sort=True):
            t_cav = pd.to_numeric(seeds["t_CAV"], errors="coerce").tolist()
            cells = [f"{net}, {task}", labels[key], str(len(seeds)), _mean_sd(t_cav),
                     _late_error(seeds)]
            for against, _ in AGAINST:
                cells.append(_against(t_cav, seeds, against, base))
            out.append("| " + " | ".join(cells) + " |")
    return "\n".join([AGAINST_TEXT, "", *out]) if len(out) > 2 else ""


def _late_error(seeds: pd.DataFrame) -> str:
    """The seeds' mean late day error of the surrogate (`drift.late_day_error` of each rounds.csv)."""
    errors = []
    for folder in seeds.get("folder", pd.Series(dtype=str)):
        rounds = Path(folder) / ROUNDS_FILE
        if rounds.is_file():
            table = pd.read_csv(rounds)
            if ERROR_COLUMN in table and (e := late_day_error(table[ERROR_COLUMN].tolist())) is not None:
                errors.append(e)
    if not errors:
        return "n/a"
    mean = sum(errors) / len(errors)
    return f"{mean:+.1%}" + (f", beyond ±{TRUSTED:.0%}" if abs(mean) > TRUSTED else "")


def _against(t_cav: list[float], seeds: pd.DataFrame, against: str, base: dict[str, list[float]]) -> str:
    if against == "t_pre":
        d = paired(t_cav, pd.to_numeric(seeds["t_pre"], errors="coerce").tolist())
    elif base.get(against):
        d = welch(Sample.of(t_cav), Sample.of(base[against]))
    else:
        return "not run"
    verdict = order(d)
    return f"**{verdict.kind}** {verdict.detail}"


def _mean_sd(values: list[float]) -> str:
    sample = Sample.of(values)
    return f"{sample.mean:.4f}" + (f" ± {sample.sd:.4f}" if sample.n > 1 else "")


def wall_times_table(folders: list[Path]) -> str:
    """Markdown: each run's wall time on the machine that made it (a row per network and run, seeds
    trained together counted once: they share one wall time), with the human phase's share."""
    rows: dict[tuple[str, str], dict] = {}
    for folder in folders:
        config = json.loads((folder / "exp_config.json").read_text())
        run = str(config.get("alg") or config.get("algorithm"))  # with its --set items: another run
        key = (str(config.get("network")), with_overrides(run, overrides_of(config)))
        row = rows.setdefault(key, {"seeds": 0, "wall": 0.0, "human": None})
        row["seeds"] += 1
        row["wall"] = max(row["wall"], float(config.get("wall_time_s") or 0.0))
        if config.get("human_phase_s") is not None:
            row["human"] = float(config["human_phase_s"])
    out = ["| network | run | seeds | wall time | of which the human phase |", "|---|---|---|---|---|"]
    for (net, run), r in sorted(rows.items()):
        human = "" if r["human"] is None else _duration(r["human"])
        out.append(f"| {net} | {run} | {r['seeds']} | {_duration(r['wall'])} | {human} |")
    return "\n".join(out)


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 600 else f"{seconds / 60:.1f} min"


def run_labels(runs: pd.DataFrame) -> dict[tuple, str]:
    """Each run group's (KEYS) name in a suite's comparisons: `run_label`, and where that name stands
    for two runs of one network and task anywhere in `runs` (e.g. other `--set` overrides), with
    its algorithm config and command, as the tables name them."""
    groups = {key: g.iloc[0] for key, g in runs.groupby(KEYS, sort=True)}
    names = {key: run_label(r) for key, r in groups.items()}
    counts = Counter((r["network"], r["task_config"], names[k]) for k, r in groups.items())
    ambiguous = {name for (_, _, name), n in counts.items() if n > 1}
    return {key: qualified_label(r) if names[key] in ambiguous else names[key] for key, r in groups.items()}


def run_label(row: pd.Series) -> str:
    """A suite's row name: urb-jax's id (--alg, baseline_<model>); URB's name for URB's own runs."""
    return str(row.get("alg") or row["algorithm"])


def qualified_label(row: pd.Series) -> str:
    """`run_label` with the algorithm config and command (its `--set` items): where one name stands
    for two runs."""
    return f"{run_label(row)} ({row['alg_config']}; {row['script']})"


def _num(x: float | None, digits: int = 4) -> str:
    return "n/a" if x is None or x != x else f"{x:.{digits}f}"


def per_day_means(folder: Path) -> tuple[pd.DataFrame, int, int]:
    """(mean travel time per record day and group CAV/HDV/all, human days, SUMO training days)."""
    cfg = json.loads((folder / "exp_config.json").read_text())
    rec = read_records(folder, columns=["day", "agent", "kind", "travel_time"])
    final_kind = rec[rec["day"] == rec["day"].max()].set_index("agent")["kind"]
    rec = rec.assign(group=rec["agent"].map(final_kind))
    per_day = rec.groupby(["day", "group"])["travel_time"].mean().unstack()
    per_day["all"] = rec.groupby("day")["travel_time"].mean()
    H = int(cfg.get("human_days", 0))
    T = int(cfg.get("sumo_training_days", cfg.get("training_days", 0)))
    return per_day, H, T


AGAINST_FIGURE = "against_the_humans"


def against_humans_points(runs: pd.DataFrame) -> pd.DataFrame:
    """[network, task, run, seeds, mean, lo, hi]: each run's t_CAV - t_pre (minutes; below 0 its CAVs
    beat what the humans drove before them), the mean over seeds with its 95% t-interval (one run:
    its value); what the suite's summary figure draws."""
    rows = []
    labels = run_labels(runs)
    for (net, task), group in runs.groupby(["network", "task_config"], sort=True):
        for key, seeds in group.groupby(KEYS, sort=True):
            d = paired(pd.to_numeric(seeds["t_CAV"], errors="coerce").tolist(),
                       pd.to_numeric(seeds["t_pre"], errors="coerce").tolist())
            lo, hi = d.interval(0.95)
            rows.append({"network": net, "task": task, "run": labels[key], "seeds": len(seeds),
                         "mean": d.diff, "lo": lo, "hi": hi})
    return pd.DataFrame(rows, columns=["network", "task", "run", "seeds", "mean", "lo", "hi"])


def against_humans_figure(points: pd.DataFrame, path: Path) -> Path:
    """Every run's t_CAV - t_pre per network (`against_humans_points`), one marker per run, 95%
    intervals as bars, 0 (the humans' own time) as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = points["task"].nunique() > 1
    groups = sorted({(n, t) for n, t in zip(points["network"], points["task"], strict=True)})
    x = {g: i for i, g in enumerate(groups)}
    labels = sorted(points["run"].unique())
    fig, ax = plt.subplots(figsize=(max(7.0, 1.1 * len(groups) + 3.5), 4.5))
    for j, run in enumerate(labels):
        sel = points[points["run"] == run]
        xs = [x[(n, t)] + (j - (len(labels) - 1) / 2) * 0.18 for n, t in zip(sel["network"], sel["task"],
                                                                           strict=True)]
        err = [sel["mean"] - sel["lo"], sel["hi"] - sel["mean"]]
        ax.errorbar(xs, sel["mean"], yerr=err, fmt="o", capsize=3, label=textwrap.fill(run, 48))
    ax.axhline(0.0, color="grey", lw=1, ls="--")
    ax.set_xticks(range(len(groups)), [f"{n}\n({t})" if tasks else n for n, t in groups], rotation=30,
                  ha="right", fontsize=8)
    ax.set_ylabel("t_CAV - t_pre (min)")
    ax.set_title("Each run's CAVs against the humans before them (below 0: faster)\n"
                 "mean over seeds with its 95% interval", fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def suite_figures(folders: list[Path], out_dir: Path) -> list[Path]:
    """The runs against the humans (`against_humans_figure`), then one PNG per (network, algorithm,
    task): the seeds' per-day group means, averaged."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = collect_folders(folders)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if runs.empty:
        return written
    written.append(against_humans_figure(against_humans_points(runs), out_dir / f"{AGAINST_FIGURE}.png"))
    for key, g in runs.groupby(KEYS, sort=True):
        r = dict(zip(KEYS, key, strict=True))
        label = run_label(g.iloc[0])
        name = f"{r['network']}_{label}_{r['task_config']}".replace("/", "-")
        if any(p.stem == name for p in written):  # one label twice (other config or trainer)
            name = f"{name}_{len(written)}"
        days = [per_day_means(Path(f)) for f in g["folder"]]
        mean = pd.concat([d[0] for d in days]).groupby(level=0).mean()
        H, T = days[0][1], days[0][2]
        last = int(mean.index.max())
        fig, ax = plt.subplots(figsize=(9, 4.5))
        plot_phases(ax, mean, H, T, last)
        seeds = f"{len(days)} seed{'s' * (len(days) > 1)}"
        ax.set_title(f"{r['network']}: {label} ({r['alg_config']}), task {r['task_config']} ({seeds})")
        ax.set_xlabel("day (SUMO days as recorded)")
        ax.set_ylabel("mean travel time (min)")
        ax.legend(fontsize=8, loc="best")
        fig.tight_layout()
        path = out_dir / f"{name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written
