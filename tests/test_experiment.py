"""Runner phases with a fake day function; baselines; demand scaling; config errors."""

import dataclasses
import json

import numpy as np
import pytest
from support.fakeday import FakeDay

from urb_jax.algorithms.baselines import make_baseline
from urb_jax.city.demand import scale_demand
from urb_jax.core.configio import configs_dir, load_json
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import EnvConfig, TaskConfig, load_task_config, task_from_dict
from urb_jax.game.mutation import draw_cavs
from urb_jax.training.protocol import PHASE_HUMAN, PHASE_TEST, PHASE_TRAIN, run_experiment

TINY = TaskConfig(ratio_machines=0.25, human_learning_episodes=4, training_eps=3, test_eps=2)


def _run(scn, task=TINY, model="aon", seed=7):
    fake, records = FakeDay(), []
    out = run_experiment(scn, task, EnvConfig(), make_baseline(model), env_seed=seed, executor=fake,
                         sink=records.append)
    return out, fake, records


def test_phases_days_and_mutation(grid_scenario):
    scn = grid_scenario
    out, fake, records = _run(scn)
    assert len(fake.calls) == 4 + 3 + 2 == out.days
    assert [r.phase for r in records] == [PHASE_HUMAN] * 4 + [PHASE_TRAIN] * 3 + [PHASE_TEST] * 2
    assert [r.day for r in records] == list(range(1, 10))
    expected_cav = draw_cavs(7, scn.n_agents, 0.25, agent_id=scn.agent_id)
    assert out.is_cav.sum() == int(scn.n_agents * 0.25)
    np.testing.assert_array_equal(out.is_cav, expected_cav)
    for (choices, is_cav), rec in zip(fake.calls, records, strict=True):
        # a humans-only day goes to the executor without a CAV mask
        assert is_cav is None if rec.phase == PHASE_HUMAN else np.array_equal(is_cav, expected_cav)
        np.testing.assert_array_equal(choices, rec.choices)
    # AON CAVs take the minimum free-flow route every day.
    aon = np.argmin(np.where(scn.route_valid, scn.fft, np.inf), axis=1)
    for rec in records[4:]:
        np.testing.assert_array_equal(rec.choices[out.is_cav], aon[out.is_cav])
        assert np.isnan(rec.observations[~out.is_cav]).all()
        assert np.isfinite(rec.observations[out.is_cav]).all()
        # selfish CAV reward = -own time; humans get -time too
        np.testing.assert_allclose(rec.rewards, -rec.result.travel_time, rtol=1e-6)


def test_humans_learn_in_human_phase_and_freeze_after(grid_scenario):
    """Deterministic humans: choices vary while they learn; frozen humans repeat yesterday."""
    _, _, records = _run(grid_scenario, dataclasses.replace(TINY, training_eps=4, test_eps=3))
    human = ~records[-1].is_cav
    post = [r.choices[human] for r in records[4:]]
    assert all(np.array_equal(post[0], p) for p in post)
    assert any(not np.array_equal(records[0].choices, r.choices) for r in records[1:4])


def test_adapting_humans_keep_learning(grid_scenario):
    task = dataclasses.replace(TINY, should_humans_adapt=True, training_eps=6, test_eps=0)
    _, _, records = _run(grid_scenario, task)
    human = ~records[-1].is_cav
    post = [r.choices[human] for r in records[4:]]
    assert any(not np.array_equal(post[0], p) for p in post[1:])


def test_random_baseline_is_seeded_and_uniform_over_valid_routes(grid_scenario):
    _, _, a = _run(grid_scenario, model="random", seed=3)
    _, _, b = _run(grid_scenario, model="random", seed=3)
    _, _, c = _run(grid_scenario, model="random", seed=4)
    assert all(np.array_equal(x.choices, y.choices) for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x.choices, y.choices) for x, y in zip(a, c, strict=True))
    cav = a[-1].is_cav
    picks = np.stack([r.choices[cav] for r in a[4:]])
    assert len(np.unique(picks)) > 1
    valid = grid_scenario.route_valid[cav]
    assert valid[np.arange(cav.sum())[None, :].repeat(len(picks), 0), picks].all()


def test_human_baseline_continues_the_trained_model(grid_scenario):
    """The CAV keeps its human's trained costs: its first CAV choice is the argmin of the costs
    replayed by hand from the human days (C <- 0.8 C + 0.2 t on the chosen route, from FFT)."""
    out, _, records = _run(grid_scenario, model="human")
    state, _ = out.policy_state
    assert state.cost.shape == (int(out.is_cav.sum()), grid_scenario.k)
    cost = np.where(grid_scenario.route_valid, grid_scenario.fft, np.inf).astype(np.float64)
    rows = np.arange(cost.shape[0])
    for r in records[:4]:
        cost[rows, r.choices] = 0.8 * cost[rows, r.choices] + 0.2 * r.result.travel_time
    np.testing.assert_allclose(np.asarray(out.humans.cost), cost, rtol=1e-5)
    np.testing.assert_array_equal(records[4].choices[out.is_cav], np.argmin(cost[out.is_cav], axis=1))
    assert not np.allclose(cost[out.is_cav], np.asarray(grid_scenario.fft)[out.is_cav])


