"""Beyond URB: the paper's own limitations as experiments, one generated page (docs/beyond_urb.md).

Reads finished runs under RESULTS: the `varying_demand` and `departure_jitter` suites (St. Arnoult,
IQL* and AON with day_participation 0.9, with day_departure_jitter_s 300, and under fixed demand),
the `scenario1_emissions` suite (IQL* with SUMO's emission device and AON on the three paper
networks, Scenario 1's task) and the `two_fleets` suite (two competing CAV fleets). Every number is
from SUMO days; over seeds, mean ± sample sd (ddof=1) with the 95% t-interval of the mean. A suite
not run yet shows as such; the page is rewritten whole each time.

    urb-jax suite varying_demand --networks-dir DIR --results-dir RESULTS
    urb-jax suite departure_jitter --networks-dir DIR --results-dir RESULTS
    urb-jax suite two_fleets --networks-dir DIR --results-dir RESULTS
    urb-jax suite scenario1_emissions --networks-dir DIR --results-dir RESULTS
    python benchmarks/beyond_urb.py --results-dir RESULTS --out docs/beyond_urb.md
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from urb_jax.core.atomic import write_text
from urb_jax.core.configio import configs_dir
from urb_jax.reporting import verdicts as V  # noqa: N812
from urb_jax.reporting.metrics import fleet_metrics
from urb_jax.reporting.records import finished_run_config, read_records, run_fleets

NETWORKS = {"saint_arnoult": "St. Arnoult", "provins": "Provins", "ingolstadt_custom": "Ingolstadt"}


@dataclass(frozen=True)
class Run:
    """A suite run's finished folders (one per seed; a baseline has one) and their metric files."""

    label: str
    folders: list[Path]
    bench: list[pd.Series]
    social: list[pd.Series]
    configs: list[dict]

    def values(self, column: str, table: str = "bench") -> list[float]:
        rows = self.bench if table == "bench" else self.social
        return [float(r[column]) for r in rows if column in r and not pd.isna(r[column])]


def _done(folder: Path) -> dict | None:
    path = folder / "exp_config.json"
    if not path.is_file():
        return None
    config = json.loads(path.read_text())
    return config if config.get("status") == "done" else None


def load_run(results: Path, label: str, names: list[str]) -> Run | None:
    """The run whose folders are `names`, if every one of them is done."""
    folders = [results / n for n in names]
    configs = [_done(f) for f in folders]
    if any(c is None for c in configs):
        return None
    bench = [pd.read_csv(f / "metrics" / "BenchmarkMetrics.csv").iloc[0] for f in folders]
    social = [_first_row(f / "metrics" / "SocialMetrics.csv") for f in folders]
    return Run(label, folders, bench, social, [c for c in configs if c is not None])


def _first_row(path: Path) -> pd.Series:
    """A one-row metric file's row (empty when the file is absent, e.g. a run from before it)."""
    return pd.read_csv(path).iloc[0] if path.is_file() else pd.Series(dtype=float)


def suite_runs(entry: str) -> list[dict]:
    """The runs of the shipped suite `entry` (configs/suites/<entry>.json), as the file gives them."""
    return json.loads((configs_dir() / "suites" / f"{entry}.json").read_text())["runs"]


def folder_names(run: dict) -> list[str]:
    if run["kind"] == "baseline":
        return [run["id"]]
    return [f"{run['id']}_s{s}" for s in run["args"].get("seeds", [0])]


def cell(values: list[float], digits: int = 4) -> str:
    """mean ± sd (n) [95% interval]; one value: the value (n = 1)."""
    if not values:
        return "–"
    s = V.Sample.of(values)
    if s.n == 1:
        return f"{s.mean:.{digits}f} (1)"
    lo, hi = V.welch(s, V.Sample(0.0, 0.0, 1)).interval(0.95)
    return f"{s.mean:.{digits}f} ± {s.sd:.{digits}f} ({s.n}) [{lo:.{digits}f}, {hi:.{digits}f}]"


def diff_cell(left: list[float], right: list[float], digits: int = 4) -> str:
    """left − right, Welch's 95% interval and two-sided p (a one-value side has no seed variance)."""
    if not left or not right:
        return "–"
    d = V.welch(V.Sample.of(left), V.Sample.of(right))
    lo, hi = d.interval(0.95)
    p = d.p_two()
    p_text = "" if math.isnan(p) else f", p = {p:.3g}"
    return f"{d.diff:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}]{p_text}"


@dataclass(frozen=True)
class Variation:
    """One day-to-day variation suite: its runs under the variation (`varied`, `varied_aon`) beside
    the same learner and AON under URB's fixed demand."""

    entry: str  # configs/suites/<entry>.json
    title: str
    what: str  # the label of the varied setting
    text: str  # what the variation is
    varied: str  # run id of IQL* under the variation
    varied_aon: str


