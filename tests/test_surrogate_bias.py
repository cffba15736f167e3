"""The per-(agent, route) SUMO residual correction (`surrogate.calibrate.route_bias`)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from urb_jax.surrogate.calibrate import SumoSample, route_bias, without_bias
from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict


@pytest.fixture(scope="module")
def grid(grid_scenario):
    static = build_static(grid_scenario, SurrogateConfig(chunk=32))
    return grid_scenario, static, init_params(static)


def _sample(scn, static, params, days=5, seed=0):
    rng = np.random.default_rng(seed)
    choices = rng.integers(0, scn.k, (days, scn.n_agents)).astype(np.int32)
    choices[:, 0] = 1  # agent 0 always drives route 1
    pred = np.asarray(predict(params, static, jnp.asarray(choices)))
    # "SUMO": the model plus a known per-(agent, route) offset and day noise
    offset = rng.normal(0, 0.5, (scn.n_agents, scn.k))
    times = pred + offset[np.arange(scn.n_agents), choices] + rng.normal(0, 0.05, choices.shape)
    arrived = np.ones_like(choices, bool)
    arrived[2, 3] = False  # a removed vehicle carries a penalty, not a travel time
    return SumoSample(choices, times.astype(np.float32), arrived), offset


def test_bias_is_the_shrunk_mean_residual_of_driven_routes(grid):
    scn, static, params = grid
    sample, _ = _sample(scn, static, params)
    prior = 2.0
    bias = np.asarray(route_bias(params, static, sample, prior))
    pred = np.asarray(predict(params, static, jnp.asarray(sample.choices)))
    for n in (0, 3, 17, scn.n_agents - 1):  # hand loop over days
        for k in range(scn.k):
            rows = [d for d in range(len(sample)) if sample.choices[d, n] == k and sample.arrived[d, n]]
            expect = sum(sample.travel_time[d, n] - pred[d, n] for d in rows) / (len(rows) + prior)
            assert bias[n, k] == pytest.approx(expect, abs=1e-5)
    assert np.all(bias[0, [0, 2, 3]] == 0.0)  # routes never driven keep the model's estimate


def test_predict_adds_the_bias_for_choices_and_probabilities(grid):
    scn, static, params = grid
    sample, offset = _sample(scn, static, params, days=40)
    with_b = {**params, "route_bias": route_bias(params, static, sample, 0.0)}
    ch = jnp.asarray(sample.choices[:3])
    base = np.asarray(predict(params, static, ch))
    corrected = np.asarray(predict(with_b, static, ch))
    b = np.asarray(with_b["route_bias"])
    assert np.isfinite(b).all() and b[0, 0] == 0.0  # no shrinkage: undriven routes stay 0, not 0/0
    np.testing.assert_allclose(corrected - base, b[np.arange(scn.n_agents), sample.choices[:3]], atol=1e-5)
    # with no shrinkage the corrected model recovers the known offsets on driven routes
    assert abs(b[0, 1] - offset[0, 1]) < 0.05
    onehot = jnp.eye(scn.k)[ch]
    probs = 0.5 * onehot + 0.5 / scn.k  # mixed: the bias enters as its expectation
    delta = np.asarray(predict(with_b, static, probs)) - np.asarray(predict(params, static, probs))
    np.testing.assert_allclose(delta, (np.asarray(probs) * b[None]).sum(-1), atol=1e-4)
    assert set(without_bias(with_b)) == set(params)


def test_removed_days_count_at_their_charged_time_when_asked(grid):
    """Agent 3 was removed on day 2 with 20 min charged: left out by default, counted with `removed`;
    a driver at home (ABSENT, NaN) never counts."""
    scn, static, params = grid
    sample, _ = _sample(scn, static, params)
    times, choices = sample.travel_time.copy(), sample.choices.copy()
    times[2, 3] = 20.0  # the time charged for the removal (sumo_bridge: elapsed until removed)
    choices[1, 5], times[1, 5] = -1, np.nan  # at home on day 1
    arrived = sample.arrived.copy()
    arrived[1, 5] = False
    jammed = SumoSample(choices, times, arrived)
    pred = np.asarray(predict(params, static, jnp.asarray(np.maximum(choices, 0))))
    prior, k = 2.0, choices[2, 3]
    rows = [d for d in range(len(jammed)) if choices[d, 3] == k]  # day 2 among them
    arrived_only = [d for d in rows if arrived[d, 3]]
    plain = np.asarray(route_bias(params, static, jammed, prior))
    counted = np.asarray(route_bias(params, static, jammed, prior, removed=True))
    assert plain[3, k] == pytest.approx(sum(times[d, 3] - pred[d, 3] for d in arrived_only)
                                        / (len(arrived_only) + prior), abs=1e-5)
    assert counted[3, k] == pytest.approx(sum(times[d, 3] - pred[d, 3] for d in rows) / (len(rows) + prior),
                                          abs=1e-5)
    assert counted[3, k] > plain[3, k] + 1.0  # the stuck day makes the route look as costly as scored
    np.testing.assert_array_equal(np.delete(counted, 3, axis=0), np.delete(plain, 3, axis=0))  # others
