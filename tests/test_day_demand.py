"""Demand varying day to day (task key day_participation): who travels is reproducible and
changes between days; a driver who stays home has no SUMO vehicle, no surrogate flow, is not
observed, does not learn, and its CAV's row is left out of the losses; runs that cannot honour
the option refuse it."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_alg_env import fft_plus_half_flow, tiny_scenario

from urb_jax.algorithms.configs import IQLConfig, MixerConfig
from urb_jax.algorithms.learner import Day, active_mean
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import TaskConfig
from urb_jax.game.demand import ABSENT, DayDemand, present_on
from urb_jax.game.env import RoutingEnv
from urb_jax.game.humans import HumanParams, end_day, init_humans
from urb_jax.runs.setup import check_day_demand
from urb_jax.sumo_bridge import ARRIVED, day_key, run_day
from urb_jax.sumo_bridge.types import STAYED_HOME
from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict_jit


def test_who_travels_is_a_pure_function_of_seed_day_and_agent():
    a = np.asarray(present_on(42, 0.7, 5, 200))
    np.testing.assert_array_equal(a, np.asarray(present_on(42, 0.7, 5, 200)))  # reproducible
    np.testing.assert_array_equal(a[:50], np.asarray(present_on(42, 0.7, 5, 50)))  # agent i: its own draw
    np.testing.assert_array_equal(a, np.asarray(jax.jit(lambda d: present_on(42, 0.7, d, 200))(5)))
    assert not np.array_equal(a, np.asarray(present_on(42, 0.7, 6, 200)))  # another day, others
    assert not np.array_equal(a, np.asarray(present_on(43, 0.7, 5, 200)))  # another env seed
    assert 0.6 < a.mean() < 0.8
    assert np.asarray(present_on(42, 1.0, 5, 200)).all()


def _day_where(demand: DayDemand, pattern: list[bool]) -> int:
    """The first day index whose travellers are `pattern` (the draw is seeded, so this is fixed)."""
    for d in range(256):
        if np.asarray(demand.present(d, len(pattern))).tolist() == pattern:
            return d
    raise AssertionError(f"no day in 0..255 with travellers {pattern}")


def _tiny_env(demand: DayDemand | None, adapt: bool = False) -> RoutingEnv:
    """Agents 0 (CAV, 0 s), 1 (human, 10 s), 2 (CAV, 20 s) of one OD; time = fft + 0.5 x flow."""
    scn = tiny_scenario()
    return RoutingEnv(scn, np.array([True, False, True]), fft_plus_half_flow(scn),
                      HumanParams(model="gawron", alpha=0.5), humans_adapt=adapt, day_demand=demand)


def test_a_cav_who_stays_home_is_not_observed_and_carries_no_flow():
    demand = DayDemand(seed=3, participation=0.5)
    env = _tiny_env(demand)
    _, state = env.reset(jax.random.PRNGKey(0))
    d = _day_where(demand, [False, True, True])  # CAV 0 stays home
    state = state._replace(day=jnp.asarray(d, jnp.int32), human_actions=jnp.array([0, 0, 0], jnp.int32))
    cavs = jnp.array([1, 0])  # CAV 0 would take the 2-min route, CAV 2 the 1-min one
    np.testing.assert_array_equal(env.joint_actions(state, cavs), [ABSENT, 0, 0])
    np.testing.assert_array_equal(env.active(state), [False, True])
    # CAV 2 (20 s) sees only the human (10 s) on route 0: CAV 0's route 1 is not there today
    np.testing.assert_array_equal(env.observe(state, cavs)[1], [20.0, 1.0, 0.0, 0.0])
    _, _, rewards, _, info = env.step(jax.random.PRNGKey(1), state, cavs)
    # route 0 carries the human and CAV 2: 1 + 0.5 x 2 = 2 min each; CAV 0 has no time and no reward
    np.testing.assert_allclose(info["times"], [0.0, 2.0, 2.0])
    np.testing.assert_allclose(rewards, [0.0, -2.0])
    np.testing.assert_array_equal(info["active"], [False, True])
    assert float(info["mean_time_cav"]) == 2.0 and float(info["mean_time_human"]) == 2.0
    # fixed demand, the same day: everyone travels and CAV 0 is observed
    fixed = _tiny_env(None)
    np.testing.assert_array_equal(fixed.observe(state, cavs)[1], [20.0, 1.0, 1.0, 0.0])


def test_a_human_who_stayed_home_keeps_its_expectations():
    demand = DayDemand(seed=3, participation=0.5)
    env = _tiny_env(demand, adapt=True)
    _, state = env.reset(jax.random.PRNGKey(0))
    cost0 = np.asarray(state.humans.cost[1])  # free flow: [1, 2, inf]
    home = _day_where(demand, [True, False, True])
    away = _day_where(demand, [True, True, True])
    for d, expect_cost, expect_last in ((home, cost0[0], -1), (away, 0.5 * 1.0 + 0.5 * 2.0, 0)):
        s = state._replace(day=jnp.asarray(d, jnp.int32), human_actions=jnp.array([0, 0, 0], jnp.int32))
        _, after, _, _, _ = env.step(jax.random.PRNGKey(1), s, jnp.array([1, 0]))
        assert float(after.humans.cost[1, 0]) == pytest.approx(expect_cost)  # route 0: gawron, alpha 0.5
        assert float(after.humans.cost[1, 1]) == cost0[1]
        assert int(after.humans.last_action[1]) == expect_last  # home: yesterday's route (none yet)
    # the rule itself: only travellers learn, CAVs never
    hp = HumanParams(model="gawron", alpha=0.5)
    fft = jnp.array([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0]])
    h = init_humans(jax.random.PRNGKey(0), fft, jnp.ones((3, 2), bool), hp)._replace(
        last_action=jnp.array([1, 1, 1], jnp.int32))
    out = end_day(jax.random.PRNGKey(2), h, jnp.array([0, ABSENT, 0]), jnp.array([3.0, jnp.nan, 3.0]), hp,
                  np.array([False, False, True]), learn_today=True, travelled=jnp.array([True, False, True]))
    np.testing.assert_allclose(out.cost, [[2.0, 2.0], [1.0, 2.0], [1.0, 2.0]])
    np.testing.assert_array_equal(out.last_action, [0, 1, 0])


def test_an_absent_driver_has_no_sumo_vehicle(grid_scenario):
    scn = grid_scenario
    choices = np.zeros(scn.n_agents, np.int64)
    absent = np.zeros(scn.n_agents, bool)
    absent[::3] = True
    res = run_day(scn, np.where(absent, ABSENT, choices), seed=42)
    assert (res.status[absent] == STAYED_HOME).all() and (res.status[~absent] == ARRIVED).all()
    assert np.isnan(res.travel_time[absent]).all() and np.isfinite(res.travel_time[~absent]).all()
    assert np.isnan(res.route_length[absent]).all() and res.n_removed == 0
    full = run_day(scn, choices, seed=42)
    assert res.travel_time[~absent].mean() <= full.travel_time[~absent].mean()  # less traffic
    # the day store's key holds who travelled: never a day made with other demand
    assert day_key(scn, np.where(absent, ABSENT, choices), 42, None, None) != day_key(scn, choices, 42, None,
                                                                                     None)


def test_an_absent_driver_carries_no_surrogate_flow(grid_scenario):
    scn = grid_scenario
    static = build_static(scn, SurrogateConfig(chunk=32))
    params = init_params(static)
    params = {**params, "log_a_c": params["log_a_c"] + 2.0}  # congested: flows matter
    ch = np.random.default_rng(0).integers(0, scn.k, scn.n_agents).astype(np.int32)
    absent = np.random.default_rng(1).random(scn.n_agents) < 0.3
    with_absent = np.asarray(predict_jit(params, static, jnp.asarray(np.where(absent, ABSENT, ch))))
    probs = np.eye(scn.k, dtype=np.float32)[ch] * ~absent[:, None]  # the absent rows: no weight anywhere
    no_flow = np.asarray(predict_jit(params, static, jnp.asarray(probs)))
    np.testing.assert_allclose(with_absent[~absent], no_flow[~absent], rtol=1e-5)
    full = np.asarray(predict_jit(params, static, jnp.asarray(ch)))
    assert (with_absent[~absent] <= full[~absent] + 1e-6).all()
    assert (with_absent[~absent] < full[~absent]).any()


def test_losses_leave_out_the_cavs_who_stayed_home():
    x = jnp.array([[1.0, 100.0], [3.0, 5.0]])
    assert float(active_mean(x, None)) == pytest.approx(27.25)
    assert float(active_mean(x, jnp.array([[True, False], [True, True]]))) == pytest.approx(3.0)
    assert Day.zeros(2, 3).active is None and Day.zeros(2, 3, active=True).active.shape == (2,)
    assert len(jax.tree_util.tree_leaves(Day.zeros(2, 3))) == 7  # fixed demand: the same pytree as before


def test_task_option_range_and_refusals():
    assert TaskConfig().day_demand(42) is None
    assert TaskConfig(day_participation=0.9).day_demand(42) == DayDemand(42, 0.9)
    for bad in (0.0, 1.5):
        with pytest.raises(ConfigError, match="day_participation"):
            TaskConfig(day_participation=bad)
    task, path = TaskConfig(day_participation=0.9), Path("task.json")
    check_day_demand(task, path, train=True, alg="iql", alg_config=IQLConfig())
    with pytest.raises(ConfigError, match="supported by `urb-jax train` and the aon and random baselines"):
        check_day_demand(task, path, train=False)
    with pytest.raises(ConfigError, match="algorithm 'qmix'"):
        check_day_demand(task, path, train=True, alg="qmix", alg_config=MixerConfig())
    with pytest.raises(ConfigError, match="frames 'urb'"):
        check_day_demand(task, path, train=True, alg="iql", alg_config=IQLConfig(frames="urb"))
    with pytest.raises(ConfigError, match="reward_credit"):
        check_day_demand(TaskConfig(day_participation=0.9, reward_credit="marginal"), path, train=True,
                         alg="iql", alg_config=IQLConfig())
