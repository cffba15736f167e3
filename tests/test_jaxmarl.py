"""The routing game as a JaxMARL MultiAgentEnv (urb_jax.interop.jaxmarl) and SUMO test days for
outside policies (run_policy, FixedPolicy). The env's travel times here come from a small
congestion model (the adapter does not care what simulates the day; the surrogate itself is tested
in test_surrogate_*), so each test compiles in seconds."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeDay

from urb_jax.algorithms.baselines import FixedPolicy
from urb_jax.game.env import RoutingEnv
from urb_jax.game.humans import aon_routes
from urb_jax.game.mutation import draw_cavs
from urb_jax.reporting.records import read_records
from urb_jax.runs.baseline import run_baseline, run_policy
from urb_jax.runs.request import BaselineRequest

jaxmarl = pytest.importorskip("jaxmarl", reason="the JaxMARL extra: pip install 'urb-jax[jaxmarl]'")
from jaxmarl.environments.multi_agent_env import MultiAgentEnv  # noqa: E402
from jaxmarl.wrappers.baselines import LogWrapper  # noqa: E402

from urb_jax.interop.jaxmarl import JaxMARLRoutingEnv  # noqa: E402


def congested_env(scn) -> RoutingEnv:
    """Free-flow time x scale x (1 + share of everyone on the same route index): rewards depend on
    the joint action and on the parameters."""
    fft = jnp.asarray(scn.fft_full)

    def times(params, choices):
        load = jnp.bincount(choices, length=scn.k)[choices] / scn.n_agents
        return fft[jnp.arange(scn.n_agents), choices] * params["scale"] * (1.0 + load)

    # 10% CAVs (40): a JaxMARL env has a dict entry per agent, and XLA's compile time grows with them
    return RoutingEnv(scn, draw_cavs(42, scn.n_agents, 0.1, agent_id=scn.agent_id), times,
                      default_params={"scale": jnp.asarray(1.3)})


@pytest.fixture(scope="module")
def game(grid_scenario):
    return congested_env(grid_scenario)


def random_actions(key, env):
    routes = jax.random.randint(key, (env.num_agents,), 0, env.action_space(env.agents[0]).n)
    return {a: routes[i] for i, a in enumerate(env.agents)}


def test_the_env_keeps_multiagentenvs_contract(game):
    env = JaxMARLRoutingEnv(game, od_onehot=True)
    assert isinstance(env, MultiAgentEnv)
    assert env.num_agents == game.n_cavs == len(set(env.agents))
    assert env.agents == [f"cav_{int(i)}" for i in game.scenario.agent_id[game.cav_index]]
    assert env.agent_classes == {"cav": env.agents}
    n_ods = len(np.unique(game.cav_od))
    obs, state = env.reset(jax.random.PRNGKey(0))
    assert set(obs) == set(env.agents)
    for a in env.agents:
        assert env.action_space(a).n == game.n_actions
        assert obs[a].shape == env.observation_space(a).shape == (game.obs_size + n_ods,)
        assert bool(env.observation_space(a).contains(obs[a]))
        assert float(obs[a][game.obs_size:].sum()) == 1.0  # the OD one-hot
    actions = random_actions(jax.random.PRNGKey(2), env)
    obs2, _, rewards, dones, infos = env.step(jax.random.PRNGKey(1), state, actions)
    assert set(obs2) == set(rewards) == set(env.agents) and set(dones) == {*env.agents, "__all__"}
    assert all(r.shape == () and r.dtype == jnp.float32 for r in rewards.values())
    assert bool(dones["__all__"]) and all(bool(dones[a]) for a in env.agents)  # a day ends every episode
    assert infos["travel_time"].shape == (env.num_agents,)
    np.testing.assert_allclose(-np.asarray(infos["travel_time"]), [rewards[a] for a in env.agents])  # selfish
    avail = env.get_avail_actions(state)
    np.testing.assert_array_equal(np.stack([avail[a] for a in env.agents]), game.action_mask)


def test_rewards_and_days_are_urb_jaxs_own(game):
    """The same joint actions and key give RoutingEnv.step's rewards, next day and observations (up to
    the last bit of float32: two separately compiled programs)."""
    env = JaxMARLRoutingEnv(game)
    game_step = jax.jit(game.step)
    obs, state = env.reset(jax.random.PRNGKey(3))
    _, day = game.reset(jax.random.PRNGKey(3))
    np.testing.assert_array_equal(np.stack([obs[a] for a in env.agents]),
                                  game.observe(day, day.cav_actions) / env.scale)
    for t in range(3):  # the world goes on from day to day (no auto-reset)
        actions = random_actions(jax.random.PRNGKey(10 + t), env)
        joint = jnp.stack([actions[a] for a in env.agents])
        key = jax.random.PRNGKey(20 + t)
        obs, state, rewards, _, _ = env.step(key, state, actions)
        _, day, want, _, _ = game_step(key, day, joint, game.default_params)
        np.testing.assert_allclose([rewards[a] for a in env.agents], want, rtol=1e-6)
        for a, b in zip(jax.tree_util.tree_leaves(state.day), jax.tree_util.tree_leaves(day), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6)
        np.testing.assert_array_equal(state.day.cav_actions, joint)
        np.testing.assert_array_equal(state.day.human_actions, day.human_actions)
        np.testing.assert_array_equal(np.stack([obs[a] for a in env.agents]),
                                      game.observe(day, joint) / env.scale)
    assert int(state.day.day) == 3
    other = env.step(key, state._replace(params={"scale": jnp.asarray(2.6)}), actions)  # no recompile needed
    np.testing.assert_allclose(np.asarray(other[4]["travel_time"]),
                               2 * np.asarray(env.step(key, state, actions)[4]["travel_time"]), rtol=1e-6)


@pytest.mark.slow
def test_steps_jit_vmap_and_scan(game):
    """Vmapped envs under lax.scan (how JaxMARL's scripts roll out) give each env's own unbatched days."""
    env = JaxMARLRoutingEnv(game)
    B, T = 3, 4
    _, states = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(5), B))

    def day(states, key):
        k_act, k_step = jax.random.split(key)
        acts = jax.vmap(lambda k: random_actions(k, env))(jax.random.split(k_act, B))
        _, states, rewards, _, _ = jax.vmap(env.step)(jax.random.split(k_step, B), states, acts)
        return states, jnp.stack([rewards[a] for a in env.agents], axis=-1)  # [B, C]

    keys = jax.random.split(jax.random.PRNGKey(6), T)
    _, rewards = jax.jit(lambda s: jax.lax.scan(day, s, keys))(states)  # [T, B, C]
    b = 1
    _, state = env.reset(jax.random.split(jax.random.PRNGKey(5), B)[b])
    for t in range(T):
        k_act, k_step = jax.random.split(keys[t])
        acts = random_actions(jax.random.split(k_act, B)[b], env)
        _, state, r, _, _ = env.step(jax.random.split(k_step, B)[b], state, acts)
        np.testing.assert_allclose([r[a] for a in env.agents], rewards[t, b], rtol=1e-6)


def test_jaxmarls_log_wrapper_sees_one_day_episodes(game):
    env = LogWrapper(JaxMARLRoutingEnv(game))
    _, state = env.reset(jax.random.PRNGKey(0))
    for t in range(2):
        actions = random_actions(jax.random.PRNGKey(9 + t), env)
        _, state, rewards, _, info = env.step(jax.random.PRNGKey(t), state, actions)
        np.testing.assert_allclose(info["returned_episode_returns"], [rewards[a] for a in env.agents])
        assert np.all(info["returned_episode_lengths"] == 1) and np.all(info["returned_episode"])
    assert int(state.env_state.day.day) == 2


def test_policy_maps_urb_jax_observations_to_the_agents_features(game):
    env = JaxMARLRoutingEnv(game, od_onehot=True)
    obs, state = env.reset(jax.random.PRNGKey(0))
    seen = []
    policy = env.policy(lambda key, x: seen.append(x) or jnp.zeros(x.shape[0], jnp.int32))
    raw = game.observe(state.day, state.day.cav_actions)
    idx = jnp.asarray([4, 0, 7])
    policy(jax.random.PRNGKey(0), raw[idx], idx)
    np.testing.assert_array_equal(seen[0], np.stack([obs[env.agents[i]] for i in [4, 0, 7]]))


TINY = {"human_learning_episodes": 3, "training_eps": 0, "test_eps": 2}


def test_an_outside_policy_runs_urbs_test_days(tmp_path):
    """run_policy with a FixedPolicy that returns each CAV's AON route writes the same days and metrics
    as the AON baseline; the policy sees the env's observations in departure order."""
    from urb_jax.city.scenario import load_scenario

    scn = load_scenario("urb_grid")
    aon = jnp.asarray(aon_routes(scn.fft, scn.route_valid)[np.flatnonzero(
        draw_cavs(42, scn.n_agents, 0.4, agent_id=scn.agent_id))])
    shapes = []

    def policy(key, obs, idx=None):
        shapes.append(obs.shape)
        return aon if idx is None else aon[idx]

    req = BaselineRequest(results_dir=str(tmp_path), progress=False)
    ours = run_policy(FixedPolicy(policy, "aon_fn"), req, executor=FakeDay(), task_overrides=TINY)
    base = run_baseline(BaselineRequest(model="aon", results_dir=str(tmp_path), progress=False),
                        executor=FakeDay(), task_overrides=TINY)
    assert ours.folder.name == "aon_fn_urb_grid_config1_s42"
    pd.testing.assert_frame_equal(read_records(ours.folder), read_records(base.folder))
    np.testing.assert_equal(ours.metrics, base.metrics)  # NaN (no training day) equal too
    cfg = json.loads((ours.folder / "exp_config.json").read_text())
    assert cfg["algorithm"] == "aon_fn" and cfg["alg_config"] == "outside" and "baseline_model" not in cfg
    assert len(shapes) > 1 and all(len(s) == 2 and s[1] == scn.k + 1 for s in shapes)  # [n, D] per level
