"""A train run's kept checkpoints tested as the run tests its final policies (urb_jax.runs.snapshots)."""

from __future__ import annotations

import pandas as pd
import pytest
from support.fakeday import FakeExecutor
from support.tiny_runs import train_iql

from urb_jax.core.errors import UrbJaxError
from urb_jax.runs.snapshots import SNAPSHOT_METRICS, SNAPSHOTS_FILE, SnapshotRequest, run_snapshots


def test_the_last_snapshot_is_the_runs_own_test_and_earlier_ones_are_the_curve(confs, tmp_path):
    """Rounds 0, 2 and 3 kept (rounds of 6 days, 2 of them SUMO days): the newest checkpoint tested
    again gives the run's own test metrics to the bit; the rows say the SUMO days each had seen."""
    (out,) = train_iql(confs, tmp_path, "curve", overrides=["hybrid.keep_checkpoints_at=[0, 7]"])
    table = run_snapshots(SnapshotRequest("curve", str(tmp_path), progress=False), executor=FakeExecutor())
    assert table["round"].tolist() == [0, 2, 3]
    assert table["training_days"].tolist() == [0, 12, 18]
    assert table["sumo_training_days"].tolist() == [0, 4, 6]
    own = pd.read_csv(out.folder / "metrics" / "BenchmarkMetrics.csv").iloc[0]
    last = table.iloc[-1]
    for metric in SNAPSHOT_METRICS:
        assert last[metric] == pytest.approx(own[metric], rel=1e-12, abs=0.0), metric
    pd.testing.assert_frame_equal(pd.read_csv(out.folder / SNAPSHOTS_FILE), table, check_dtype=False)


def test_a_round_that_was_not_kept_is_refused_naming_the_kept_ones(confs, tmp_path):
    train_iql(confs, tmp_path, "one")
    req = SnapshotRequest("one", str(tmp_path), rounds=(1,), progress=False)
    kept_only_the_newest_two = r"no checkpoint after round\(s\) \[1\]; kept: \[2, 3\].*keep_checkpoints_at"
    with pytest.raises(UrbJaxError, match=kept_only_the_newest_two):
        run_snapshots(req, executor=FakeExecutor())
