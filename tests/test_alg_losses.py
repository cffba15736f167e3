"""Each algorithm's loss on a tiny batch against hand-computed values, plus the shared pieces
(GAE, ring buffer, masking, schedules)."""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from support.mixer_reference import qmix_jnp, qmix_numpy

from urb_jax.algorithms.buffer import buffer_add, buffer_init, buffer_sample
from urb_jax.algorithms.configs import MixerConfig
from urb_jax.algorithms.ippo import Batch, ppo_loss
from urb_jax.algorithms.ippo_star import bandit_ppo_loss
from urb_jax.algorithms.iql import td_loss
from urb_jax.algorithms.iql_star import bandit_loss
from urb_jax.algorithms.learner import Day
from urb_jax.algorithms.networks import WideDense
from urb_jax.algorithms.policy import eps_greedy, linear_schedule
from urb_jax.algorithms.qmix import QMixer, VDNMixer, mixed_td_loss
from urb_jax.algorithms.updates import clip_by_global_norm, gae, polyak
from urb_jax.core.errors import ConfigError

MASK = jnp.array([[True, True, False], [True, True, True]])  # CAV0 has 2 distinct routes


def day_batch(reward, done) -> Day:
    """One day, two CAVs; Q tables come from the fake q_apply below, observations are unused."""
    z = jnp.zeros((1, 2, 4))
    return Day(z, jnp.array([[1, 2]]), jnp.array([reward], jnp.float32), jnp.array([done]), z + 1.0,
               jnp.zeros((1,)), jnp.zeros((1,)))


Q_ONLINE = jnp.array([[[1.0, 2.0, 3.0], [0.5, 0.0, -1.0]]])
Q_TARGET = jnp.array([[[4.0, 1.0, 9.0], [2.0, 3.0, 1.0]]])  # 9.0 is a masked route


def fake_q(params, obs):
    return params


def test_td_target_bootstraps_masked_max_unless_done():
    batch = day_batch([1.0, -1.0], [False, True])
    loss = td_loss(fake_q, Q_ONLINE, Q_TARGET, batch, MASK, gamma=0.9)
    y = np.array([1.0 + 0.9 * 4.0, -1.0])  # CAV0: max over valid routes is 4 (not 9); CAV1 done
    q_a = np.array([2.0, -1.0])
    assert float(loss) == pytest.approx(np.mean((q_a - y) ** 2))


def test_vdn_sums_agent_values_on_team_reward():
    batch = day_batch([-2.0, -4.0], [False, False])
    params = {"agent": Q_ONLINE, "mixer": {}}
    target = {"agent": Q_TARGET, "mixer": {}}
    vdn = VDNMixer()
    loss = mixed_td_loss(fake_q, vdn.apply, params, target, batch, MASK, 0.5, lambda o: o.reshape(1, -1))
    q_tot = 2.0 + (-1.0)
    y = -3.0 + 0.5 * (4.0 + 3.0)  # team reward = mean, target: sum of masked maxima
    assert float(loss) == pytest.approx((q_tot - y) ** 2)


def test_own_q_scale_feeds_q_over_c_to_the_mixer():
    batch = day_batch([-2.0, -4.0], [False, False])
    params = {"agent": Q_ONLINE, "mixer": {}}
    target = {"agent": Q_TARGET, "mixer": {}}
    loss = mixed_td_loss(fake_q, VDNMixer().apply, params, target, batch, MASK, 0.5,
                         lambda o: o.reshape(1, -1), q_scale=0.5)
    q_tot = (2.0 + (-1.0)) / 2  # VDN with own-scale Qs: Q_tot = mean of the chosen Qs
    y = -3.0 + 0.5 * (4.0 + 3.0) / 2  # mean team reward, bootstrap from the mean of the maxima
    assert float(loss) == pytest.approx((q_tot - y) ** 2)
    with pytest.raises(ConfigError, match="'q_scale' is 'sum'"):
        MixerConfig(q_scale="sum")


