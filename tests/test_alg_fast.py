"""The urb-jax `fast` configs and the knobs they use: the PureJaxRL update schedule (Adam steps and
minibatch sizes, hand-computed and counted in the optimiser state) and QMIX's two-layer
hypernetwork (shape, monotonicity, numpy reference). URB's config1..5 keep URB's behaviour."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from standin import make_env
from support.mixer_reference import qmix_numpy

from urb_jax.algorithms import ippo, iql, qmix
from urb_jax.algorithms.configs import IQLConfig, MixerConfig, PPOConfig
from urb_jax.algorithms.learner import Day
from urb_jax.algorithms.qmix import QMixer
from urb_jax.algorithms.registry import ALGORITHMS, load_algo_config
from urb_jax.algorithms.updates import update_plan

TORCHRL = ("iql", "ippo", "mappo", "qmix", "vdn")


def test_fast_configs_load_for_every_algorithm():
    for alg in ALGORITHMS:
        config = load_algo_config(alg, "fast")
        assert isinstance(config, ALGORITHMS[alg].config_class)
        assert config.num_envs == 64
    for alg in TORCHRL:
        fast, urb = load_algo_config(alg, "fast"), load_algo_config(alg, "config1")
        assert fast.num_minibatches > 0 and urb.num_minibatches == 0
        assert fast.mlp_cells * fast.mlp_depth < urb.mlp_cells * urb.mlp_depth
    assert load_algo_config("qmix", "fast").hypernet_hidden > 0
    for i in range(1, 6):  # URB's configs keep URB's single-layer hypernetwork and per-CAV Q scale
        assert load_algo_config("qmix", f"config{i}").hypernet_hidden == 0
        assert load_algo_config("vdn", f"config{i}").q_scale == "team"
    assert {load_algo_config(a, "fast").q_scale for a in ("qmix", "vdn")} == {"own"}


def test_hybrid_configs_are_per_cav_with_urb_schedule():
    """configs/algo/<alg>/hybrid.json: URB's config1 schedule, one network per CAV, sized for 6,000
    days on 16 envs (the hybrid trainer's defaults)."""
    for alg in TORCHRL:
        hybrid, urb = load_algo_config(alg, "hybrid"), load_algo_config(alg, "config1")
        assert not hybrid.shared_parameters and urb.shared_parameters
        assert hybrid.agent_frames_per_batch == urb.agent_frames_per_batch
        assert hybrid.num_epochs == urb.num_epochs
        assert hybrid.lr == (1e-3 if alg == "vdn" else urb.lr)
        assert hybrid.num_envs * hybrid.n_iters * hybrid.agent_frames_per_batch >= 6000
    assert {load_algo_config(a, "hybrid").q_scale for a in ("qmix", "vdn")} == {"own"}


def test_update_plan_hand_computed():
    # URB: frames // minibatch_size steps of minibatch_size // C whole days; B = 64 -> 64x the steps
    assert update_plan(0, 256, 20, 88) == (6, 2)  # 20 * 88 // 256 = 6; 256 // 88 = 2
    assert update_plan(0, 256, 20 * 64, 88) == (440, 2)
    assert update_plan(0, 256, 1, 400) == (1, 1)  # at least one step of one day
    # PureJaxRL: num_minibatches steps, the minibatch grows with B
    assert update_plan(4, 256, 10, 88) == (4, 2)
    assert update_plan(4, 256, 10 * 64, 88) == (4, 160)
    assert update_plan(4, 256, 10 * 64, 88, capacity_days=100) == (4, 100)  # replay holds 100 days
    assert update_plan(8, 256, 3, 88) == (8, 1)


def adam_count(opt_state) -> int:
    return int(optax.tree_utils.tree_get(opt_state, "count"))


def fake_days(env, t: int, b: int, key: jax.Array) -> Day:
    c, d = env.n_cavs, env.obs_size
    k1, k2, k3 = jax.random.split(key, 3)
    obs = jax.random.uniform(k1, (t, b, c, d)) * 5.0
    action = jax.random.randint(k2, (t, b, c), 0, 2)
    reward = -jax.random.uniform(k3, (t, b, c))
    return Day(obs, action, reward, jnp.ones((t, b, c), bool), obs, jnp.zeros((t, b)), jnp.zeros((t, b)))


@pytest.fixture(scope="module")
def env(grid_scenario):
    return make_env(grid_scenario, cav_share=0.1)  # 40 CAVs


@pytest.mark.slow
@pytest.mark.parametrize(("num_minibatches", "n_envs"), [(0, 4), (3, 1), (3, 4)])
def test_adam_steps_per_update(env, num_minibatches, n_envs):
    """Counted in Adam's state: URB's count grows with B, the PureJaxRL count does not."""
    small = dict(agent_frames_per_batch=5, mlp_depth=1, mlp_cells=8, minibatch_size=80, num_envs=n_envs,
                 num_epochs=2, num_minibatches=num_minibatches)
    days = fake_days(env, 5, n_envs, jax.random.PRNGKey(0))
    frames = 5 * n_envs * env.n_cavs  # 200 per env
    urb_steps = 2 * (frames // 80)  # num_epochs x frames // minibatch_size
    expected = urb_steps if num_minibatches == 0 else 2 * num_minibatches
    cases = [
        (iql, IQLConfig(**small)),
        (qmix, MixerConfig(**small, mixing_embed_dim=4, hypernet_hidden=4)),
        (ippo, PPOConfig(**small, critic_depth=1, critic_cells=8)),
    ]
    for module, config in cases:
        learner = module.make_learner(config, env)
        runner = learner.init(jax.random.PRNGKey(1))
        runner, _ = jax.jit(learner.update_from_days)(runner, days, jax.random.PRNGKey(2))
        if module is ippo and num_minibatches == 0:  # PPO: minibatches of 2 days cover the batch
            assert adam_count(runner.opt_state) == 2 * (5 * n_envs // 2), module.__name__
        else:
            assert adam_count(runner.opt_state) == expected, module.__name__


def test_two_layer_hypernetwork_shape_reference_and_monotonicity():
    n_agents, embed, hidden, state_dim = 6, 5, 7, 11
    mixer = QMixer(n_agents=n_agents, embed_dim=embed, hypernet_hidden=hidden)
    params = mixer.init(jax.random.PRNGKey(0), jnp.zeros(n_agents), jnp.zeros(state_dim))
    shapes = {k: v["kernel"].shape for k, v in params["params"].items()}
    assert shapes["hyper_w1_hidden"] == (state_dim, hidden)
    assert shapes["hyper_w1"] == (hidden, n_agents * embed)
    assert shapes["hyper_w2_hidden"] == (state_dim, hidden) and shapes["hyper_w2"] == (hidden, embed)
    single = QMixer(n_agents=n_agents, embed_dim=embed).init(jax.random.PRNGKey(0), jnp.zeros(n_agents),
                                                             jnp.zeros(state_dim))
    assert single["params"]["hyper_w1"]["kernel"].shape == (state_dim, n_agents * embed)
    value_and_grad = jax.jit(jax.value_and_grad(lambda qq, ss: mixer.apply(params, qq, ss)))
    for i in range(6):
        kq, ks = jax.random.split(jax.random.PRNGKey(i + 1))
        q = jax.random.normal(kq, (n_agents,)) * 3.0
        s = jax.random.normal(ks, (state_dim,))
        value, grad = value_and_grad(q, s)
        assert float(value) == pytest.approx(qmix_numpy(params, np.asarray(q), np.asarray(s)), rel=1e-5,
                                             abs=1e-5)
        assert bool((grad >= 0).all()) and bool((grad > 0).any())
    batch_q = jax.random.normal(jax.random.PRNGKey(9), (3, 4, n_agents))
    batch_s = jax.random.normal(jax.random.PRNGKey(10), (3, 4, state_dim))
    assert mixer.apply(params, batch_q, batch_s).shape == (3, 4)
    assert bool((params["params"]["hyper_w1"]["kernel"] < 0).any())  # the abs makes it monotonic


@pytest.mark.parametrize("shared", [True, False])
def test_mappo_critic_one_value_per_cav_without_sharing(env, shared):
    """URB broadcasts one team value with shared parameters; per-CAV parameters give each CAV its
    own value head on the global state."""
    config = PPOConfig(mlp_depth=1, mlp_cells=8, critic_depth=1, critic_cells=8, shared_parameters=shared)
    _, critic_init, critic_apply = ippo.make_networks(config, env, centralised=True)
    params = critic_init(jax.random.PRNGKey(0))
    obs = jax.random.uniform(jax.random.PRNGKey(1), (3, env.n_cavs, env.obs_size)) * 100.0
    values = np.asarray(critic_apply(params, obs))
    assert values.shape == (3, env.n_cavs)
    spread = values.max(-1) - values.min(-1)
    if shared:
        assert np.all(spread == 0.0)
    else:
        assert np.all(spread > 0.0)
        assert params["params"]["Dense_1"]["kernel"].shape == (8, env.n_cavs)
