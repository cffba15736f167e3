"""The functional env on a hand-made 3-agent day: observations, order, rewards, dones, masks."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.baselines import baseline_policy
from urb_jax.algorithms.learner import collect, reset_envs
from urb_jax.city.routes import RouteParams
from urb_jax.city.scenario import Scenario
from urb_jax.game.env import EnvState, RoutingEnv
from urb_jax.game.humans import HumanParams
from urb_jax.game.rewards import behaviour_coefficients
from urb_jax.game.rollout import Policy, act_at_once, act_by_levels, dependency_levels


def tiny_scenario() -> Scenario:
    """One OD pair, routes e0 (1 min), e1 (2 min) and a padding repeat of e0 (invalid); agents
    depart at 0 s (CAV), 10 s (human), 20 s (CAV)."""
    f = np.float64
    return Scenario(
        name="tiny", net_file="", env_seed=0, route_params=RouteParams(number_of_paths=3),
        edge_ids=("e0", "e1"), edge_length=np.array([600.0, 1200.0]), edge_speed=np.array([10.0, 10.0]),
        edge_lanes=np.array([1, 1]), edge_priority=np.array([1, 1]), edge_type=("", ""),
        edge_capacity=np.array([1800.0, 1800.0]),
        od_origin=np.array([0]), od_destination=np.array([0]), od_origin_edge=("e0",),
        od_destination_edge=("e1",),
        od_routes=np.array([[[0], [1], [0]]]), od_route_len=np.array([[1, 1, 1]]),
        od_route_valid=np.array([[True, True, False]]), od_fft=np.array([[1.0, 2.0, 1.0]], f),
        od_fft_full=np.array([[1.0, 2.0, 1.0]], f), od_route_length=np.array([[600.0, 1200.0, 600.0]]),
        agent_id=np.array([0, 1, 2]), agent_od=np.array([0, 0, 0]), agent_origin=np.array([0, 0, 0]),
        agent_destination=np.array([0, 0, 0]), agent_depart=np.array([0, 10, 20]), agent_kind=("Human",) * 3,
    )


def fft_plus_half_flow(scn: Scenario):
    """time = route free-flow time + 0.5 * (agents on the same route); a day's departure shifts (an
    env whose demand varies passes them) do not matter to it."""
    fft = jnp.asarray(scn.fft, jnp.float32)

    def tt(choices, shift=None):
        flow = jnp.zeros(scn.k).at[choices].add(1.0)
        return fft[jnp.arange(scn.n_agents), choices] + 0.5 * flow[choices]

    return tt


def tiny_env(behaviour: str = "selfish") -> RoutingEnv:
    scn = tiny_scenario()
    return RoutingEnv(scn, np.array([True, False, True]), fft_plus_half_flow(scn), HumanParams(model="aon"),
                      reward_coefficients=behaviour_coefficients(behaviour))


def chain_depth(env: RoutingEnv) -> int:
    """The longest chain of CAVs of one observation group with strictly increasing departures."""
    group, depart = env.obs_spec.group, env.obs_spec.depart
    return max((len(np.unique(depart[env.is_cav & (group == g)])) for g in np.unique(group[env.is_cav])),
               default=0)


def act_in_order(env: RoutingEnv, key: jax.Array, state: EnvState, policy: Policy
                 ) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Oracle for departure order: iterate obs -> act `chain_depth` times with the same key (a CAV's
    action changes only if its observation did), every CAV each round; the fixed point reproduces
    the sequential day exactly."""
    def round_(actions, _):
        return policy(key, env.observe(state, actions)).astype(jnp.int32), None

    actions, _ = jax.lax.scan(round_, state.cav_actions, None, length=max(chain_depth(env), 1))
    return env.observe(state, actions), actions


def test_hand_made_day_observations_rewards_dones():
    env = tiny_env()
    assert (env.n_cavs, env.obs_size, env.n_actions) == (2, 4, 3)
    np.testing.assert_array_equal(env.action_mask, [[True, True, False]] * 2)
    _, state = env.reset(jax.random.PRNGKey(0))
    assert int(state.human_actions[1]) == 0  # AON human takes the 1-min route
    obs = env.observe(state, jnp.array([1, 0]))
    # CAV0 departs first: nobody earlier. CAV2 at 20 s sees the human (route 0) and CAV0 (route 1).
    np.testing.assert_array_equal(obs, [[0, 0, 0, 0], [20, 1, 1, 0]])
    _, state2, rewards, dones, info = env.step(jax.random.PRNGKey(1), state, jnp.array([1, 0]))
    # route 1: 2 + 0.5*1 = 2.5 (CAV0); route 0: 1 + 0.5*2 = 2.0 (human, CAV2)
    np.testing.assert_allclose(info["times"], [2.5, 2.0, 2.0])
    np.testing.assert_allclose(rewards, [-2.5, -2.0])
    assert bool(dones.all())
    np.testing.assert_allclose(info["mean_time_cav"], 2.25)
    assert int(state2.day) == 1


