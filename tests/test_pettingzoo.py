"""The PettingZoo AEC env passes PettingZoo's api_test and keeps URB's turn semantics."""

import numpy as np
import pytest
from fakeday import FakeDay
from pettingzoo.test import api_test

from urb_jax.experiment.pettingzoo_env import UrbAECEnv
from urb_jax.game.config import TaskConfig

TASK = TaskConfig(ratio_machines=0.05, human_learning_episodes=2, test_eps=0)


def test_api_test(grid_scenario):
    env = UrbAECEnv(grid_scenario, TASK, day_fn=FakeDay(), env_seed=3)
    api_test(env, num_cycles=60)


def test_turn_order_observation_and_rewards(grid_scenario):
    scn = grid_scenario
    fake = FakeDay()
    env = UrbAECEnv(scn, TASK, day_fn=fake, env_seed=3)
    assert len(fake.calls) == 2  # the human phase ran
    env.reset()
    order = []
    for agent in env.agent_iter():
        obs, reward, term, _trunc, info = env.last()
        if term:
            assert reward == pytest.approx(-info["travel_time"])  # selfish: -own time, minutes
            env.step(None)
            continue
        order.append(agent)
        i = int(np.flatnonzero(scn.agent_id == int(agent))[0])
        assert obs[0] == scn.agent_depart[i]
        # counts = same-OD agents with an earlier departure, by today's route
        earlier = (scn.agent_od == scn.agent_od[i]) & (scn.agent_depart < scn.agent_depart[i])
        expected = np.bincount(env.joint[earlier], minlength=scn.k)
        np.testing.assert_array_equal(obs[1:], expected)
        env.step(int(np.argmin(scn.fft[i])))
    departs = [scn.agent_depart[scn.agent_id == int(a)][0] for a in order]
    assert order == env.possible_agents and departs == sorted(departs)
    assert len(fake.calls) == 3
    choices, is_cav = fake.calls[-1]
    cav = env.cav_index
    np.testing.assert_array_equal(choices[cav], np.argmin(scn.fft[cav], axis=1))
    assert is_cav.sum() == len(order) == int(0.05 * scn.n_agents)
