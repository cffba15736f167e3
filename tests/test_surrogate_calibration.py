"""Calibration against a small SUMO sample on urb_grid, the refit path, and the SUMO-day cache."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from urb_jax.sumo_bridge.memo import load_day, save_day
from urb_jax.surrogate.calibrate import FitConfig, SumoSample, calibrate, refit
from urb_jax.surrogate.data import make_choices
from urb_jax.surrogate.model import build_static, init_params, predict_jit
from urb_jax.surrogate.sumo_days import sumo_days

pytestmark = pytest.mark.sumo


def _mape(params, static, sample: SumoSample) -> float:
    pred = np.asarray(predict_jit(params, static, jnp.asarray(sample.choices)))
    m = sample.arrived
    return float(np.mean(np.abs(pred - sample.travel_time)[m] / sample.travel_time[m]))


def _mean_err(params, static, sample: SumoSample) -> float:
    pred = np.asarray(predict_jit(params, static, jnp.asarray(sample.choices)))
    return float(np.mean(np.abs(pred.mean(1) - sample.travel_time.mean(1)) / sample.travel_time.mean(1)))


@pytest.fixture(scope="module")
def grid_days(grid_scenario):
    scn = grid_scenario
    static = build_static(scn)
    p0 = init_params(static)
    choices, _ = make_choices(scn, static, p0, 10, seed=5)
    days = sumo_days(scn, choices, 42, workers=1)
    assert all(d.n == scn.n_agents for d in days)
    sample = SumoSample.from_days(choices, days)
    train = SumoSample(sample.choices[:7], sample.travel_time[:7], sample.arrived[:7])
    test = SumoSample(sample.choices[7:], sample.travel_time[7:], sample.arrived[7:])
    return scn, static, p0, train, test, days


def test_calibration_reduces_held_out_error(grid_days):
    scn, static, p0, train, test, _ = grid_days
    params = calibrate(scn, train, fit=FitConfig(steps=200), static=static)
    before, after = _mape(p0, static, test), _mape(params, static, test)
    assert after < 0.8 * before, (before, after)
    assert _mean_err(params, static, test) < max(0.03, 0.5 * _mean_err(p0, static, test))
    # the data varies (joint actions of several kinds), not one day repeated
    assert np.unique(train.choices, axis=0).shape[0] == len(train)


def test_refit_moves_toward_new_days_and_stays_anchored(grid_days):
    scn, static, p0, train, test, _ = grid_days
    # equal sizes: one compiled fit serves both calibrations (shapes and FitConfig are the jit key)
    old = SumoSample(train.choices[:3], train.travel_time[:3], train.arrived[:3])
    new = SumoSample(train.choices[3:6], train.travel_time[3:6], train.arrived[3:6])
    params = calibrate(scn, old, fit=FitConfig(steps=150), static=static)
    updated = refit(params, scn, new, static=static)
    assert _mape(updated, static, new) <= _mape(params, static, new) + 1e-4
    assert _mape(updated, static, test) < _mape(p0, static, test)
    # anchored: a refit moves the smooth model's parameters less than a fresh fit from the textbook
    # start does (the route residual is not anchored: it is recomputed from the days each time)
    fresh = calibrate(scn, new, fit=FitConfig(steps=150), static=static)
    dist = lambda a, b: sum(float(((a[k] - b[k]) ** 2).sum()) for k in a if k != "route_bias")  # noqa: E731
    assert dist(updated, params) < dist(fresh, params)
    # sample concatenation for "all SUMO days so far"
    assert len(old + new) == 6


def test_day_cache_round_trip(grid_days, tmp_path):
    *_, days = grid_days
    path = tmp_path / "d.npz"
    save_day(path, days[0])
    back = load_day(path)
    np.testing.assert_array_equal(back.travel_time, days[0].travel_time)
    np.testing.assert_array_equal(back.status, days[0].status)
    assert back.seed == days[0].seed and back.teleports == days[0].teleports


def test_cached_days_are_reused(grid_days, monkeypatch, tmp_path):
    """With the SUMO day store on, asking again for the same days reads them back (the same
    record, wall time included, not a re-run), and they are the days SUMO gives without it."""
    monkeypatch.setenv("URB_JAX_DAY_STORE_GB", "1")
    monkeypatch.setenv("URB_JAX_CACHE", str(tmp_path))
    scn, static, p0, *_, days = grid_days
    choices, _ = make_choices(scn, static, p0, 10, seed=5)
    first = sumo_days(scn, choices[:2], 42, workers=1)
    again = sumo_days(scn, choices[:2], 42, workers=1)  # served from the store written above
    for a, b, off in zip(again, first, days[:2], strict=True):
        np.testing.assert_array_equal(a.travel_time, b.travel_time)
        np.testing.assert_array_equal(a.travel_time, off.travel_time)
        assert a.wall_time == b.wall_time  # identical record, not a re-run


def test_the_public_calibration_is_the_training_runs_own(grid_days):
    """`urb_jax.calibrate` gives exactly the surrogate a training run starts from on the same days
    (the smooth fit, then each driven (agent, route)'s residual shrunk by count / (count + 2))."""
    from urb_jax.surrogate.calibrate import uncalibrated, without_bias
    from urb_jax.training import human_phase
    from urb_jax.training.hybrid.plan import HybridConfig

    scn, static, _, train, _, _ = grid_days
    params = calibrate(scn, train, fit=FitConfig(steps=60), static=static)
    human = human_phase.HumanPhase(None, [], train.choices, train.travel_time, train.arrived)
    trained = human_phase.calibrate(uncalibrated(static), static, human, HybridConfig(calib_steps=60))
    assert params.keys() == trained.keys()
    for k in params:
        np.testing.assert_array_equal(np.asarray(params[k]), np.asarray(trained[k]), err_msg=k)
    # the residual by hand for one driven (agent, route): mean SUMO - smooth model over its days
    smooth = np.asarray(predict_jit(without_bias(params), static, jnp.asarray(train.choices)))
    agent, route = 0, int(train.choices[0, 0])
    days = (train.choices[:, agent] == route) & train.arrived[:, agent]
    res = (train.travel_time[days, agent] - smooth[days, agent]).sum() / (days.sum() + 2.0)
    assert float(params["route_bias"][agent, route]) == pytest.approx(res, rel=1e-4, abs=1e-5)
    plain = calibrate(scn, train, fit=FitConfig(steps=60), static=static, route_bias_prior_days=None)
    assert not np.asarray(plain["route_bias"]).any()
