"""The paper page's travel-time figure data, its cost table and its training-days column, each on
hand-made inputs whose answers are computed here by hand (the data functions, not pixels)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from urb_jax.reporting.cost import cost_markdown, our_cost
from urb_jax.reporting.paper import NAMES
from urb_jax.reporting.suite_report import runs_tables
from urb_jax.reporting.train_days import ROUND_UP_MARK, TrainDays, days_cell, train_days_of
from urb_jax.reporting.travel_figures import (
    Schedule,
    gapped,
    moving_average,
    schedule_of,
    seed_band,
    seed_days,
    surrogate_steps,
)

# ---- the figure's data

# 2 human days, two rounds of 3 surrogate days then 1 SUMO day, 1 test day: days on the axis
# 1, 2 (human), 6 and 10 (the rounds' SUMO days), 11 (test)
SCHEDULE = Schedule(2, ((3, 1), (3, 1)))


def _records(cav: list[float], hdv: list[float]) -> pd.DataFrame:
    """Two agents over recorded days 1-5 (human, human, train, train, test); agent 0 a CAV from day 3."""
    phases = ["human", "human", "train", "train", "test"]
    rows = []
    for day, (phase, a, b) in enumerate(zip(phases, cav, hdv, strict=True), start=1):
        rows.append({"day": day, "phase": phase, "agent": 0, "kind": "HDV" if day < 3 else "CAV",
                     "travel_time": a})
        rows.append({"day": day, "phase": phase, "agent": 1, "kind": "HDV", "travel_time": b})
    return pd.DataFrame(rows)


def test_the_schedule_places_sumo_days_after_each_rounds_surrogate_days():
    assert SCHEDULE.training_days == 8
    assert SCHEDULE.sumo_positions().tolist() == [6, 10]
    assert SCHEDULE.surrogate_spans() == [(3, 5), (7, 9)]
    rounds = pd.DataFrame({"round": [1, 2], "surrogate_days": [3, 3], "sumo_days": [1, 1]})
    assert schedule_of({"human_days": 2}, rounds) == SCHEDULE
    sumo_only = pd.DataFrame({"round": [1, 2], "sumo_days": [4, 4]})  # a --mode sumo run's rounds.csv
    assert schedule_of({"human_days": 2}, sumo_only).sumo_positions().tolist() == list(range(3, 11))


def test_seed_days_divide_by_t_pre_and_place_each_day():
    days = seed_days(_records([2, 4, 6, 8, 10], [1, 1, 2, 2, 3]), 2.0, SCHEDULE)
    assert days["x"].tolist() == [1, 2, 6, 10, 11]
    assert days["phase"].tolist() == ["human", "human", "train", "train", "test"]
    assert days["CAV"].tolist() == [1, 2, 3, 4, 5]  # agent 0 is a CAV on the last day: its group throughout
    assert days["HDV"].tolist() == [0.5, 0.5, 1, 1, 1.5]
    with pytest.raises(ValueError, match="1 SUMO training days recorded, 2 in its rounds"):
        seed_days(_records([2, 4, 6, 8, 10], [1] * 5).query("day != 4"), 2.0, SCHEDULE)


def test_seed_band_is_the_mean_and_the_95_percent_t_interval():
    a = seed_days(_records([2, 4, 6, 8, 10], [1] * 5), 2.0, SCHEDULE)  # CAV 1 2 3 4 5
    b = seed_days(_records([4, 4, 2, 8, 14], [1] * 5), 2.0, SCHEDULE)  # CAV 2 2 1 4 7
    band = seed_band([a, b], "CAV")
    assert band.x.tolist() == [1, 2, 6, 10, 11] and band.seeds == 2
    np.testing.assert_allclose(band.mean, [1.5, 2, 2, 4, 6])
    # two seeds: sd = |a - b| / sqrt(2), half = t(0.975, 1) * sd / sqrt(2) = 12.7062 * |a - b| / 2
    half = 12.7062047 * np.array([1, 0, 2, 0, 2]) / 2
    np.testing.assert_allclose(band.lo, band.mean - half, rtol=1e-6)
    np.testing.assert_allclose(band.hi, band.mean + half, rtol=1e-6)
    one = seed_band([a], "CAV")
    assert one.seeds == 1 and one.lo.tolist() == one.mean.tolist() == one.hi.tolist()
    # only the days every seed recorded
    assert seed_band([a, b.iloc[:3]], "CAV").x.tolist() == [1, 2, 6]


def test_the_moving_average_is_numpys_convolution_on_consecutive_days():
    rng = np.random.default_rng(0)
    y = rng.normal(size=400)
    x = np.arange(1, 401)
    got = moving_average(x, y, 150)
    np.testing.assert_allclose(got[149:], np.convolve(y, np.ones(150) / 150, mode="valid"))
    np.testing.assert_allclose(got[:149], np.cumsum(y[:149]) / np.arange(1, 150))  # fewer at the start
    # days far apart (a hybrid run's rounds): a window of days holds only its own round's days
    np.testing.assert_allclose(moving_average(np.array([1, 2, 500, 501]), np.array([1.0, 3, 5, 7]), 150),
                               [1, 2, 5, 6])
    # a NaN day (no humans left) is left out, not spread
    np.testing.assert_allclose(moving_average(np.arange(3), np.array([1.0, np.nan, 3]), 3), [1, 1, 2])


def test_surrogate_steps_are_the_rounds_means_over_t_pre_across_seeds():
    r1 = pd.DataFrame({"sur_time_cav": [3.0, 2.0], "sur_time_hdv": [2.0, 2.0]})
    r2 = pd.DataFrame({"sur_time_cav": [6.0, 6.0], "sur_time_hdv": [2.0, 4.0]})
    steps = surrogate_steps([r1, r2], [2.0, 3.0], SCHEDULE, "CAV")
    assert steps == [(3, 5, pytest.approx((1.5 + 2.0) / 2)), (7, 9, pytest.approx((1.0 + 2.0) / 2))]
    assert surrogate_steps([pd.DataFrame({"sumo_days": [4]})], [2.0], SCHEDULE, "CAV") == []  # SUMO only


def test_lines_break_across_unrecorded_days():
    x, y = gapped(np.array([1, 2, 6, 7]), np.array([1.0, 2, 3, 4]))
    assert np.isnan(x[2]) and np.isnan(y[2]) and x[~np.isnan(x)].tolist() == [1, 2, 6, 7]


# ---- training days and the round-up mark

def _row(sumo: int | None, surrogate: int | None, asked: int | None, **extra) -> dict:
    return {"sumo_training_days": sumo, "surrogate_training_days": surrogate, "train_days_asked": asked,
            **extra}


def test_a_run_trained_past_its_budget_is_marked_and_an_exact_one_is_not():
    up = train_days_of(_row(40, 6400, 6000))
    assert up == TrainDays(40, 6400, 6000) and up.rounded_up
    assert days_cell(pd.DataFrame([_row(40, 6400, 6000)] * 5)) == (
        f"40 SUMO + 6,400 surrogate = 6,440 (6,000 asked) {ROUND_UP_MARK}")
    exact = days_cell(pd.DataFrame([_row(6000, 0, 6000)]))
    assert exact == "6,000 SUMO + 0 surrogate = 6,000 (6,000 asked)" and ROUND_UP_MARK not in exact
    # the ledger's older rows: asked from the provenance's request; days not kept: not recorded
    prov = {"request": {"train_days": 6000}}
    assert train_days_of(_row(4, 5996, None, provenance=prov)) == TrainDays(4, 5996, 6000)
    assert days_cell(pd.DataFrame([_row(None, None, None)])) == "not recorded"
    assert days_cell(pd.DataFrame([{"alg": "baseline_aon"}])).startswith("none (a baseline")
    mixed = days_cell(pd.DataFrame([_row(40, 6400, 6000), _row(40, 6400, 6000), _row(None, None, None)]))
    assert mixed == f"40 SUMO + 6,400 surrogate = 6,440 (6,000 asked) {ROUND_UP_MARK} (2 seeds); " \
                    "not recorded (1 seeds)"


def test_the_suite_tables_show_each_rows_training_days_and_the_legend():
    base = {"network": "saint_arnoult", "algorithm": "iql", "alg": "iql", "script": "s", "alg_config": "c",
            "task_config": "t", "env_config": "e", "exp_type": "normal", "winrate": 0.0, "t_pre": 3.0}
    qmix = {**base, "algorithm": "qmix", "alg": "qmix", **_row(6000, 0, 6000), "exp_id": "b"}
    runs = pd.DataFrame([{**base, **_row(40, 6400, 6000), "exp_id": f"a_s{i}"} for i in range(2)] + [qmix])
    text = runs_tables(runs)
    assert f"| iql | 2 | 40 SUMO + 6,400 surrogate = 6,440 (6,000 asked) {ROUND_UP_MARK} |" in text
    assert "| qmix | 1 | 6,000 SUMO + 0 surrogate = 6,000 (6,000 asked) |" in text
    assert f"{ROUND_UP_MARK} trained more days than asked" in text


# ---- the cost table

COMPUTE = {"source": "tab:comp_time", "caption": "four experiments",
           "runs": [{"network": "saint_arnoult", "algorithm": "qmix", "hours": 15.5},
                    {"network": "provins", "algorithm": "qmix", "hours": 44}],
           "hardware": {"source": "tab:hardware", "CPU": "Xeon", "GPU": "RTX 2080", "RAM": "64 GB",
                        "Operating system": "Ubuntu", "SUMO version": "1.18.0"},
           "ours": [{"entry": "hybrid_entry", "what": "hybrid"},
                    {"entry": "sumo_entry", "what": "SUMO only"}]}
MACHINE = {"cpu": "EPYC", "cpu_count": 2, "backend": "cpu", "device": "cpu"}


def _run(exp_id: str, wall: float | None, group: list[str] | None, days: tuple[int, int], **extra) -> dict:
    prov = {"machine": MACHINE, "seeds_trained_together": group or "not recorded",
            "wall_time_s": "not recorded" if wall is None else wall, "request": {"train_days": 6000}}
    return {"exp_id": exp_id, "network": "saint_arnoult", "alg": "qmix", "algorithm": "qmix_torchrl",
            "sumo_training_days": days[0], "surrogate_training_days": days[1], "provenance": prov, **extra}


def test_the_cost_rows_are_group_walls_and_their_shares_per_seed():
    together = ["h_s0", "h_s1"]  # trained in one program: both record the group's 7,200 s
    hybrid = pd.DataFrame([_run(n, 7200.0, together, (40, 6400)) for n in together])
    walls = (3600.0, 7200.0, 10800.0, None)  # one seed alone each; the last with no wall time recorded
    alone = pd.DataFrame([_run(f"s_s{i}", w, None, (6000, 0)) for i, w in enumerate(walls)])
    h, s = our_cost("hybrid_entry", "hybrid", hybrid), our_cost("sumo_entry", "SUMO only", alone)
    assert h.mean_per_seed_h == pytest.approx(1.0) and len(h.groups) == 1  # 2 h over 2 seeds
    assert s.mean_per_seed_h == pytest.approx(2.0) and s.unrecorded == 1  # (1 + 2 + 3) / 3 h
    text = cost_markdown(COMPUTE, {"hybrid_entry": hybrid, "sumo_entry": alone}, NAMES)
    rows = text.splitlines()
    i = rows.index(next(r for r in rows if r.startswith("| saint_arnoult | QMIX | paper")))
    assert "~15.5 h" in rows[i] and "6,000 training days, all in SUMO" in rows[i] and "Xeon" in rows[i]
    assert rows[i + 1] == ("| | | ours, `hybrid_entry` (hybrid), 2 seed(s) | 40 SUMO + 6,400 surrogate = "
                           f"6,440 (6,000 asked) {ROUND_UP_MARK} | EPYC, 2 cores, backend cpu, no GPU used | "
                           "2 seeds trained together: 2.00 h (1.00 h per seed) | 1.00 |")
    assert rows[i + 2] == ("| | | ours, `sumo_entry` (SUMO only), 4 seed(s) | 6,000 SUMO + 0 surrogate = "
                           "6,000 (6,000 asked) | EPYC, 2 cores, backend cpu, no GPU used | `s_s0`: 1.00 h; "
                           "`s_s1`: 2.00 h; `s_s2`: 3.00 h; 1 seed(s): wall time not recorded | 2.00 |")
    assert "| provins | QMIX | paper" in text and text.count("not run yet") == 2
