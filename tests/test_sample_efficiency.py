"""benchmarks/sample_efficiency.py: the curve's points from finished runs and tested snapshots."""

from __future__ import annotations

import json

import pandas as pd
import sample_efficiency as se


def _hybrid(root, tag, t_cav, days, wall):
    for s, t in enumerate(t_cav):
        folder = root / f"se_saint_arnoult_iql_{tag}_s{s}"
        (folder / "metrics").mkdir(parents=True)
        (folder / "exp_config.json").write_text(json.dumps(
            {"status": "done", "sumo_training_days": days, "wall_time_s": wall}))
        pd.DataFrame([{"t_CAV_duration": t, "t_pre_duration": 3.1}]).to_csv(
            folder / "metrics" / "BenchmarkMetrics.csv", index=False)


def test_points_are_the_seeds_of_each_run_or_snapshot_sorted_by_sumo_days(tmp_path):
    _hybrid(tmp_path, "p4", [3.00, 3.02, 3.04, 3.06, 3.08], 40, 120.0)
    _hybrid(tmp_path, "sur", [3.2] * 5, 0, 60.0)
    _hybrid(tmp_path, "p16", [3.0] * 4, 160, 1.0)  # one seed missing: not a point yet
    points = se.hybrid_points(tmp_path, "iql")
    assert [(p.label, p.sumo_days, p.wall_s, p.wins) for p in points] == [
        ("hybrid, sur", 0, 60.0, 0), ("hybrid, p4", 40, 120.0, 5)]
    p4 = points[1]
    assert round(p4.t_cav.mean, 10) == 3.04 and round(p4.t_cav.sd, 10) == round(0.0316227766, 10)
    lo, hi = p4.interval()  # t(0.975, 4) = 2.776445
    assert abs((hi - lo) / 2 - 2.776445 * 0.0316227766 / 5 ** 0.5) < 1e-5
    for s in range(5):  # the SUMO-only run: its t_pre per seed, its snapshots table in the first folder
        folder = tmp_path / f"sumo_s1_saint_arnoult_iql_s{s}"
        (folder / "metrics").mkdir(parents=True)
        pd.DataFrame([{"t_pre_duration": 3.1}]).to_csv(folder / "metrics" / "BenchmarkMetrics.csv",
                                                        index=False)
    pd.DataFrame({"seed": [0, 1, 2, 3, 4] * 2, "round": [0] * 5 + [10] * 5,
                  "sumo_training_days": [0] * 5 + [40] * 5, "wall_s": [30.0] * 5 + [90.0] * 5,
                  "t_CAV_duration": [3.5] * 5 + [3.0, 3.2, 3.0, 3.0, 3.0]}).to_csv(
        tmp_path / "sumo_s1_saint_arnoult_iql_s0" / "snapshots.csv", index=False)
    snaps = se.sumo_only_points(tmp_path, "iql")
    assert [(p.label, p.sumo_days, p.wall_s, p.wins) for p in snaps] == [
        ("SUMO only, round 0", 0.0, 30.0, 0), ("SUMO only, round 10", 40.0, 90.0, 4)]
    assert abs(snaps[1].t_cav.mean - 3.04) < 1e-12
