"""Every metric on a synthetic records table with hand-computed answers (docs/metrics.md)."""

import math

import numpy as np
import pandas as pd
import pytest

from urb_jax.reporting.metrics import compute_metrics, gini, social_metrics, vector_metrics

# Agents 10, 11 stay HDVs; 12 becomes a CAV on day 3. H = 2 human days, T = 2 training days,
# days 5-6 test. Pre means: a10 3, a11 3, a12 5.
TT = {10: [2, 4, 3, 5, 4, 4], 11: [3, 3, 3, 3, 2, 2], 12: [4, 6, 7, 3, 2, 6]}
ACT = {10: [0, 1, 1, 1, 2, 2], 11: [0] * 6, 12: [0, 0, 1, 2, 2, 3]}
H, T = 2, 2


def _records(all_cav: bool = False) -> pd.DataFrame:
    rows = []
    for agent in (10, 11, 12):
        for d in range(1, 7):
            kind = "CAV" if d > H and (agent == 12 or all_cav) else "HDV"
            t = TT[agent][d - 1]
            speed, length, status = 10.0, 1000.0, 0
            if d == 5:
                speed, length = {10: (5.0, 2000.0), 11: (100.0, 99999.0), 12: (5.0, 4000.0)}[agent]
                status = 1 if agent == 11 else 0  # removed: excluded from SUMO statistics
            if d == 6:
                speed, length = 20.0, 3000.0
            rows.append(dict(day=d, agent=agent, kind=kind, action=ACT[agent][d - 1], travel_time=float(t),
                             route_length=length, speed=speed, duration=t * 60.0 if status == 0 else np.nan,
                             time_loss=1.0, depart_delay=0.5, status=status))
    return pd.DataFrame(rows)


def test_benchmark_metrics_hand_computed():
    m = compute_metrics(_records(), H, T)
    expected = {
        "t_pre": 11 / 3, "t_train": 4.0, "t_test": 10 / 3, "t_CAV": 4.0, "t_HDV_pre": 3.0, "t_HDV_test": 3.0,
        "CAV_advantage": 0.75, "Effect_of_change": 0.75, "Effect_of_remaining": 1.0,
        "avg_speed_pre": 36.0, "avg_speed_test": 45.0, "delta_V": 9.0,
        "avg_mileage_pre": 1.0, "avg_mileage_test": 3.0, "delta_L": 2.0,
        "winrate": 0.0,
        "cost_of_learning": 1 / 3, "cost_of_learning_humans": 0.5, "cost_of_learning_CAVs": 0.0,
        "avg_time_lost": 0.0, "avg_human_time_lost": 0.25, "avg_CAV_time_lost": -0.5,
        "diff_sumo_routerl": 3.5 - 10 / 3,
        "instability_humans_test": 0.5, "instability_CAVs_test": 0.5,
    }
    for key, value in expected.items():
        assert m[key] == pytest.approx(value), key


def test_winrate_compares_t_cav_with_t_pre():
    rec = _records()
    rec.loc[(rec.agent == 12) & (rec.day == 6), "travel_time"] = 1.0  # t_CAV = 1.5 < t_pre
    assert compute_metrics(rec, H, T)["winrate"] == 1.0


def test_vector_metrics_hand_computed():
    v = vector_metrics(_records(), H, T)
    assert v["episode"].tolist() == [3, 4, 5, 6]
    assert v["instability_humans"].tolist() == [0, 0, 1, 0]
    assert v["instability_CAVs"].tolist() == [1, 1, 0, 1]
    assert v["time_excess"].tolist() == pytest.approx([2.0, 0.0, -3.0, 1.0])
    assert v["avg_time_lost"].tolist() == pytest.approx([1.5] * 4)


def test_all_cav_scenario_reports_hdv_metrics_as_nan_not_errors():
    m = compute_metrics(_records(all_cav=True), H, T)
    for key in ("t_HDV_pre", "t_HDV_test", "CAV_advantage", "Effect_of_change", "Effect_of_remaining",
                "cost_of_learning_humans", "avg_human_time_lost", "instability_humans_test"):
        assert math.isnan(m[key]), key
    assert m["t_CAV"] == pytest.approx(10 / 3)
    assert m["t_pre"] == pytest.approx(11 / 3)
    assert m["winrate"] == 1.0


def test_every_pre_day_counts_and_window_is_50_days():
    """pre = days (H-50, H]: with H = 60, days 1-10 are excluded and all of 11-60 count."""
    rows = [dict(day=d, agent=0, kind="HDV" if d <= 60 else "CAV", action=0,
                 travel_time=100.0 if d <= 10 else float(d), route_length=1.0, speed=1.0, duration=60.0,
                 time_loss=0.0, depart_delay=0.0, status=0) for d in range(1, 63)]
    m = compute_metrics(pd.DataFrame(rows), 60, 1)
    assert m["t_pre"] == pytest.approx(np.mean(np.arange(11, 61)))


