"""The suite report's statistics: sample std in its tables, each trained run against the humans and
the baselines (hand-computed cases)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from urb_jax.reporting.drift import ERROR_COLUMN, ROUNDS_FILE
from urb_jax.reporting.leaderboard import KEYS, aggregate
from urb_jax.reporting.suite_report import (
    against_humans_figure,
    against_humans_points,
    baseline_comparisons,
    wall_times_table,
)


def _runs(rows: list[tuple[str, float, float]], net: str = "gotham") -> pd.DataFrame:
    """Runs of one network and task: (alg, t_CAV, t_pre) each, with the leaderboard's keys."""
    out = []
    for alg, t_cav, t_pre in rows:
        base = alg.startswith("baseline_")
        out.append({"network": net, "algorithm": alg.removeprefix("baseline_"), "alg": alg,
                    "script": "urb-jax", "alg_config": "none" if base else "config1",
                    "task_config": "config1", "env_config": "config1",
                    "exp_type": "baseline" if base else "train", "winrate": 1.0,
                    "t_CAV": t_cav, "t_pre": t_pre})
    return pd.DataFrame(out)


def test_aggregate_gives_the_sample_std_and_zero_for_one_run():
    runs = _runs([("iql_star", 3.0, 3.2), ("iql_star", 3.2, 3.2), ("baseline_aon", 3.1, 3.2)])
    table = aggregate(runs, metrics=["t_CAV"]).set_index("alg")
    assert table.loc["iql_star", "t_CAV_std"] == pytest.approx(math.sqrt(0.02))  # ddof=1 (ddof=0: 0.1)
    assert table.loc["baseline_aon", "t_CAV_std"] == 0.0


def test_each_trained_run_against_the_humans_and_the_baselines():
    """3 seeds at 3.00, 3.01, 3.02 (sd 0.01, se 0.00577, df 2, t(0.975) = 4.303): against t_pre 3.20
    -0.1900 [-0.2148, -0.1652] lower; against AON 3.015 (one run, a constant) -0.0050, t = -0.866,
    two-sided p = 1 - |t| / sqrt(t^2 + 2) = 0.478 (df 2): tie; random is not run."""
    runs = _runs([("iql_star", 3.00, 3.2), ("iql_star", 3.01, 3.2), ("iql_star", 3.02, 3.2),
                  ("baseline_aon", 3.015, 3.2)])
    text = baseline_comparisons(runs)
    [row] = [line for line in text.splitlines() if line.startswith("| gotham")]
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[:5] == ["gotham, config1", "iql_star", "3", "3.0100 ± 0.0100", "n/a"]  # no rounds.csv
    assert cells[5] == "**lower** -0.1900 [-0.2148, -0.1652], p < 0.001"
    assert cells[6] == "**tie** -0.0050 [-0.0298, +0.0198], p = 0.478"
    assert cells[7] == "not run"
    assert set(KEYS) <= set(runs.columns)


def test_no_trained_run_no_section():
    assert baseline_comparisons(_runs([("baseline_aon", 3.0, 3.2), ("baseline_random", 3.5, 3.2)])) == ""


def test_the_summary_figure_draws_each_run_against_t_pre(tmp_path):
    """t_CAV - t_pre per run: the 3 seeds' -0.19 with the interval of the test above, AON's -0.185 as
    one value (no interval); two networks, each its own group."""
    runs = pd.concat([_runs([("iql_star", 3.00, 3.2), ("iql_star", 3.01, 3.2), ("iql_star", 3.02, 3.2),
                             ("baseline_aon", 3.015, 3.2)]),
                      _runs([("baseline_aon", 2.5, 2.4)], net="metropolis")], ignore_index=True)
    points = against_humans_points(runs).set_index(["network", "run"])
    iql = points.loc[("gotham", "iql_star")]
    assert (iql["seeds"], iql["mean"], iql["lo"], iql["hi"]) == pytest.approx((3, -0.19, -0.2148, -0.1652),
                                                                               abs=1e-4)
    aon = points.loc[("gotham", "baseline_aon"), ["mean", "lo", "hi"]].tolist()
    assert aon == pytest.approx([-0.185] * 3)
    assert points.loc[("metropolis", "baseline_aon"), "mean"] == pytest.approx(0.1)
    path = against_humans_figure(against_humans_points(runs), tmp_path / "against.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_surrogates_late_error_beside_each_run(tmp_path):
    """Each seed's late error (the last half of its rounds), their mean, flagged beyond ±5%."""
    runs = _runs([("iql_star", 3.00, 3.2), ("iql_star", 3.01, 3.2)])
    folders = []
    for seed, errors in enumerate(([-0.30, -0.20, -0.10, -0.12], [-0.05, -0.16, -0.18, -0.20])):
        folder = tmp_path / f"s{seed}"
        folder.mkdir()
        _write_rounds(folder, errors)
        folders.append(str(folder))
    cell = _row_cells(baseline_comparisons(runs.assign(folder=folders)))[4]
    assert cell == "-15.0%, beyond ±5%"  # (-0.11 + -0.19) / 2
    for folder in folders:
        _write_rounds(Path(folder), [0.01, 0.002, -0.001, 0.003])
    assert _row_cells(baseline_comparisons(runs.assign(folder=folders)))[4] == "+0.1%"


def _write_rounds(folder: Path, errors: list[float]) -> None:
    pd.DataFrame({"round": range(1, len(errors) + 1), ERROR_COLUMN: errors}).to_csv(folder / ROUNDS_FILE,
                                                                                   index=False)


def _row_cells(text: str) -> list[str]:
    [row] = [line for line in text.splitlines() if line.startswith("| gotham")]
    return [c.strip() for c in row.strip("|").split("|")]


def test_runs_that_differ_in_their_overrides_keep_apart():
    """Two IQL* runs of one network, one with a --set: two rows, each named with its command, and so
    is the IQL* run of another network (one name for one run across the report and its figure);
    a name that stands for one run everywhere stays short."""
    base = _runs([("iql_star", 3.00, 3.2), ("iql_star", 3.02, 3.2)])
    other = _runs([("iql_star", 2.90, 3.2)]).assign(script="urb-jax --set hybrid.route_bias_removed=true")
    alone = _runs([("iql_star", 2.5, 2.6)], net="metropolis")
    text = baseline_comparisons(pd.concat([base, other, alone], ignore_index=True))
    rows = [line for line in text.splitlines() if line.startswith("| gotham")]
    assert [r.split("|")[2].strip() for r in rows] == [
        "iql_star (config1; urb-jax)", "iql_star (config1; urb-jax --set hybrid.route_bias_removed=true)"]
    assert [r.split("|")[3].strip() for r in rows] == ["2", "1"]
    assert "| metropolis, config1 | iql_star (config1; urb-jax) | 1 |" in text
    assert "| metropolis, config1 | iql_star | 1 |" in baseline_comparisons(alone)


def test_wall_times_keep_runs_with_other_overrides_apart(tmp_path):
    runs = (("a_s0", 100.0, []), ("a_s1", 100.0, []), ("b_s0", 300.0, ["hybrid.sumo_days_per_round=16"]))
    for name, wall, over in runs:
        (tmp_path / name).mkdir()
        (tmp_path / name / "exp_config.json").write_text(json.dumps(
            {"network": "gotham", "alg": "iql_star", "wall_time_s": wall, "train_args": {"overrides": over}}))
    text = wall_times_table(sorted(tmp_path.iterdir()))
    assert "| gotham | iql_star | 2 | 100 s |  |" in text
    assert "| gotham | iql_star --set hybrid.sumo_days_per_round=16 | 1 | 300 s |  |" in text