VARIATIONS = (
    Variation(
        "varying_demand",
        "Demand that varies day to day",
        "p = 0.9",
        "With the task key `day_participation` p = 0.9 every driver, CAV or human, travels on a day after "
        "mutation with probability 0.9, drawn from the env seed, the same draw on surrogate and SUMO days; a "
        "driver at home has no vehicle, is not observed and does not learn, and those who travel take the "
        "SUMO speed factors of the insertion slots they hold that day (docs/experiment.md, \"Demand that "
        'varies day to day"). Task config `varying_demand_40`: config1 with p = 0.9; under p < 1 each IQL\\* '
        "CAV stores and learns from only the days it travelled.",
        "vd_saint_arnoult_iql_star",
        "vd_saint_arnoult_aon",
    ),
    Variation(
        "departure_jitter",
        "Departures that vary day to day",
        "±300 s",
        "With the task key `day_departure_jitter_s` J = 300 every driver leaves on a day after mutation at "
        "its scheduled second plus a uniform offset in [−300, 300] s (St. Arnoult's departures span 30 min), "
        "drawn from the env seed and the day; SUMO days run the day's departures and the travel time counts "
        "from them, the surrogate's days of the same index move by the same draw (entry times, insertion "
        "load, and SUMO's speed factors, which belong to insertion slots), and CAVs observe their "
        "scheduled departure "
        '(docs/experiment.md, "Departures that vary day to day"). Task config `departure_jitter_40`: '
        "config1 with J = 300.",
        "dj_saint_arnoult_iql_star",
        "dj_saint_arnoult_aon",
    ),
)
FIXED = (("IQL\\*, fixed demand", "fd_saint_arnoult_iql_star"), ("AON, fixed demand", "saint_arnoult_aon"))