def test_agent_credit_adds_each_cavs_own_td_error():
    batch = day_batch([-2.0, -4.0], [False, False])
    params = {"agent": Q_ONLINE, "mixer": {}}
    target = {"agent": Q_TARGET, "mixer": {}}
    args = (fake_q, VDNMixer().apply, params, target, batch, MASK, 0.5, lambda o: o.reshape(1, -1))
    base = float(mixed_td_loss(*args, q_scale=0.5))
    with_credit = float(mixed_td_loss(*args, q_scale=0.5, agent_credit=0.3))
    # own scale (C = 2, q_scale 1/2): Q_i targets its own reward + gamma * its masked max
    y_i = np.array([-2.0 + 0.5 * 4.0, -4.0 + 0.5 * 3.0])
    per_agent = np.mean((np.array([2.0, -1.0]) - y_i) ** 2)
    assert with_credit == pytest.approx(base + 0.3 * per_agent)
    # team scale: Q_i stands for 1/C of the team reward, so its own target is reward / C
    team = float(mixed_td_loss(*args, q_scale=1.0, agent_credit=1.0)) - float(mixed_td_loss(*args))
    y_team = np.array([-2.0 / 2 + 0.5 * 4.0, -4.0 / 2 + 0.5 * 3.0])
    assert team == pytest.approx(np.mean((np.array([2.0, -1.0]) - y_team) ** 2))
    with pytest.raises(ConfigError, match="'agent_credit' is -1"):
        MixerConfig(agent_credit=-1)


def test_qmix_mixer_matches_reference_and_is_monotonic():
    mixer = QMixer(n_agents=3, embed_dim=5)
    key = jax.random.PRNGKey(0)
    params = mixer.init(key, jnp.zeros(3), jnp.zeros(7))
    for i in range(5):
        kq, ks = jax.random.split(jax.random.PRNGKey(i + 1))
        q = jax.random.normal(kq, (3,)) * 3.0
        s = jax.random.normal(ks, (7,))
        expected = qmix_numpy(params, np.asarray(q), np.asarray(s))
        assert float(mixer.apply(params, q, s)) == pytest.approx(expected, rel=1e-5, abs=1e-5)
        grad = jax.grad(lambda qq, s=s: mixer.apply(params, qq, s))(q)
        assert bool((grad >= 0).all())
    raw = params["params"]["hyper_w1"]["kernel"]
    assert bool((raw < 0).any())  # monotonicity comes from the abs, not from lucky weights


def test_wide_dense_is_dense_with_the_same_gradients():
    """WideDense only changes how the kernel's gradient is laid out: same parameters, outputs and
    gradients as nn.Dense, with and without leading axes, and under vmap (seeds)."""
    wide, plain = WideDense(6, name="w"), nn.Dense(6, name="w")
    params = plain.init(jax.random.PRNGKey(0), jnp.zeros(5))
    assert jax.tree_util.tree_structure(wide.init(jax.random.PRNGKey(0), jnp.zeros(5))) == \
        jax.tree_util.tree_structure(params)
    for shape in [(5,), (1, 5), (4, 5), (2, 3, 5)]:
        x = jax.random.normal(jax.random.PRNGKey(len(shape)), shape)
        g = jax.random.normal(jax.random.PRNGKey(7), (*shape[:-1], 6))

        def loss(p, x, layer, g=g):
            return jnp.sum(jnp.sin(layer.apply(p, x)) * g)

        np.testing.assert_array_equal(wide.apply(params, x), plain.apply(params, x))
        got, want = jax.grad(loss, (0, 1))(params, x, wide), jax.grad(loss, (0, 1))(params, x, plain)
        for a, b in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    seeds = jax.vmap(lambda k: plain.init(k, jnp.zeros(5)))(jax.random.split(jax.random.PRNGKey(1), 3))
    x = jax.random.normal(jax.random.PRNGKey(2), (3, 4, 5))
    got = jax.vmap(jax.grad(lambda p, x: jnp.sum(wide.apply(p, x) ** 2)))(seeds, x)
    want = jax.vmap(jax.grad(lambda p, x: jnp.sum(plain.apply(p, x) ** 2)))(seeds, x)
    for a, b in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("hidden", [0, 4])
