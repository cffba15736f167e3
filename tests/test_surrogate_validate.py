"""Validation metrics on hand-made numbers, and `urb-jax validate-surrogate` end to end on the grid."""

from __future__ import annotations

import json

import numpy as np
import pytest

from urb_jax.surrogate.calibrate import SumoSample
from urb_jax.surrogate.validate import deviation_choices, error_metrics, route_agreement


def test_error_metrics_hand_case():
    y = np.array([[2.0, 4.0], [3.0, 3.0]], dtype=np.float32)
    pred = np.array([[2.2, 3.8], [3.0, 3.3]], dtype=np.float32)
    m = error_metrics(pred, SumoSample(np.zeros((2, 2), np.int32), y, np.ones((2, 2), bool)))
    # day means: 3.0 vs 3.0 (0%), 3.0 vs 3.15 (5%)
    assert abs(m["mean_tt_error"] - 0.025) < 1e-6
    assert abs(m["mape"] - np.mean([0.1, 0.05, 0.0, 0.1])) < 1e-6
    # removed vehicles are excluded
    arrived = np.array([[True, False], [True, True]])
    m2 = error_metrics(pred, SumoSample(np.zeros((2, 2), np.int32), y, arrived))
    assert m2["removed"] == 1 and abs(m2["mape"] - np.mean([0.1, 0.0, 0.1])) < 1e-6


def test_deviation_choices_switch_one_agent_each():
    base = np.array([0, 1, 2])
    valid = np.array([[True, True, False], [True, True, True], [True, True, True]])
    rows, meta = deviation_choices(base, np.array([0, 2]), valid)
    assert meta == [(0, 1), (2, 0), (2, 1)]
    for row, (i, k) in zip(rows, meta, strict=True):
        assert row[i] == k and np.array_equal(np.delete(row, i), np.delete(base, i))


def test_route_agreement_counts_signs_and_argmin():
    base = np.array([0, 0])
    meta = [(0, 1), (0, 2), (1, 1)]
    # reference: agent 0 route 1 faster (-1), route 2 slower (+2); agent 1 route 1 slower (+0.1)
    base_t = np.array([[5.0, 4.0], [5.0, 4.0]])
    dev_t = np.array([[4.0, 7.0, 4.1], [4.5, 4.0, 3.9]])  # model: -0.5, -1.0 (wrong), -0.1 (wrong)
    a = route_agreement(base_t, dev_t, base, meta, k=3)
    assert a["pairs"] == 3 and abs(a["pair_agreement"] - 1 / 3) < 1e-9
    assert a["clear_pairs"] == 2 and abs(a["pair_agreement_clear"] - 0.5) < 1e-9
    # fastest: agent 0 ref route 1, model route 2 (disagree); agent 1 ref route 0, model route 1
    assert a["argmin_agreement"] == 0.0


@pytest.mark.sumo
def test_validate_surrogate_end_to_end_calibration_beats_the_uncalibrated_model(tmp_path, capsys):
    """`urb-jax validate-surrogate` on the embedded grid, as small as it goes: SUMO calibration and
    held-out days, single-agent deviations and the second-seed noise floor, all in its files."""
    from urb_jax.commands.cli import main

    out = tmp_path / "val"
    argv = ["validate-surrogate", "--days", "5", "--train-days", "10", "--agents", "6", "--workers", "1",
            "--out", str(out)]
    assert main(argv) == 0
    m = json.loads((out / "metrics.json").read_text())
    held, raw = m["held_out"], m["uncalibrated"]
    # calibration on SUMO days must beat the uncalibrated BPR model on days it never saw
    assert held["mape"] < raw["mape"] and held["mean_tt_error"] < raw["mean_tt_error"]
    assert held["mean_tt_error"] < 0.05 and held["r2"] > 0.5
    assert held["sumo_mean_tt"] == raw["sumo_mean_tt"]  # the same SUMO days judge both
    kinds = m["setup"]["test_kinds"]
    assert len(kinds) == 5 and set(m["by_kind"]) == set(kinds)
    assert sum(k["removed"] for k in m["by_kind"].values()) == held["removed"]
    agree = m["route_agreement"]
    assert set(agree) == {"surrogate", "free_flow", "uncalibrated", "sumo_seed_vs_seed"}
    n_dev = m["setup"]["deviation_days"]  # one day per (agent, other valid route): 6 agents, up to 3 each
    assert 6 <= n_dev <= 18
    assert all(agree[name]["pairs"] == n_dev for name in ("surrogate", "free_flow", "uncalibrated"))
    assert 0 < agree["sumo_seed_vs_seed"]["pairs"] < n_dev  # the noise floor re-runs 2 of the 6 agents
    assert all(0.0 <= a["pair_agreement"] <= 1.0 for a in agree.values())
    assert 0 < m["seed_to_seed_mape_base"] < 0.5
    params = np.load(out / "params.npz")
    assert len(params.files) > 0
    report = (out / "report.md").read_text()
    assert f"{100 * held['mape']:.2f}%" in report and f"{100 * raw['mape']:.2f}%" in report
    assert (out / "scatter_residuals.png").stat().st_size > 0
    assert str(out / "report.md") in capsys.readouterr().out