def variation(results: Path, v: Variation) -> list[str]:
    rows = [(f"IQL\\*, {v.what}", v.varied), (f"AON, {v.what}", v.varied_aon), *FIXED]
    specs = {r["id"]: r for r in suite_runs(v.entry)}
    runs = {rid: load_run(results, label, folder_names(specs[rid])) for label, rid in rows}
    out = [
        f"## {v.title}",
        "",
        f"The paper's limitation (iii): its demand is fixed in OD pairs and departure times. {v.text} "
        "St. Arnoult, Scenario 1's task, URB's IQL\\* (algorithm config1: one network per CAV), 6,000 "
        "training days, hybrid training; AON every day in SUMO under the same variation. t_pre comes from "
        "the human phase, which keeps URB's fixed demand, so it is the same in both settings; t_CAV, t_HDV "
        "and t_test are means over the test days' trips that happened. Minutes, URB's measure (RouteRL's "
        "travel time); WR: seeds whose t_CAV is below t_pre.",
        "",
        "```bash",
        f"urb-jax suite {v.entry} --networks-dir DIR --results-dir RESULTS",
        "python benchmarks/beyond_urb.py --results-dir RESULTS --out docs/beyond_urb.md",
        "```",
        "",
    ]
    if not any(runs.values()):
        return [*out, "Not run yet.", ""]
    out += [
        "| run | t_pre | t_CAV | t_HDV (test) | t_test | WR | trips a test day |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, rid in rows:
        run = runs[rid]
        if run is None:
            out.append(f"| {label} | not run yet | | | | | |")
            continue
        t_cav, t_pre = run.values("t_CAV"), run.values("t_pre")
        wins = sum(c < p for c, p in zip(t_cav, t_pre, strict=True))
        trips = [_test_trips(f) for f in run.folders]
        out.append(
            f"| {label} | {cell(t_pre)} | {cell(t_cav)} | {cell(run.values('t_HDV_test'))} | "
            f"{cell(run.values('t_test'))} | {wins}/{len(t_cav)} | {cell(trips, 1)} |"
        )
    diffs = []
    pairs = [
        (f"IQL\\* − t_pre, {v.what}", v.varied, None),
        (f"IQL\\* − AON, {v.what}", v.varied, v.varied_aon),
        ("IQL\\* − t_pre, fixed demand", FIXED[0][1], None),
        ("IQL\\* − AON, fixed demand", FIXED[0][1], FIXED[1][1]),
    ]
    for label, left, right in pairs:
        a = runs[left]
        if a is None or (right is not None and runs[right] is None):
            continue
        b = None if right is None else runs[right]
        other = a.values("t_pre") if b is None else b.values("t_CAV")
        diffs.append(f"| {label} | {diff_cell(a.values('t_CAV'), other)} |")
    if diffs:
        out += [
            "",
            "Differences (Welch, 95% interval; AON is one deterministic run, so its side has no seed "
            "variance):",
            "",
            "| comparison | t_CAV difference (min) |",
            "|---|---|",
            *diffs,
        ]
    return [*out, ""]


def _test_trips(folder: Path) -> float:
    """Mean number of trips made (vehicles SUMO inserted) a test day."""
    rec = pd.read_parquet(folder / "records.parquet", columns=["day", "phase", "action"])
    test = rec[rec["phase"] == "test"]
    return float((test["action"] >= 0).groupby(test["day"]).sum().mean())


EQUITY = [
    ("humans_worse_off_share", "humans worse off (share)", 3),
    ("human_change_mean", "mean change (min)", 4),
    ("human_loss_max", "largest loss (min)", 3),
    ("human_loss_gini", "Gini of losses", 3),
]
EMISSIONS = [
    ("co2_pre_day_g", 1e-3, "CO2 a day before the CAVs (kg)"),
    ("co2_test_day_g", 1e-3, "CO2 a test day (kg)"),
]


def equity_emissions(results: Path) -> list[str]:
    specs = suite_runs("scenario1_emissions")
    out = [
        "## Equity and emissions in Scenario 1",
        "",
        "Who among the humans pays for the CAVs, and what the CAVs do to the day's CO2, every number from "
        "SUMO days. Scenario 1's task (URB's task config1: 40% selfish CAVs after 200 human days, 100 "
        "test days) on the three paper networks; URB's IQL\\* (algorithm config1), 6,000 training days, "
        "hybrid training, with SUMO's emission device on each SUMO day (`--set hybrid.emissions=true`: "
        "SUMO's default class, HBEFA4/PC_petrol_Euro-4); AON every day in SUMO (without the device: its "
        'emission cells are empty). Equity (metrics/SocialMetrics.csv, docs/metrics.md "Equity over the '
        'humans"): for each human, its mean time over the test days minus its own mean over the pre-CAV '
        'window; changes within 10⁻⁴ min are ties. Emissions (docs/metrics.md "Emissions"): the day\'s '
        "total over every vehicle, mean over the pre-CAV window's days and over the test days.",
        "",
        "```bash",
        "urb-jax suite scenario1_emissions --networks-dir DIR --results-dir RESULTS",
        "python benchmarks/beyond_urb.py --results-dir RESULTS --out docs/beyond_urb.md",
        "```",
        "",
    ]
    any_run = False
    for net, name in NETWORKS.items():
        rows = [r for r in specs if r["args"]["net"] == net]
        loaded = [(r, load_run(results, _label(r), folder_names(r))) for r in rows]
        out += [f"### {name}", ""]
        if not any(run for _, run in loaded):
            out += ["Not run yet.", ""]
            continue
        any_run = True
        out += [
            "| run | t_pre | t_CAV | "
            + " | ".join(h for _, h, _ in EQUITY)
            + " | "
            + " | ".join(h for _, _, h in EMISSIONS)
            + " | CO2 change (%) |",
            "|---" * (4 + len(EQUITY) + len(EMISSIONS)) + "|",
        ]
        for spec, run in loaded:
            if run is None:
                out.append(f"| {_label(spec)} | not run yet |" + " |" * (2 + len(EQUITY) + len(EMISSIONS)))
                continue
            equity = [cell(run.values(c, "social"), d) for c, _, d in EQUITY]
            co2 = [cell([v * k for v in run.values(c, "social")], 2) for c, k, _ in EMISSIONS]
            pre, test = run.values("co2_pre_day_g", "social"), run.values("co2_test_day_g", "social")
            change = [100.0 * (t / p - 1.0) for p, t in zip(pre, test, strict=True)]
            out.append(
                f"| {run.label} | {cell(run.values('t_pre'))} | {cell(run.values('t_CAV'))} | "
                + " | ".join(equity)
                + " | "
                + " | ".join(co2)
                + f" | {cell(change, 2)} |"
            )
        out.append("")
    return out if any_run else [*out, ""]


def _label(run: dict) -> str:
    if run["kind"] == "baseline":
        return run["args"]["model"].upper()
    return {"iql_star": "IQL\\*", "ippo_star": "IPPO\\*"}.get(run["args"]["alg"], run["args"]["alg"])


FLEET_RUNS = (
    ("one fleet of 40%, IQL\\*", "fleets_saint_arnoult_one_fleet_iql_star"),
    ("one fleet of 40%, MAPPO", "fleets_saint_arnoult_one_fleet_mappo"),
    ("two fleets, competing", "fleets_saint_arnoult_iql_star_mappo"),
)


def fleet_values(
    results: Path, names: list[str], fleets: dict[str, list[int]]
) -> dict[str, list[float]] | None:
    """Each fleet's t_pre_<name> and t_CAV_<name> over the seed folders `names` (None: not all done):
    `metrics.fleet_metrics` over the fleet's drivers, whichever run they drove in."""
    out: dict[str, list[float]] = {}
    for name in names:
        folder = results / name
        if _done(folder) is None:
            return None
        cfg = finished_run_config(folder)
        row = fleet_metrics(read_records(folder), int(cfg["human_days"]), int(cfg["training_days"]), fleets)
        for key, value in row.items():
            out.setdefault(key, []).append(value)
    return out


def fleets(results: Path) -> list[str]:
    specs = {r["id"]: r for r in suite_runs("two_fleets")}
    out = [
        "## Competing fleets",
        "",
        "The paper's limitation (iv): a single CAV fleet. Two selfish fleets of 20% on St. Arnoult, one "
        "learning with IQL\\* (URB's algorithm config1), one with MAPPO (urb-jax's hybrid config), trained "
        "together in one hybrid run (task `two_fleets_20_20`; the fleets split URB's 40% CAV draw), against "
        "the one-fleet 40% run of each algorithm with the same CAVs, humans, budget (2,000 training days) "
        "and seeds, and AON on the same task. Each fleet's drivers are compared with themselves: before the "
        "CAVs (t_pre over the fleet's drivers), under AON, in each one-fleet run and competing "
        "(`metrics.fleet_metrics`, URB's travel-time measure, minutes; docs/experiment.md, \"Competing CAV "
        'fleets").',
        "",
        "```bash",
        "urb-jax suite two_fleets --networks-dir DIR --results-dir RESULTS",
        "python benchmarks/beyond_urb.py --results-dir RESULTS --out docs/beyond_urb.md",
        "```",
        "",
    ]
    first = results / folder_names(specs[FLEET_RUNS[-1][1]])[0]
    if _done(first) is None:
        return [*out, "Not run yet.", ""]
    members = run_fleets(first)
    aon = fleet_values(results, folder_names(specs["fleets_saint_arnoult_aon"]), members)
    runs = {rid: fleet_values(results, folder_names(specs[rid]), members) for _, rid in FLEET_RUNS}
    out += [
        "| the fleet's drivers | n | before the CAVs | AON | "
        + " | ".join(lb for lb, _ in FLEET_RUNS)
        + " |",
        "|---" * (4 + len(FLEET_RUNS)) + "|",
    ]
    for name, agents in members.items():
        pre = (runs[FLEET_RUNS[-1][1]] or {}).get(f"t_pre_{name}", [])
        cells = [cell((runs[rid] or {}).get(f"t_CAV_{name}", [])) for _, rid in FLEET_RUNS]
        aon_cell = cell((aon or {}).get(f"t_CAV_{name}", []))
        out.append(
            f"| fleet `{name}` | {len(agents)} | {cell(pre[:1])} | {aon_cell} | " + " | ".join(cells) + " |"
        )
    out += [
        "",
        "Competing against alone (Welch, 95% interval):",
        "",
        "| fleet | two fleets − one fleet of the same algorithm (min) | two fleets − before the CAVs (min) |",
        "|---|---|---|",
    ]
    both = runs[FLEET_RUNS[-1][1]] or {}
    for (_, rid), name in zip(FLEET_RUNS[:2], members, strict=False):
        alone = (runs[rid] or {}).get(f"t_CAV_{name}", [])
        mine = both.get(f"t_CAV_{name}", [])
        out.append(
            f"| `{name}` | {diff_cell(mine, alone)} | {diff_cell(mine, both.get(f't_pre_{name}', [])[:1])} |"
        )
    return [*out, ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results-dir", default="results")
    ap.add_argument("--out", default="docs/beyond_urb.md")
    args = ap.parse_args()
    results, out = Path(args.results_dir), Path(args.out)
    head = [
        "# Beyond URB: the paper's limitations as experiments",
        "",
        "Generated by `python benchmarks/beyond_urb.py --results-dir RESULTS` from the finished runs of "
        "the `varying_demand`, `departure_jitter`, `scenario1_emissions` and `two_fleets` suites "
        "(`configs/suites/`). Every number is from "
        "SUMO days. Over seeds: mean ± sample sd (n) [95% t-interval of the mean]; a single value is one "
        "deterministic run. The runs were made on 2 CPU cores shared with other work.",
        "",
    ]
    write_text(
        out,
        "\n".join(
            [
                *head,
                *[line for v in VARIATIONS for line in variation(results, v)],
                *equity_emissions(results),
                *fleets(results),
            ]
        ),
    )
    print(f"-> {out}")


if __name__ == "__main__":
    main()
