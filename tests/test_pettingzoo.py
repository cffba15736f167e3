"""The PettingZoo AEC and Parallel envs pass PettingZoo's API tests, keep URB's turn semantics and
give the same day for the same policy; the incremental observations equal the full computation."""

import os
import re
import subprocess
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test
from support.fakeday import FakeDay

from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.observations import (
    OBSERVATION_TYPES,
    IncrementalObservations,
    make_observation_spec,
    observe,
)
from urb_jax.interop.pettingzoo import UrbAECEnv, UrbParallelEnv

REPO = Path(__file__).resolve().parents[1]
TASK = TaskConfig(ratio_machines=0.05, human_learning_episodes=2, test_eps=0)
# 0.4: 160 CAVs in >= 10 levels on urb_grid (global observations: > 100); humans adapt (day end)
BIG = TaskConfig(ratio_machines=0.4, human_learning_episodes=2, test_eps=0, should_humans_adapt=True)
GLOBAL = EnvConfig(observations="global_previous_agents")


def test_api_test(grid_scenario):
    env = UrbAECEnv(grid_scenario, TASK, executor=FakeDay(), env_seed=3)
    api_test(env, num_cycles=60)


@pytest.mark.parametrize("env_config", [None, GLOBAL])
def test_parallel_api_test(grid_scenario, env_config):
    env = UrbParallelEnv(grid_scenario, TASK, env_config, executor=FakeDay(), env_seed=3)
    assert env.num_levels == (3 if env_config is None else 20)  # the test steps through every level
    parallel_api_test(env, num_cycles=60)


def test_turn_order_observation_and_rewards(grid_scenario):
    scn = grid_scenario
    fake = FakeDay()
    env = UrbAECEnv(scn, TASK, executor=fake, env_seed=3)
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


def _policy(obs: np.ndarray, k: int) -> int:
    """Deterministic and observation-dependent: any earlier CAV's action changes later ones."""
    return int(obs.sum() * 7 + obs[-1] * 3) % k


def _aec_days(env: UrbAECEnv, days: int) -> list[tuple[dict, dict, dict, np.ndarray]]:
    """Per day (acting observation, reward, info per CAV, simulated joint choices)."""
    out = []
    for _ in range(days):
        env.reset()
        seen, rewards, infos = {}, {}, {}
        for agent in env.agent_iter():
            obs, reward, term, _trunc, info = env.last()
            if term:
                rewards[agent], infos[agent] = reward, info
                env.step(None)
                continue
            seen[agent] = obs
            env.step(_policy(obs, env.scenario.k))
        out.append((seen, rewards, infos, np.asarray(env.last_result.travel_time)))
    return out


def _parallel_days(env: UrbParallelEnv, days: int) -> list[tuple[dict, dict, dict, np.ndarray]]:
    out = []
    for _ in range(days):
        obs, infos = env.reset()
        seen = {}
        steps = 0
        while env.agents:
            acting = [a for a in env.agents if infos[a]["acting"]]
            seen.update({a: obs[a] for a in acting})
            actions = {a: _policy(obs[a], env.scenario.k) for a in acting}
            obs, rewards, terms, _truncs, infos = env.step(actions)
            steps += 1
        assert steps == env.num_levels and all(terms.values())
        for info in infos.values():
            del info["acting"]
        out.append((seen, rewards, infos, np.asarray(env.last_result.travel_time)))
    return out


def _assert_same_days(a_days: list, p_days: list, env: UrbAECEnv) -> None:
    for a_day, p_day in zip(a_days, p_days, strict=True):
        (a_seen, a_rew, a_info, a_times), (p_seen, p_rew, p_info, p_times) = a_day, p_day
        assert a_seen.keys() == p_seen.keys() == set(env.possible_agents)
        for agent in a_seen:
            np.testing.assert_array_equal(a_seen[agent], p_seen[agent])
        assert a_rew == p_rew and a_info == p_info
        np.testing.assert_array_equal(a_times, p_times)


