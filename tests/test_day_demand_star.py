"""Demand varying day to day (task key day_participation) for URB's bandit-style IQL* and IPPO* and
for the AON and random baselines: a CAV at home stores no sample and does not update, a CAV's
buffer holds exactly the days it travelled, IPPO*'s loss averages over travelled rows only, and a
baseline's absent drivers simply do not travel (no vehicle, NaN reward), on hand-computed cases."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from support.fakeday import FakeDay
from test_alg_env import fft_plus_half_flow, tiny_scenario

from urb_jax.algorithms import ippo_star, iql_star
from urb_jax.algorithms.baselines import make_baseline
from urb_jax.algorithms.buffer import buffer_add_where, buffer_init_columns
from urb_jax.algorithms.configs import IPPOStarConfig, IQLStarConfig, MixerConfig
from urb_jax.algorithms.learner import Day
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.demand import ABSENT, DayDemand, present_on
from urb_jax.game.env import RoutingEnv
from urb_jax.game.humans import HumanParams, aon_routes
from urb_jax.runs.setup import check_day_demand
from urb_jax.sumo_bridge.types import ARRIVED, STAYED_HOME
from urb_jax.training.protocol import PHASE_HUMAN, run_experiment


def test_column_buffer_keeps_each_columns_rows_in_order_fifo():
    buf = buffer_init_columns(jnp.zeros((2,)), capacity=3, n_columns=2)
    rows = jnp.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [4.0, 40.0]])
    keep = jnp.array([[True, False], [False, True], [True, False], [True, False]])
    buf = buffer_add_where(buf, rows, keep)
    np.testing.assert_array_equal(buf.data, [[1.0, 20.0], [3.0, 0.0], [4.0, 0.0]])
    np.testing.assert_array_equal(buf.pos, [0, 1])
    np.testing.assert_array_equal(buf.size, [3, 1])
    buf = buffer_add_where(buf, jnp.array([[5.0, 50.0]]), jnp.array([[True, True]]))
    np.testing.assert_array_equal(buf.data, [[5.0, 20.0], [3.0, 50.0], [4.0, 0.0]])  # column 0: 1 replaced
    np.testing.assert_array_equal(buf.pos, [1, 2])
    np.testing.assert_array_equal(buf.size, [3, 2])
    # more kept rows than capacity: the newest 3 (c, d, e at ranks 2, 3, 4 -> places 2, 0, 1)
    buf = buffer_add_where(buffer_init_columns(jnp.zeros((1,)), 3, 1), jnp.arange(1.0, 6.0)[:, None],
                           jnp.ones((5, 1), bool))
    np.testing.assert_array_equal(buf.data[:, 0], [4.0, 5.0, 3.0])
    assert int(buf.pos[0]) == 2 and int(buf.size[0]) == 3
    # a column that keeps nothing is as it was
    same = buffer_add_where(buf, jnp.array([[9.0]]), jnp.array([[False]]))
    np.testing.assert_array_equal(same.data, buf.data)
    assert int(same.pos[0]) == 2 and int(same.size[0]) == 3


HALF = DayDemand(seed=3, participation=0.5)


def _demand_env(demand: DayDemand | None = HALF) -> RoutingEnv:
    """tiny_scenario: agents 0 (CAV), 1 (human), 2 (CAV) of one OD; time = fft + 0.5 x flow."""
    scn = tiny_scenario()
    return RoutingEnv(scn, np.array([True, False, True]), fft_plus_half_flow(scn),
                      HumanParams(model="gawron", alpha=0.5), day_demand=demand)


def _day(env: RoutingEnv, obs: np.ndarray, action: list[int], reward: list[float], active: list[bool]) -> Day:
    """One day [T=1, B=1, C] with the given per-CAV values."""
    c = env.n_cavs
    return Day(jnp.asarray(obs, jnp.float32)[None, None], jnp.asarray(action, jnp.int32)[None, None],
               jnp.asarray(reward, jnp.float32)[None, None], jnp.ones((1, 1, c), bool),
               jnp.asarray(obs, jnp.float32)[None, None], jnp.zeros((1, 1)), jnp.zeros((1, 1)),
               jnp.asarray(active)[None, None])


def _rows_equal(tree_a, tree_b, row: int) -> bool:
    return all(bool(jnp.array_equal(a[row], b[row])) for a, b in
               zip(jax.tree_util.tree_leaves(tree_a), jax.tree_util.tree_leaves(tree_b), strict=True))


def test_iql_star_a_cav_at_home_stores_nothing_and_does_not_update():
    env = _demand_env()
    config = IQLStarConfig(batch_size=1, buffer_size=4, eps_decay=0.5, lr=0.01)
    learner = iql_star.make_learner(config, env)
    runner = learner.init(jax.random.PRNGKey(0))
    assert runner.buffer.size.shape == (2,)  # one ring per CAV
    obs = np.array([[0.0, 1.0, 0.0, 0.0], [20.0, 0.0, 1.0, 0.0]])
    _, apply, _, _ = iql_star.make_network(config, env)
    q = np.asarray(apply(runner.params, jnp.asarray(obs, jnp.float32)))  # [C, K] before the update
    # day 1: CAV 0 at home, CAV 1 travels on route 1 and is paid -2.5
    after, metrics = learner.update_from_days(runner, _day(env, obs, [0, 1], [0.0, -2.5], [False, True]),
                                              jax.random.PRNGKey(1))
    np.testing.assert_array_equal(after.buffer.size, [0, 1])
    assert float(after.buffer.data.reward[0, 1]) == -2.5 and int(after.buffer.data.action[0, 1]) == 1
    assert _rows_equal(after.params, runner.params, 0) and _rows_equal(after.opt_state, runner.opt_state, 0)
    assert not _rows_equal(after.params, runner.params, 1)
    # the loss is CAV 1's own: (Q(s, 1) + 2.5)^2 on its one sample, CAV 0 not in the mean
    assert float(metrics["loss"]) == pytest.approx((q[1, 1] + 2.5) ** 2, rel=1e-5)
    assert float(after.eps) == pytest.approx(0.5)  # one update: eps_init 1 x eps_decay 0.5
    # day 2: both at home: nothing changes, epsilon does not decay
    home, _ = learner.update_from_days(after, _day(env, obs, [1, 0], [0.0, 0.0], [False, False]),
                                       jax.random.PRNGKey(2))
    np.testing.assert_array_equal(home.buffer.size, [0, 1])
    assert _rows_equal(home.params, after.params, 0) and _rows_equal(home.params, after.params, 1)
    assert float(home.eps) == pytest.approx(0.5)
    # day 3: CAV 0 travels; with one sample it updates now, CAV 1 (at home) keeps its network
    third, _ = learner.update_from_days(home, _day(env, obs, [1, 0], [-1.0, 0.0], [True, False]),
                                        jax.random.PRNGKey(3))
    np.testing.assert_array_equal(third.buffer.size, [1, 1])
    assert not _rows_equal(third.params, home.params, 0) and _rows_equal(third.params, home.params, 1)


def test_iql_star_fixed_demand_keeps_one_shared_ring():
    learner = iql_star.make_learner(IQLStarConfig(), _demand_env(None))
    assert learner.init(jax.random.PRNGKey(0)).buffer.size.shape == ()


def test_ippo_star_loss_averages_over_travelled_rows_only():
    logits = jnp.array([[0.3, -0.2], [1.0, 0.5], [-0.4, 0.2], [0.0, 0.9]])
    action = jnp.array([0, 1, 1, 0])
    old = jnp.array([-0.8, -0.6, -0.5, -1.2])
    reward = jnp.array([-2.0, -3.0, -1.5, -4.0])
    args = (0.2, 0.01)
    for normalize in (True, False):
        full = ippo_star.bandit_ppo_loss(logits, action, old, reward, *args, normalize)
        assert float(ippo_star.weighted_ppo_loss(logits, action, old, reward, jnp.ones(4), *args, normalize)
                     ) == pytest.approx(float(full), rel=1e-5)
        rows = jnp.array([0, 2, 3])
        part = ippo_star.bandit_ppo_loss(logits[rows], action[rows], old[rows], reward[rows], *args,
                                         normalize)
        weighted = ippo_star.weighted_ppo_loss(logits, action, old, reward, jnp.array([1.0, 0.0, 1.0, 1.0]),
                                               *args, normalize)
        assert float(weighted) == pytest.approx(float(part), rel=1e-5)
    # by hand, unnormalised, ratio 1 (old = the current log-prob): -mean(A) + 0 entropy
    logp = jax.nn.log_softmax(logits)[jnp.arange(4), action]
    w = jnp.array([1.0, 1.0, 0.0, 0.0])
    assert float(ippo_star.weighted_ppo_loss(logits, action, logp, reward, w, 0.2, 0.0, False)) == \
        pytest.approx(2.5, rel=1e-6)


def test_ippo_star_a_cav_at_home_every_day_does_not_update():
    env = _demand_env()
    config = IPPOStarConfig(batch_size=2, update_every=1, num_envs=1, num_epochs=2)
    learner = ippo_star.make_learner(config, env)
    runner = learner.init(jax.random.PRNGKey(0))
    obs = np.array([[0.0, 1.0, 0.0, 0.0], [20.0, 0.0, 1.0, 0.0]])
    one = _day(env, obs, [0, 1], [-1.0, -2.5], [False, True])
    two = _day(env, obs, [1, 0], [-2.0, -1.0], [False, True])
    days = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), one, two)  # [T=2, B=1, C]
    after, metrics = learner.update_from_days(runner, days, jax.random.PRNGKey(1))
    assert _rows_equal(after.params, runner.params, 0) and _rows_equal(after.opt_state, runner.opt_state, 0)
    assert not _rows_equal(after.params, runner.params, 1)
    assert np.isfinite(float(metrics["loss"]))


TINY = TaskConfig(ratio_machines=0.25, human_learning_episodes=3, training_eps=3, test_eps=2,
                  day_participation=0.7)


@pytest.mark.parametrize("model", ["aon", "random"])
def test_baseline_absent_drivers_do_not_travel(grid_scenario, model):
    scn, seed = grid_scenario, 7
    fake, records = FakeDay(), []
    out = run_experiment(scn, TINY, EnvConfig(), make_baseline(model), env_seed=seed, executor=fake,
                         sink=records.append)
    aon = aon_routes(scn.fft, scn.route_valid)
    for rec in records:
        choices = np.asarray(rec.choices)
        if rec.phase == PHASE_HUMAN:  # the human phase keeps URB's fixed demand
            assert (choices >= 0).all()
            continue
        # record day r is the day after the env state's day r - 1 (the first CAV day follows day H)
        home = ~np.asarray(present_on(seed, 0.7, rec.day - 1, scn.n_agents))
        assert 0 < home.sum() < scn.n_agents
        np.testing.assert_array_equal(choices == ABSENT, home)
        assert (rec.result.status[home] == STAYED_HOME).all() and (rec.result.status[~home] == ARRIVED).all()
        assert np.isnan(rec.rewards[home]).all() and np.isfinite(rec.rewards[~home]).all()
        went_cav = out.is_cav & ~home
        if model == "aon":
            np.testing.assert_array_equal(choices[went_cav], aon[went_cav])
        # SUMO (here the stand-in) saw the day's joint choices, absent drivers as ABSENT
        np.testing.assert_array_equal(fake.calls[rec.day - 1][0], choices)


def test_refusals_name_what_supports_varying_demand():
    task, path = TaskConfig(day_participation=0.9), Path("task.json")
    for alg, conf in (("iql_star", IQLStarConfig()), ("ippo_star", IPPOStarConfig())):
        check_day_demand(task, path, train=True, alg=alg, alg_config=conf)
    for model in ("aon", "random"):
        check_day_demand(task, path, train=False, baseline=model)
    with pytest.raises(ConfigError, match=r"not by the 'human' baseline.*--model aon or random"):
        check_day_demand(task, path, train=False, baseline="human")
    with pytest.raises(ConfigError, match="not by a policy run outside"):
        check_day_demand(task, path, train=False)
    with pytest.raises(ConfigError, match="algorithm 'vdn'"):
        check_day_demand(task, path, train=True, alg="vdn", alg_config=MixerConfig())
