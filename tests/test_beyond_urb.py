"""benchmarks/beyond_urb.py: the generated page's tables from finished runs (hand-computed means,
sample sds and intervals), the suites not run yet, and the competing fleets' drivers against
themselves (hand-computed fleet means)."""

from __future__ import annotations

import json

import beyond_urb as bu
import numpy as np
import pandas as pd


def _run(root, name, bench: dict, social: dict | None = None, trips: tuple[int, ...] = (3, 2)) -> None:
    """A finished run folder: exp_config.json done, its metric files, records with two test days."""
    folder = root / name
    (folder / "metrics").mkdir(parents=True)
    (folder / "exp_config.json").write_text(json.dumps({"status": "done"}))
    pd.DataFrame([bench]).to_csv(folder / "metrics" / "BenchmarkMetrics.csv", index=False)
    if social is not None:
        pd.DataFrame([social]).to_csv(folder / "metrics" / "SocialMetrics.csv", index=False)
    rows = [{"day": 300 + d, "phase": "test", "action": a} for d, n in enumerate(trips)
            for a in [0] * n + [-1] * (3 - n)]
    pd.DataFrame(rows).to_parquet(folder / "records.parquet")


def test_cells_are_mean_sd_and_the_95_interval():
    assert bu.cell([]) == "–" and bu.cell([3.25]) == "3.2500 (1)"
    # mean 3.1, sd 0.1 (ddof 1), t(0.975, 2) = 4.302653: half-width 4.302653 x 0.1 / sqrt(3)
    half = 4.302653 * 0.1 / np.sqrt(3)
    assert bu.cell([3.0, 3.1, 3.2]) == f"3.1000 ± 0.1000 (3) [{3.1 - half:.4f}, {3.1 + half:.4f}]"
    # against one deterministic value: the difference of means, the seeds' interval only
    diff = bu.diff_cell([3.0, 3.1, 3.2], [3.15])
    assert diff.startswith(f"-0.0500 [{-0.05 - half:+.4f}, {-0.05 + half:+.4f}]")


def test_page_from_finished_runs(tmp_path, monkeypatch):
    for s, t in enumerate([3.0, 3.1, 3.2, 3.0, 3.2]):
        _run(tmp_path, f"vd_saint_arnoult_iql_star_s{s}", {"t_CAV": t, "t_pre": 3.19, "t_HDV_test": 3.3,
                                                           "t_test": 3.2})
    _run(tmp_path, "vd_saint_arnoult_aon", {"t_CAV": 3.05, "t_pre": 3.19, "t_HDV_test": 3.3, "t_test": 3.2})
    for s in range(3):
        _run(tmp_path, f"em_provins_iql_star_s{s}", {"t_CAV": 2.8, "t_pre": 2.84},
             {"humans_worse_off_share": 0.5, "human_change_mean": 0.01, "human_loss_max": 0.2,
              "human_loss_gini": 0.6, "co2_pre_day_g": 1000.0, "co2_test_day_g": 1000.0 + 10 * s})
    out = tmp_path / "beyond_urb.md"
    monkeypatch.setattr("sys.argv", ["beyond_urb.py", "--results-dir", str(tmp_path), "--out", str(out)])
    bu.main()
    page = out.read_text()
    assert "urb-jax suite varying_demand --networks-dir DIR --results-dir RESULTS" in page
    assert "urb-jax suite scenario1_emissions --networks-dir DIR --results-dir RESULTS" in page
    jitter = page[page.index("## Departures that vary day to day"):page.index("## Equity")]
    assert "urb-jax suite departure_jitter --networks-dir DIR" in jitter and "Not run yet." in jitter
    iql = next(line for line in page.splitlines() if line.startswith("| IQL\\*, p = 0.9 |"))
    assert "3.1000 ± 0.1000 (5)" in iql and "| 3/5 |" in iql  # below t_pre 3.19: 3.0, 3.1, 3.0
    assert "2.5 (1)" in next(line for line in page.splitlines() if line.startswith("| AON, p = 0.9 |"))
    assert "| IQL\\*, fixed demand | not run yet |" in page
    assert "| IQL\\* − AON, p = 0.9 | +0.0500 [" in page
    provins = page[page.index("### Provins"):page.index("### Ingolstadt")]
    # CO2 a test day 1.00, 1.01, 1.02 kg: +0, +1, +2 %
    assert "1.01 ± 0.01 (3)" in provins and "| 1.00 ± 0.00 (3)" in provins and "1.00 ± 1.00 (3)" in provins
    assert "### St. Arnoult\n\nNot run yet." in page
    assert "## Competing fleets" in page


def _fleet_run(root, name, test_times: tuple[float, float], fleets: dict | None = None) -> None:
    """A finished run of agents 0 (fleet `iql_star`), 1 (fleet `mappo`) and 2 (a human): 3.0, 3.3 and
    4.0 min on human days 1-2, then a training day 3 and a test day 4 with agents 0 and 1 at
    `test_times`."""
    folder = root / name
    folder.mkdir(parents=True)
    config = {"status": "done", "human_days": 2, "training_days": 1, "fleet_agents": fleets}
    (folder / "exp_config.json").write_text(json.dumps(config))
    days = {1: (3.0, 3.3), 2: (3.0, 3.3), 3: (5.0, 5.0), 4: test_times}
    rows = [{"day": d, "agent": a, "travel_time": t} for d, (t0, t1) in days.items()
            for a, t in ((0, t0), (1, t1), (2, 4.0))]
    pd.DataFrame(rows).to_parquet(folder / "records.parquet")


def test_fleets_section_compares_each_fleets_drivers_with_themselves(tmp_path):
    fleets = {"iql_star": [0], "mappo": [1]}
    for s in range(3):
        _fleet_run(tmp_path, f"fleets_saint_arnoult_iql_star_mappo_s{s}", (2.9 + 0.1 * s, 3.2), fleets)
        _fleet_run(tmp_path, f"fleets_saint_arnoult_one_fleet_iql_star_s{s}", (2.8, 3.4))
        _fleet_run(tmp_path, f"fleets_saint_arnoult_one_fleet_mappo_s{s}", (3.1, 3.2 + 0.1 * s))
    _fleet_run(tmp_path, "fleets_saint_arnoult_aon", (2.95, 3.25))
    lines = bu.fleets(tmp_path)
    iql = next(line for line in lines if line.startswith("| fleet `iql_star` |"))
    # n, before the CAVs (its drivers' human days), AON, alone with IQL*, alone with MAPPO, competing
    assert iql.startswith("| fleet `iql_star` | 1 | 3.0000 (1) | 2.9500 (1) | 2.8000 ± 0.0000 (3)")
    assert "| 3.1000 ± 0.0000 (3) [3.1000, 3.1000] | 3.0000 ± 0.1000 (3)" in iql
    mappo = next(line for line in lines if line.startswith("| fleet `mappo` |"))
    assert "| 3.3000 (1) | 3.2500 (1) | 3.4000 ± 0.0000 (3)" in mappo and "3.3000 ± 0.1000 (3)" in mappo
    # competing − alone with its own algorithm: IQL* 3.0 − 2.8; MAPPO 3.2 − 3.3
    diffs = [line for line in lines if line.startswith("| `")]
    assert diffs[0].startswith("| `iql_star` | +0.2000 [") and diffs[1].startswith("| `mappo` | -0.1000 [")
    assert bu.fleets(tmp_path / "none")[-2] == "Not run yet."
