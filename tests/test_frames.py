"""URB's TorchRL frames rebuilt from days (algorithms/frames.py): frame observations, emitted
actions, rewards and dones against hand-built cases; frame sampling; the update count of a frame
learner; config checks."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from standin import make_env

from urb_jax.algorithms import ippo, iql, qmix
from urb_jax.algorithms.buffer import buffer_add, buffer_init
from urb_jax.algorithms.configs import IQLConfig, MixerConfig, PPOConfig
from urb_jax.algorithms.frames import (
    FrameDay,
    emit_frame_actions,
    expand_frames,
    sample_frames,
    turn_positions,
)
from urb_jax.algorithms.learner import Day
from urb_jax.core.errors import ConfigError

K = 2
TURN = jnp.array([2, 0, 1])  # CAV1 acts first, then CAV2, then CAV0
# acted-on observations [start, count_0, count_1] of 3 CAVs on one day
OBS = jnp.array([[[30.0, 1.0, 1.0], [10.0, 0.0, 0.0], [20.0, 1.0, 0.0]]])
ACTION = jnp.array([[1, 0, 1]])
REWARD = jnp.array([[-3.0, -1.0, -2.0]])


def one_day() -> Day:
    return Day(OBS, ACTION, REWARD, jnp.ones((1, 3), bool), OBS + 100.0, jnp.zeros((1,)), jnp.zeros((1,)))


def test_expand_frames_hand_built():
    emitted = jnp.array([[[7, 0, 7], [7, 0, 1], [1, 0, 1]]])  # [1 day, 3 frames, 3 CAVs]
    stored = FrameDay(one_day(), emitted)
    for j in range(3):
        frame = expand_frames(stored, jnp.array([j]), TURN, K)
        before = np.asarray(TURN) > j
        expect_obs = np.asarray(OBS[0]).copy()
        expect_obs[before, 1:] = 0.0  # not yet acted: start time, counts 0
        np.testing.assert_array_equal(np.asarray(frame.obs[0]), expect_obs)
        np.testing.assert_array_equal(np.asarray(frame.action[0]), np.asarray(emitted[0, j]))
        last = j == 2
        np.testing.assert_array_equal(np.asarray(frame.reward[0]), np.asarray(REWARD[0]) * last)
        assert np.asarray(frame.done[0]).tolist() == [last] * 3
        if not last:  # the next frame's observations (in the last frame done stops the bootstrap)
            nxt = expand_frames(stored, jnp.array([j + 1]), TURN, K)
            np.testing.assert_array_equal(np.asarray(frame.next_obs), np.asarray(nxt.obs))


def q_table(obs):
    """Q values that prefer route 1 on an acted observation (counts > 0) and route 0 before it."""
    acted = obs[..., 1:].sum(-1, keepdims=True) > 0
    return jnp.where(acted, jnp.array([0.0, 1.0]), jnp.array([1.0, 0.0]))


def test_emitted_actions_greedy_and_exploring():
    mask = jnp.ones((3, K), bool)
    greedy = emit_frame_actions(jax.random.PRNGKey(0), q_table, mask, jnp.asarray(0.0), one_day(), TURN, K)
    # frame j: the turn CAV executes its action; earlier-turn CAVs re-emit greedy on their acted obs
    # (route 1, or 0 for CAV1 whose acted obs has zero counts); later-turn CAVs greedy on the reset obs (0)
    expect = np.array([[0, 0, 0],
                       [0, 0, 1],
                       [1, 0, 1]])
    np.testing.assert_array_equal(np.asarray(greedy[0]), expect)
    mask = jnp.array([[True, False], [True, True], [True, True]])  # CAV0 has one valid route
    days = jax.tree.map(lambda x: jnp.repeat(x, 400, axis=0), one_day())  # Day.active None: no leaf
    eps = jnp.asarray(1.0)
    drawn = np.asarray(emit_frame_actions(jax.random.PRNGKey(1), q_table, mask, eps, days, TURN, K))
    for cav, turn in enumerate(np.asarray(TURN)):
        np.testing.assert_array_equal(drawn[:, turn, cav], int(ACTION[0, cav]))  # executed at its turn
    assert set(np.unique(drawn[:, :2, 0])) == {0}  # never an invalid route
    others = drawn[:, 1:, 1]  # CAV1 (turn 0) in frames 1, 2: uniform over its 2 routes
    assert 0.4 < others.mean() < 0.6


def test_sample_frames_distinct_and_within_stored_days():
    day = one_day()
    frame_id = jnp.broadcast_to(jnp.arange(3)[None, :, None], (1, 3, 3)).astype(jnp.int32)  # action = frame
    buf = buffer_init(jax.tree_util.tree_map(lambda x: x[0], FrameDay(day, frame_id)), 4)
    buf = buffer_add(buf, FrameDay(day, frame_id))
    buf = buffer_add(buf, FrameDay(day._replace(reward=day.reward * 10.0), frame_id + 10))  # day 2: 10+frame
    batch = sample_frames(buf, jax.random.PRNGKey(3), 6, TURN, K)  # 2 stored days x 3 frames, none repeated
    assert sorted(int(a) for a in batch.action[:, 0]) == [0, 1, 2, 10, 11, 12]
    rewards = {int(a): float(r) for a, r in zip(batch.action[:, 0], batch.reward.sum(-1), strict=True)}
    assert rewards == {0: 0.0, 1: 0.0, 2: -6.0, 10: 0.0, 11: 0.0, 12: -60.0}  # the last frames only


@pytest.fixture(scope="module")
def env(grid_scenario):
    return make_env(grid_scenario, cav_share=0.1)  # 40 CAVs


def test_turn_order_follows_departure(env):
    turn = turn_positions(env)
    assert sorted(turn.tolist()) == list(range(env.n_cavs))
    depart = np.asarray(env.scenario.agent_depart)[env.cav_index]
    by_turn = np.empty_like(depart)
    by_turn[turn] = depart
    assert np.all(np.diff(by_turn) >= 0)


@pytest.mark.parametrize("module", [iql, qmix])
def test_frame_learner_makes_urbs_update_count_on_frame_minibatches(env, module):
    small = dict(agent_frames_per_batch=3, mlp_depth=1, mlp_cells=8, minibatch_size=32, num_epochs=2,
                 frames="urb")
    config = (IQLConfig(**small) if module is iql
              else MixerConfig(**small, mixing_embed_dim=4, hypernet_hidden=4))
    learner = module.make_learner(config, env)
    runner = learner.init(jax.random.PRNGKey(0))
    assert runner.buffer.data.frame_actions.shape[1:] == (env.n_cavs, env.n_cavs)
    runner, metrics = jax.jit(learner.iteration)(runner, jax.random.PRNGKey(1))
    assert int(optax.tree_utils.tree_get(runner.opt_state, "count")) == 2 * (3 * env.n_cavs // 32)
    assert np.isfinite(float(metrics["loss"])) and float(metrics["loss"]) > 0.0


def test_frames_config_checked():
    with pytest.raises(ConfigError, match="'frames' is 'turns'"):
        IQLConfig(frames="turns")
    with pytest.raises(ConfigError, match="num_minibatches"):
        MixerConfig(frames="urb", num_minibatches=4)


def test_ppo_frames_gae_across_a_days_frames():
    """Critic 0, lambda 1: every row's advantage is gamma^(frames to the day's end) x its day reward,
    so the executed decision of an early CAV sees its reward discounted C - 1 - turn times."""
    days = jax.tree.map(lambda x: jnp.stack([x, x]), one_day())  # [T=2, B=1, C=3, ...]
    logits = lambda obs: jnp.zeros((*obs.shape[:-1], K))  # noqa: E731
    values = lambda obs: jnp.zeros(obs.shape[:-1])  # noqa: E731
    batch = ippo.frame_batch(logits, values, days, TURN, K, jax.random.PRNGKey(0), 0.5, 1.0)
    assert batch.obs.shape == (2 * 3, 1, 3, 3) and batch.action.shape == (6, 1, 3)
    adv = np.asarray(batch.advantage[:, 0])  # [T * Cf, C] in play order
    for day in range(2):
        for j in range(3):
            np.testing.assert_allclose(adv[3 * day + j], 0.5 ** (2 - j) * np.asarray(REWARD[0]), rtol=1e-6)
    acted = np.asarray(batch.action[:, 0])
    for cav, turn in enumerate(np.asarray(TURN)):  # the executed action in the CAV's turn frame
        assert acted[turn, cav] == ACTION[0, cav] and acted[3 + turn, cav] == ACTION[0, cav]
    np.testing.assert_allclose(np.asarray(batch.log_prob), np.log(0.5), rtol=1e-6)


def test_ppo_frame_learner_update_count(env):
    config = PPOConfig(agent_frames_per_batch=2, mlp_depth=1, mlp_cells=8, critic_depth=1, critic_cells=8,
                       minibatch_size=32, num_epochs=2, frames="urb")
    for centralised in (False, True):
        learner = ippo.make_learner(config, env, centralised)
        runner = learner.init(jax.random.PRNGKey(0))
        runner, metrics = jax.jit(learner.iteration)(runner, jax.random.PRNGKey(1))
        assert int(optax.tree_utils.tree_get(runner.opt_state, "count")) == 2 * (2 * env.n_cavs // 32)
        assert np.isfinite(float(metrics["loss"]))