def test_cooperative_reward_is_cav_mean():
    env = tiny_env("cooperative")
    _, state = env.reset(jax.random.PRNGKey(0))
    _, _, rewards, _, _ = env.step(jax.random.PRNGKey(1), state, jnp.array([1, 0]))
    np.testing.assert_allclose(rewards, [-2.25, -2.25])


def test_oracle_order_is_sequential():
    """Policy: route 1 if at least one earlier agent took route 0. CAV0 sees nobody -> 0; then
    CAV2 sees the human and CAV0 on route 0 -> 1. A simultaneous (one-round) choice from
    yesterday's fallback actions would differ."""
    env = tiny_env()
    _, state = env.reset(jax.random.PRNGKey(0))
    state = state._replace(cav_actions=jnp.array([1, 1]))

    def policy(key, obs):
        return jnp.where(obs[:, 1] >= 1, 1, 0)

    obs, actions = act_in_order(env, jax.random.PRNGKey(2), state, policy)
    np.testing.assert_array_equal(actions, [0, 1])
    np.testing.assert_array_equal(obs, [[0, 0, 0, 0], [20, 2, 0, 0]])
    assert [lv.tolist() for lv in dependency_levels(env)] == [[0], [1]]
    obs_lv, actions_lv = act_by_levels(env, jax.random.PRNGKey(2), state, lambda k, o, idx: policy(k, o))
    np.testing.assert_array_equal(actions_lv, actions)
    np.testing.assert_array_equal(obs_lv, obs)


def test_observation_free_policy_acts_once_with_the_day_key():
    """act_at_once: one call for every CAV with the key itself (the baselines' random draws)."""
    env = tiny_env()
    _, state = env.reset(jax.random.PRNGKey(0))
    key = jax.random.PRNGKey(5)
    policy = baseline_policy("random", env)
    obs, actions = act_at_once(env, key, state, policy)
    np.testing.assert_array_equal(actions, policy(key, None))
    np.testing.assert_array_equal(obs, env.observe(state, actions))


def test_collect_batches_days_and_baselines_respect_masks():
    env = tiny_env()
    states = reset_envs(env, jax.random.PRNGKey(0), 3)
    _, days = collect(env, baseline_policy("random", env), jax.random.PRNGKey(1), states, 50)
    assert days.obs.shape == (50, 3, 2, 4) and days.reward.shape == (50, 3, 2)
    assert set(np.unique(days.action)) == {0, 1}  # the invalid padding route is never drawn
    _, aon_days = collect(env, baseline_policy("aon", env), jax.random.PRNGKey(1), states, 2)
    np.testing.assert_array_equal(aon_days.action, 0)
    np.testing.assert_allclose(aon_days.time_cav, 2.5)  # everyone on route 0: 1 + 0.5*3


def test_levels_match_env_fixed_point_order(grid_scenario):
    """act_by_levels (each CAV evaluated once) == the fixed-point oracle (depth rounds) for an
    observation-dependent policy on urb_grid (depth 14), and levels respect departures."""
    from standin import make_env

    env = make_env(grid_scenario)
    levels = dependency_levels(env)
    assert len(levels) == chain_depth(env) > 1 and sum(len(i) for i in levels) == env.n_cavs
    _, state = env.reset(jax.random.PRNGKey(0))

    def policy(key, obs, idx=None):  # deterministic in the observation: least-used route so far
        counts = obs[:, 1:] + 0.01 * jnp.arange(env.n_actions)
        return jnp.argmin(counts, axis=-1)

    obs_ref, act_ref = act_in_order(env, jax.random.PRNGKey(1), state, policy)
    obs, act = jax.jit(lambda s: act_by_levels(env, jax.random.PRNGKey(1), s, policy))(state)
    np.testing.assert_array_equal(act, act_ref)
    np.testing.assert_array_equal(obs, obs_ref)
    assert len(np.unique(np.asarray(act_ref))) > 1