@pytest.mark.parametrize("share", [0.0, 1.0])
def test_extreme_shares_run(grid_scenario, share):
    out, fake, _records = _run(grid_scenario, dataclasses.replace(TINY, ratio_machines=share))
    assert out.is_cav.sum() == int(grid_scenario.n_agents * share)
    assert len(fake.calls) == out.days


def test_demand_scaling(grid_scenario):
    scn = grid_scenario
    half = scale_demand(scn, 0.5, seed=1)
    assert half.n_agents == scn.n_agents // 2
    assert set(half.agent_id) <= set(scn.agent_id) and len(set(half.agent_id)) == half.n_agents
    assert (np.diff(half.agent_depart) >= 0).all()
    double = scale_demand(scn, 2.0, seed=1, jitter_s=30)
    assert double.n_agents == 2 * scn.n_agents
    assert len(set(double.agent_id)) == double.n_agents and set(scn.agent_id) <= set(double.agent_id)
    assert (np.diff(double.agent_depart) >= 0).all()
    copies = double.agent_id > scn.agent_id.max()
    originals = {int(i): int(t) for i, t in zip(scn.agent_id, scn.agent_depart, strict=True)}
    # copies keep their original's OD; departures jittered within +-30 s and inside the window
    assert double.agent_depart[copies].min() >= scn.agent_depart.min()
    assert double.agent_depart[copies].max() <= scn.agent_depart.max()
    orig_ods = {int(i): int(o) for i, o in zip(scn.agent_id, scn.agent_od, strict=True)}
    for i, o, t in zip(double.agent_id[~copies], double.agent_od[~copies], double.agent_depart[~copies],
                       strict=True):
        assert orig_ods[int(i)] == o and originals[int(i)] == t
    assert np.array_equal(scale_demand(scn, 2.0, seed=1, jitter_s=30).agent_depart, double.agent_depart)
    # the runner accepts a scaled scenario
    _out, fake, _ = _run(half)
    assert fake.calls[0][0].shape == (half.n_agents,)


def test_every_shipped_task_and_env_config_loads():
    names = sorted(p.stem for p in (configs_dir() / "task").glob("*.json"))
    assert {"config1", "config2", "test", "altruistic_10", "altruistic_100", "militant_60"} <= set(names)
    catalogue = {"scenario2", "scenario2_cooperative", "selfish_40_adapt", "altruistic_40_adapt",
                 "demand_half", "demand_double", "selfish_40_adapt_deterministic",
                 "altruistic_40_adapt_deterministic", "malicious_40_deterministic"}  # configs/suites
    # urb-jax's own tasks beyond URB's (docs/experiment.md)
    extensions = {"varying_demand_40", "departure_jitter_40", "two_fleets_20_20"}
    assert catalogue | extensions <= set(names)
    assert len(names) == 3 + 8 * 3 + 10 + len(catalogue) + len(extensions)
    for name in names:
        cfg, _ = load_task_config(name)
        assert 0.0 <= cfg.ratio_machines <= 1.0
    cfg1, _ = load_task_config("config1")
    assert (cfg1.ratio_machines, cfg1.human_learning_episodes, cfg1.test_eps, cfg1.av_behavior) == (
        0.4, 200, 100, "selfish")
    assert load_task_config("social_60")[0].human_deterministic is False
    assert load_json(EnvConfig, configs_dir() / "env" / "config1.json").observations == (
        "previous_agents_plus_start_time")


def test_config_errors_name_file_and_key(tmp_path):
    bad = tmp_path / "mytask.json"
    bad.write_text(json.dumps({"ratio_machines": 0.4, "human_learnig_episodes": 3}))
    with pytest.raises(ConfigError, match=r"mytask\.json: unknown key\(s\) 'human_learnig_episodes'"):
        load_task_config(str(bad))
    with pytest.raises(ConfigError, match=r"key 'test_eps' has value '5'"):
        task_from_dict({"test_eps": "5"}, "t.json")
    with pytest.raises(ConfigError, match="av_behavior"):
        task_from_dict({"av_behavior": "greedy"}, "t.json")
    with pytest.raises(ConfigError, match="ratio_machines"):
        task_from_dict({"ratio_machines": 1.5}, "t.json")
    with pytest.raises(ConfigError, match="observations"):
        EnvConfig(observations="trip_info_eta")
    custom = task_from_dict({"av_behavior": [-1, 0.5, 0, 0]}, "t.json")
    assert custom.reward_coefficients == (-1.0, 0.5, 0.0, 0.0)