def test_duration_columns_average_each_agent_first_and_skip_removed_trips():
    """The published tables' measure: SUMO tripinfo duration, per agent over the slice's days,
    then over agents, a removed trip (no duration) skipped. Agent 0 stays an HDV, agent 1 is a
    CAV from day 3; H = 2, T = 1, test days 4-5; agent 0 is removed on day 5."""
    dur = {0: [120.0, 180.0, 60.0, 60.0, np.nan], 1: [240.0, 300.0, 60.0, 120.0, 240.0]}
    rows = [dict(day=d, agent=a, kind="CAV" if (a == 1 and d > 2) else "HDV", action=0,
                 travel_time=30.0 if np.isnan(dur[a][d - 1]) else dur[a][d - 1] / 60 + 0.05,
                 route_length=1.0, speed=1.0, duration=dur[a][d - 1], time_loss=0.0, depart_delay=0.0,
                 status=1 if np.isnan(dur[a][d - 1]) else 0) for a in (0, 1) for d in range(1, 6)]
    m = compute_metrics(pd.DataFrame(rows), 2, 1)
    assert m["t_pre_duration"] == pytest.approx((150 + 270) / 2 / 60)
    assert m["t_HDV_pre_duration"] == pytest.approx(150 / 60)
    assert m["t_CAV_duration"] == pytest.approx(180 / 60)
    assert m["t_HDV_test_duration"] == pytest.approx(60 / 60)  # day 5 removed: skipped, not 30 min
    # per agent first: (60 + 180) / 2 s, not the mean of the day means (90 and 240 s)
    assert m["t_test_duration"] == pytest.approx(120 / 60)
    # the travel_time columns keep URB's current measure (the removed trip charged 30 min)
    assert m["t_HDV_test"] == pytest.approx((60 / 60 + 0.05 + 30.0) / 2)


def _equity_records() -> pd.DataFrame:
    """Humans h1, h2, h3 and one CAV; days 1-2 pre-CAV (H = 2), day 3 a test day (T = 0)."""
    times = {1: [3.0, 4.0, 2.0, 5.0], 2: [5.0, 4.0, 2.0, 5.0], 3: [6.0, 3.0, 3.0, 4.0]}
    rows = [{"day": d, "agent": a, "travel_time": t, "kind": "CAV" if a == 3 and d == 3 else "HDV"}
            for d, ts in times.items() for a, t in enumerate(ts)]
    return pd.DataFrame(rows)


def test_equity_over_the_humans_hand_computed():
    """Changes test - own pre-CAV mean: h1 6 - 4 = +2, h2 3 - 4 = -1, h3 3 - 2 = +1. Losses (2, 0, 1):
    Gini = sum_ij |x_i - x_j| / (2 n^2 mean) = 8 / (2 * 9 * 1)."""
    m = social_metrics(_equity_records(), 2, 0)
    assert m["humans_worse_off_share"] == pytest.approx(2 / 3)
    assert m["human_change_mean"] == pytest.approx(2 / 3)
    assert m["human_loss_max"] == pytest.approx(2.0)
    assert m["human_loss_gini"] == pytest.approx(8 / 18)
    assert gini(np.zeros(4)) == 0.0 and gini(np.array([0.0, 0.0, 0.0, 5.0])) == pytest.approx(0.75)
    assert math.isnan(social_metrics(_equity_records(), 2, 1)["human_loss_max"])  # no test day left


def test_equity_ties_are_not_losses():
    """Float32 minutes round: a human whose test days repeat their pre-CAV days in another order
    (same seconds, same mean) differs by ~1e-7 min. Such a tie is no loss, and a real change of one
    second is one. Humans (seconds per day, pre days 1-2 | test day 3): h0 (150, 162 | 156) a tie
    (+2.4e-7 min in float32), h1 (180, 180 | 181) one second worse, h2 (200, 200 | 197) better."""
    secs = {0: [150, 162, 156], 1: [180, 180, 181], 2: [200, 200, 197]}
    rows = [{"day": d + 1, "agent": a, "travel_time": np.float32((t[d] + 2) / 60), "kind": "HDV"}
            for a, t in secs.items() for d in range(3)]
    m = social_metrics(pd.DataFrame(rows), 2, 0)
    assert m["humans_worse_off_share"] == pytest.approx(1 / 3)
    assert m["human_loss_max"] == pytest.approx(1 / 60, rel=1e-5)
    assert m["human_loss_gini"] == pytest.approx(2 / 3)  # losses (0, 1 s, 0): one bears all
    assert gini(np.array([1.0, 2.0, 3.0, 4.0])) == pytest.approx(0.25)  # sum |xi - xj| = 20, 2 n^2 mean = 80