def test_qmix_mixer_gradients_match_plain_autodiff(hidden):
    """The mixer's parameter gradients (hypernetworks through kernel_layout_dot) equal JAX's autodiff
    of the same mixer written with plain matrix products, on a minibatch of 3 days."""
    mixer = QMixer(n_agents=3, embed_dim=5, hypernet_hidden=hidden)
    params = mixer.init(jax.random.PRNGKey(0), jnp.zeros(3), jnp.zeros(7))
    kq, ks = jax.random.split(jax.random.PRNGKey(3))
    q, s = jax.random.normal(kq, (3, 3)) * 3.0, jax.random.normal(ks, (3, 7))
    np.testing.assert_allclose(mixer.apply(params, q, s), qmix_jnp(params, q, s), rtol=1e-5, atol=1e-5)
    got = jax.grad(lambda p: jnp.sum(mixer.apply(p, q, s) ** 2))(params)
    want = jax.grad(lambda p: jnp.sum(qmix_jnp(p, q, s) ** 2))(params)
    for a, b in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


def test_clip_by_global_norm_follows_optax_rule():
    """Above max_norm the whole tree is scaled to norm max_norm (optax's rule, the same values for
    max_norm 1); below it, gradients pass unchanged."""
    tree = {"a": jnp.array([3.0, -4.0]), "b": jnp.array([[12.0]])}  # global norm 13
    for max_norm in (1.0, 2.5, 20.0):
        got, _ = clip_by_global_norm(max_norm).update(tree, optax.EmptyState())
        want, _ = optax.clip_by_global_norm(max_norm).update(tree, optax.EmptyState())
        np.testing.assert_allclose(float(optax.tree.norm(got)), min(13.0, max_norm), rtol=1e-6)
        for a, b in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6)
            if max_norm in (1.0, 20.0):
                np.testing.assert_array_equal(a, b)


def test_ppo_clipping_hand_computed():
    logits = jnp.zeros((1, 2, 2))  # pi(a) = 0.5 for both CAVs
    old = jnp.log(jnp.array([[1.0 / 3.0, 1.0 / 3.0]]))  # ratio = 1.5 for both
    batch = Batch(jnp.zeros((1, 2, 1)), jnp.array([[0, 1]]), old, jnp.array([[2.0, -2.0]]),
                  jnp.array([[1.0, 3.0]]))
    values = jnp.array([[0.5, 0.0]])
    total, aux = ppo_loss(logits, values, batch, clip_eps=0.2, entropy_coef=0.1, critic_coef=1.0)
    # A=+2: min(1.5*2, 1.2*2) = 2.4 (clipped); A=-2: min(-3, -2.4) = -3 (unclipped)
    policy = -(2.4 - 3.0) / 2
    value = (0.5 * 0.5**2 + (3.0 - 0.5)) / 2  # smooth L1: quadratic below 1, linear above
    ent = math.log(2.0)
    assert float(aux["policy_loss"]) == pytest.approx(policy)
    assert float(aux["value_loss"]) == pytest.approx(value)
    assert float(total) == pytest.approx(policy + value - 0.1 * ent, rel=1e-6)
    # the clipped sample passes no gradient to the actor
    grad = jax.grad(lambda lg: ppo_loss(lg, values, batch, 0.2, 0.0, 1.0)[1]["policy_loss"])(logits)
    np.testing.assert_allclose(grad[0, 0], 0.0, atol=1e-7)
    assert float(jnp.abs(grad[0, 1]).sum()) > 0