@pytest.mark.parametrize("env_config", [None, GLOBAL])
def test_aec_and_parallel_same_policy_same_days(grid_scenario, env_config):
    """One observation-dependent policy in both envs: the same acting observations, joint choices,
    rewards and (adapting) humans over two days; each CAV's acting observation equals the
    observation function applied to the day's final joint choices (later CAVs cannot change it)."""
    fake_a, fake_p = FakeDay(), FakeDay()
    aec = UrbAECEnv(grid_scenario, BIG, env_config, executor=fake_a, env_seed=5)
    par = UrbParallelEnv(grid_scenario, BIG, env_config, executor=fake_p, env_seed=5)
    assert par.num_levels >= (10 if env_config is None else 100)
    a_days, p_days = _aec_days(aec, 2), _parallel_days(par, 2)
    _assert_same_days(a_days, p_days, aec)
    for (choices_a, _), (choices_p, _) in zip(fake_a.calls, fake_p.calls, strict=True):
        np.testing.assert_array_equal(choices_a, choices_p)
    assert len(set(map(bytes, (c.tobytes() for c, _ in fake_a.calls[-2:])))) == 2  # the days differ
    for (seen, *_), (choices, _) in zip(a_days, fake_a.calls[-2:], strict=True):
        oracle = np.asarray(observe(aec.spec, jnp.asarray(choices)))[aec.cav_index]  # [C, D]
        np.testing.assert_array_equal(np.stack([seen[a] for a in aec.possible_agents]), oracle)


@pytest.mark.sumo
def test_aec_and_parallel_same_sumo_days(grid_scenario):
    """The same joint actions give the same SUMO travel times in both envs."""
    task = TaskConfig(ratio_machines=0.4, human_learning_episodes=1, test_eps=0)
    aec = UrbAECEnv(grid_scenario, task, env_seed=7)
    par = UrbParallelEnv(grid_scenario, task, env_seed=7, humans=aec.humans)
    a_days, p_days = _aec_days(aec, 1), _parallel_days(par, 1)
    _assert_same_days(a_days, p_days, aec)
    assert a_days[0][3].min() > 0 and np.isfinite(a_days[0][3]).all()


def test_parallel_step_needs_the_acting_cavs_and_ignores_the_rest(grid_scenario):
    env = UrbParallelEnv(grid_scenario, TASK, executor=FakeDay(), env_seed=3)
    _obs, infos = env.reset()
    acting = [a for a in env.agents if infos[a]["acting"]]
    waiting = [a for a in env.agents if not infos[a]["acting"]]
    assert acting == env.levels[0] and waiting
    with pytest.raises(ValueError, match="lacks the actions of CAVs acting at level 0"):
        env.step({a: 0 for a in acting[1:]})
    before = env.joint.copy()
    env.step({a: 1 for a in env.agents})  # the waiting CAVs' actions are ignored
    rows = {a: env.cav_index[env.possible_agents.index(a)] for a in env.possible_agents}
    assert all(env.joint[rows[a]] == 1 for a in acting)
    assert all(env.joint[rows[a]] == before[rows[a]] for a in waiting)


@pytest.mark.parametrize("kind", OBSERVATION_TYPES)
def test_incremental_observations_equal_full_computation(kind):
    """Random groups, tied departures and action sequences (single changes, batches, repeated
    agents, unchanged actions): after every change, `observe` over everyone equals `observe()`."""
    rng = np.random.default_rng(0)
    n, k = 48, 3  # one shape: the full computation compiles once
    for groups, spread in [(1, 5), (4, 10), (12, 3), (30, 40), (3, 1000)]:
        od, depart = rng.integers(0, groups, n), np.sort(rng.integers(0, spread, n))
        spec = make_observation_spec(kind, od, depart, k)
        inc = IncrementalObservations(spec)
        actions = rng.integers(0, k, n)
        inc.reset(actions)
        for _ in range(25):
            who = rng.integers(0, n, size=int(rng.integers(1, 4)))
            what = rng.integers(0, k, len(who))
            inc.set(who, what)
            for i, a in zip(who, what, strict=True):
                actions[i] = a
            full = np.asarray(observe(spec, jnp.asarray(actions)))
            np.testing.assert_array_equal(inc.observe(np.arange(n)), full)
            np.testing.assert_array_equal(inc.observe_one(int(who[0])), full[who[0]])
    with pytest.raises(ValueError, match="not a route index"):
        inc.set(0, k)


@pytest.mark.sumo
def test_example_runs():
    """examples/pettingzoo_parallel.py (urb_grid, SUMO days) runs as a user runs it and reports
    each day's travel times after its human days."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, str(REPO / "examples/pettingzoo_parallel.py"), "--days", "2", "--human-days", "2"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=REPO, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    days = re.findall(r"^day (\d+): t_CAV ([\d.]+) min, t_HDV ([\d.]+) min$", out.stdout, re.MULTILINE)
    assert [int(d) for d, _, _ in days] == [3, 4], out.stdout
    assert all(0 < float(t) < 60 for _, *ts in days for t in ts)
