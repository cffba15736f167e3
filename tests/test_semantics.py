"""Human model, CAV rewards and observations on hand-computed cases."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from urb_jax.core.errors import ConfigError
from urb_jax.game.humans import HumanParams, HumanState, act, init_humans, learn
from urb_jax.game.observations import make_observation_spec, observe
from urb_jax.game.rewards import BEHAVIOURS, behaviour_coefficients, cav_rewards

KEY = jax.random.PRNGKey(0)


def _two_route_humans(params, cost=((3.0, 4.0),)):
    cost = jnp.asarray(cost, dtype=jnp.float32)
    n = cost.shape[0]
    return HumanState(cost, jnp.full((n,), params.beta), jnp.full((n,), -1, jnp.int32),
                      jnp.full((n, 2, params.remember), jnp.nan))


def test_gawron_two_routes_hand_computed():
    """FFT 3 and 4 min. Day 1: route 0 (argmin), takes 6 min -> C0 = 0.8*3 + 0.2*6 = 3.6.
    Day 2: still route 0 (3.6 < 4), takes 6 -> C0 = 0.8*3.6 + 0.2*6 = 4.08. Day 3: route 1."""
    p = HumanParams()
    s = _two_route_humans(p)
    a = act(KEY, s, p)
    assert int(a[0]) == 0
    s = learn(KEY, s, a, jnp.array([6.0]), p)
    assert float(s.cost[0, 0]) == pytest.approx(3.6) and float(s.cost[0, 1]) == pytest.approx(4.0)
    a = act(KEY, s, p)
    assert int(a[0]) == 0
    s = learn(KEY, s, a, jnp.array([6.0]), p)
    assert float(s.cost[0, 0]) == pytest.approx(4.08)
    assert int(act(KEY, s, p)[0]) == 1


def test_initial_knowledge_is_free_flow_and_masks_invalid_routes():
    fft = jnp.array([[3.0, 2.0, 5.0]])
    valid = jnp.array([[True, False, True]])
    p = HumanParams(beta=-1.5, beta_randomness=0.1)
    s = init_humans(KEY, fft, valid, p)
    assert float(s.cost[0, 0]) == 3.0 and not np.isfinite(float(s.cost[0, 1]))
    assert -1.6 <= float(s.beta[0]) <= -1.4
    assert int(act(KEY, s, p)[0]) == 0  # route 1 is faster but masked


def test_routerl_literal_beta_sign_picks_slowest():
    p = HumanParams(routerl_literal=True)  # beta -1.5, as URB's task configs
    assert int(act(KEY, _two_route_humans(p), p)[0]) == 1
    p_pos = HumanParams(routerl_literal=True, beta=1.5)
    assert int(act(KEY, _two_route_humans(p_pos), p_pos)[0]) == 0


def test_stochastic_logit_probabilities():
    """p0 = 1 / (1 + exp(-|beta| (4 - 3))) with beta = -1.5 -> 0.8176."""
    p = HumanParams(deterministic=False, beta_randomness=0.0)
    s = _two_route_humans(p, cost=[(3.0, 4.0)] * 20000)
    share0 = float((act(KEY, s, p) == 0).mean())
    assert share0 == pytest.approx(1 / (1 + np.exp(-1.5)), abs=0.01)


def test_switching_threshold_keeps_yesterdays_route():
    p = HumanParams(gamma_c=0.1)
    s = _two_route_humans(p, cost=[(3.8, 4.0)])._replace(last_action=jnp.array([1], jnp.int32))
    assert int(act(KEY, s, p)[0]) == 1  # 3.8 is not 10% better than 4.0
    s = s._replace(cost=jnp.array([[3.5, 4.0]]))
    assert int(act(KEY, s, p)[0]) == 0


def test_update_threshold_and_frozen_agents():
    p = HumanParams(gamma_u=0.5)
    s = _two_route_humans(p)
    s2 = learn(KEY, s, jnp.array([0]), jnp.array([4.0]), p)  # |4-3| <= 1.5: no update
    assert float(s2.cost[0, 0]) == 3.0
    s3 = learn(KEY, s, jnp.array([0]), jnp.array([9.0]), p)
    assert float(s3.cost[0, 0]) == pytest.approx(0.8 * 3 + 0.2 * 9)
    frozen = learn(KEY, s, jnp.array([0]), jnp.array([9.0]), HumanParams(), learning=False)
    assert float(frozen.cost[0, 0]) == 3.0 and int(frozen.last_action[0]) == 0


def test_unknown_model_is_a_config_error():
    with pytest.raises(ConfigError, match="human_model 'gawrom'"):
        HumanParams(model="gawrom")


# ---- rewards: a day with CAVs A (4 min), B (6 min) and humans C (5 min), D (9 min)
TIMES = jnp.array([4.0, 6.0, 5.0, 9.0])
IS_CAV = jnp.array([True, True, False, False])
T_CAV, T_HUM, T_ALL = 5.0, 7.0, 6.0
EXPECTED_A = {
    "selfish": -4.0, "competitive": -8.0 + T_HUM, "collaborative": -2.0 - 0.5 * T_CAV,
    "cooperative": -T_CAV, "social": -2.0 - 0.5 * T_ALL, "altruistic": -T_ALL,
    "malicious": T_HUM, "collectivist": -0.4 - 0.9 * T_CAV, "militant": -2 * T_CAV + T_HUM,
}


@pytest.mark.parametrize("behaviour", sorted(BEHAVIOURS))
def test_each_behaviour_reward_hand_computed(behaviour):
    r = cav_rewards(TIMES, IS_CAV, behaviour_coefficients(behaviour))
    assert float(r[0]) == pytest.approx(EXPECTED_A[behaviour])


def test_custom_tuple_and_empty_groups():
    r = cav_rewards(TIMES, jnp.ones(4, bool), behaviour_coefficients([0, 0, 1, 0]))
    assert float(r[0]) == 0.0  # no humans: their mean counts as 0
    with pytest.raises(ConfigError, match="unknown av_behavior"):
        behaviour_coefficients("greedy")
    batched = cav_rewards(jnp.stack([TIMES, TIMES + 1]), IS_CAV, behaviour_coefficients("cooperative"))
    assert batched.shape == (2, 4) and float(batched[1, 0]) == -(T_CAV + 1)


# ---- observations on a hand-made day: agents (od, depart, action)
OD = np.array([0, 0, 1, 0, 0, 1])
DEPART = np.array([10, 20, 20, 20, 30, 40])
ACTIONS = jnp.array([2, 1, 3, 0, 1, 0])


def test_previous_agents_plus_start_time():
    spec = make_observation_spec("previous_agents_plus_start_time", OD, DEPART, 4)
    obs = np.asarray(observe(spec, ACTIONS))
    expected = np.array([
        [10, 0, 0, 0, 0],
        [20, 0, 0, 1, 0],  # agent 0 (od 0, t 10) chose 2; agent 3 departs at the same second
        [20, 0, 0, 0, 0],
        [20, 0, 0, 1, 0],
        [30, 1, 1, 1, 0],  # agents 0, 1, 3 of od 0 departed earlier
        [40, 0, 0, 0, 1],  # agent 2 (od 1) chose 3
    ])
    assert obs.shape == (6, spec.size) and np.array_equal(obs, expected)


def test_previous_agents_and_global_variant():
    counts = np.asarray(observe(make_observation_spec("previous_agents", OD, DEPART, 4), ACTIONS))
    assert counts.shape == (6, 4) and counts[4].tolist() == [1, 1, 1, 0]
    glob = np.asarray(observe(make_observation_spec("global_previous_agents", OD, DEPART, 4), ACTIONS))
    assert glob[5].tolist() == [40, 1, 2, 1, 1]  # actions 2,1,3,0,1 before second 40
    assert glob[1].tolist() == [20, 0, 0, 1, 0]
    with pytest.raises(ConfigError):
        make_observation_spec("trip_info_eta", OD, DEPART, 4)


def test_observe_is_jittable():
    spec = make_observation_spec("previous_agents_plus_start_time", OD, DEPART, 4)
    assert np.array_equal(jax.jit(lambda a: observe(spec, a))(ACTIONS), observe(spec, ACTIONS))