def test_ippo_star_standardises_rewards_and_iql_star_regresses_reward():
    logits = jnp.zeros((2, 2))
    old = jnp.log(jnp.array([0.5, 0.5]))  # ratio 1
    loss = bandit_ppo_loss(logits, jnp.array([0, 1]), old, jnp.array([-1.0, -3.0]), 0.2, 0.0, True)
    assert float(loss) == pytest.approx(0.0, abs=1e-6)  # standardised advantages +1, -1 cancel
    loss_raw = bandit_ppo_loss(logits, jnp.array([0, 1]), old, jnp.array([-1.0, -3.0]), 0.2, 0.0, False)
    assert float(loss_raw) == pytest.approx(2.0)
    q = jnp.array([[1.0, 2.0], [0.0, -1.0]])
    assert float(bandit_loss(q, jnp.array([1, 0]), jnp.array([0.0, 1.0]))) == pytest.approx((4.0 + 1.0) / 2)


def test_gae_hand_computed():
    rewards = jnp.array([[1.0], [2.0]])
    values = jnp.array([[0.5], [1.0]])
    adv, ret = gae(rewards, values, jnp.array([[False], [False]]), jnp.array([3.0]), gamma=0.9, lmbda=0.8)
    d1 = 2.0 + 0.9 * 3.0 - 1.0
    d0 = 1.0 + 0.9 * 1.0 - 0.5
    np.testing.assert_allclose(adv[:, 0], [d0 + 0.9 * 0.8 * d1, d1], rtol=1e-6)
    np.testing.assert_allclose(ret, adv + values)
    adv_done, _ = gae(rewards, values, jnp.array([[True], [True]]), jnp.array([3.0]), 0.9, 0.8)
    np.testing.assert_allclose(adv_done[:, 0], [0.5, 1.0])  # one-day episodes: reward - value


def test_ring_buffer_fifo_and_sampling():
    buf = buffer_init({"x": jnp.zeros(2)}, capacity=4)
    buf = buffer_add(buf, {"x": jnp.arange(6.0).reshape(3, 2)})
    assert int(buf.size) == 3
    buf = buffer_add(buf, {"x": jnp.arange(6.0, 12.0).reshape(3, 2)})
    assert int(buf.size) == 4 and int(buf.pos) == 2
    np.testing.assert_array_equal(buf.data["x"][:, 0], [8.0, 10.0, 4.0, 6.0])  # oldest two overwritten
    big = buffer_add(buf, {"x": jnp.arange(20.0).reshape(10, 2)})  # more than capacity: newest 4 stay
    assert sorted(np.asarray(big.data["x"][:, 0]).tolist()) == [12.0, 14.0, 16.0, 18.0]
    small = buffer_add(buffer_init({"x": jnp.zeros(())}, 10), {"x": jnp.arange(1.0, 4.0)})
    for i in range(10):
        got = np.asarray(buffer_sample(small, jax.random.PRNGKey(i), 3)["x"])
        assert sorted(got.tolist()) == [1.0, 2.0, 3.0]  # distinct, only filled slots


def test_eps_greedy_masks_and_schedule():
    q = jnp.array([[0.0, 1.0, 5.0]] * 2000)
    mask = jnp.array([[True, True, False]] * 2000)
    greedy = eps_greedy(jax.random.PRNGKey(0), q, mask, 0.0)
    np.testing.assert_array_equal(greedy, 1)  # the masked 5.0 is never taken
    explore = np.asarray(eps_greedy(jax.random.PRNGKey(0), q, mask, 1.0))
    assert set(np.unique(explore)) == {0, 1} and 0.4 < explore.mean() < 0.6
    sched = linear_schedule(1.0, 0.1, 100)
    np.testing.assert_allclose([sched(0.0), sched(50.0), sched(500.0)], [1.0, 0.55, 0.1], rtol=1e-6)
    np.testing.assert_allclose(polyak(jnp.array(1.0), jnp.array(3.0), 0.75), 1.5)
