"""Travel-time parameters are explicit step arguments (gymnax style), so a refit needs no
recompilation; measured times (SUMO) go through the same day transition."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.game.env import DayKeys, RoutingEnv
from urb_jax.game.humans import HumanParams
from urb_jax.game.mutation import draw_cavs


def scaled_env(scn, traces):
    fft = jnp.asarray(scn.fft_full)

    def tt(params, choices):
        traces.append(1)
        return fft[jnp.arange(scn.n_agents), choices] * params["scale"]

    return RoutingEnv(scn, draw_cavs(0, scn.n_agents, 0.4), tt, default_params={"scale": jnp.asarray(1.0)})


def test_params_change_times_without_retracing(grid_scenario):
    traces = []
    env = scaled_env(grid_scenario, traces)
    _, state = env.reset(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    actions = jnp.zeros((env.n_cavs,), jnp.int32)
    _, _, r1, _, info1 = step(jax.random.PRNGKey(1), state, actions, env.default_params)
    _, _, r2, _, info2 = step(jax.random.PRNGKey(1), state, actions, {"scale": jnp.asarray(2.0)})
    assert np.allclose(np.asarray(info2["times"]), 2 * np.asarray(info1["times"]))
    assert np.allclose(np.asarray(r2), 2 * np.asarray(r1))  # selfish: reward = -own time
    assert len(traces) == 1
    _, _, _, _, info0 = env.step(jax.random.PRNGKey(1), state, actions)  # None: default_params
    np.testing.assert_array_equal(info0["times"], info1["times"])


def test_step_with_times_is_the_same_transition(grid_scenario):
    env = scaled_env(grid_scenario, [])
    _, state = env.reset(jax.random.PRNGKey(0))
    actions = jnp.ones((env.n_cavs,), jnp.int32)
    key = jax.random.PRNGKey(3)
    simulated = env.step(key, state, actions, {"scale": jnp.asarray(1.5)})
    measured = env.step_with_times(key, state, actions, simulated[4]["times"])
    for a, b in zip(jax.tree_util.tree_leaves(simulated), jax.tree_util.tree_leaves(measured), strict=True):
        np.testing.assert_array_equal(a, b)
    sumo_only = RoutingEnv(grid_scenario, env.is_cav)  # no travel_time_fn: its days come from outside
    replay = sumo_only.step_with_times(key, state, actions, simulated[4]["times"])
    np.testing.assert_array_equal(replay[1].human_actions, simulated[1].human_actions)


def test_explicit_day_keys_are_the_split_key_and_drive_the_humans(grid_scenario):
    """A caller with its own key schedule passes DayKeys: the split key gives the same day; other
    keys change only what the keys drive (tomorrow's stochastic human draws), not the rewards."""
    env = dataclasses.replace(scaled_env(grid_scenario, []), human_params=HumanParams(deterministic=False))
    _, state = env.reset(jax.random.PRNGKey(0))
    actions = jnp.ones((env.n_cavs,), jnp.int32)
    times = env.travel_times(None, env.joint_actions(state, actions))
    key = jax.random.PRNGKey(3)
    by_key = env.step_with_times(key, state, actions, times)
    by_keys = env.step_with_times(DayKeys(*jax.random.split(key)), state, actions, times)
    for a, b in zip(jax.tree_util.tree_leaves(by_key), jax.tree_util.tree_leaves(by_keys), strict=True):
        np.testing.assert_array_equal(a, b)
    other = env.step_with_times(DayKeys(*jax.random.split(jax.random.PRNGKey(4))), state, actions, times)
    np.testing.assert_array_equal(other[2], by_key[2])
    assert not np.array_equal(other[1].human_actions, by_key[1].human_actions)


def test_humans_learn_after_a_day_only_when_the_task_lets_them_adapt(grid_scenario):
    """One rule for every caller (the SUMO protocol, PettingZoo, the trainer): without adaptation
    the humans' expected times stay, even on a day without CAVs; with it they move."""
    no_cav = np.zeros(grid_scenario.n_agents, bool)
    fft = jnp.asarray(grid_scenario.fft_full)

    def tt(choices):
        return fft[jnp.arange(grid_scenario.n_agents), choices] * 3.0  # far from the free-flow guess

    for adapt in (False, True):
        env = RoutingEnv(grid_scenario, no_cav, tt, humans_adapt=adapt)
        _, state = env.reset(jax.random.PRNGKey(0))
        _, after, *_ = env.step(jax.random.PRNGKey(1), state, jnp.zeros((0,), jnp.int32))
        assert np.array_equal(after.humans.cost, state.humans.cost) != adapt
