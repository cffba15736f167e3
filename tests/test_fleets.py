"""Competing CAV fleets (task key `fleets`): the split, each fleet's rewards, each fleet's learner
acting and learning for its own CAVs only, per-fleet metrics on a hand-computed case, and the
refusals (config validation, modes that cannot support fleets: exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from test_alg_env import fft_plus_half_flow, tiny_scenario

from urb_jax.algorithms.configs import IQLStarConfig
from urb_jax.algorithms.fleets import (
    fleet_days,
    fleet_env,
    fleet_rows,
    fleet_updates_per_iter,
    fleets_policy,
    make_fleets_learner,
)
from urb_jax.algorithms.iql_star import make_learner as iql_star_learner
from urb_jax.algorithms.learner import Day
from urb_jax.commands.cli import main
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import TaskConfig, load_task_config
from urb_jax.game.env import RoutingEnv
from urb_jax.game.humans import HumanParams
from urb_jax.game.mutation import HUMAN, draw_cavs, split_fleets
from urb_jax.game.rewards import BEHAVIOURS
from urb_jax.reporting.metrics import fleet_metrics

TWO = [{"name": "a", "share": 0.2, "alg": "iql_star"},
       {"name": "b", "share": 0.2, "alg": "mappo", "alg_conf": "hybrid", "av_behavior": "cooperative"}]


def _tiny_fleets_env(coefficients=(BEHAVIOURS["social"], BEHAVIOURS["cooperative"])) -> RoutingEnv:
    """Agents 0 (fleet 0, 0 s), 1 (human, 10 s), 2 (fleet 1, 20 s) of one OD; time = fft + 0.5 x flow."""
    scn = tiny_scenario()
    return RoutingEnv(scn, np.array([True, False, True]), fft_plus_half_flow(scn), HumanParams(),
                      cav_fleet=np.array([0, HUMAN, 1]), fleet_coefficients=tuple(coefficients))


def test_each_fleet_is_paid_its_own_behaviour_over_its_own_cavs():
    env = _tiny_fleets_env()
    _, state = env.reset(jax.random.PRNGKey(0))
    state = state._replace(human_actions=jnp.array([0, 1, 0], jnp.int32))  # the human takes route 1
    # CAV 0 route 1, CAV 2 route 0: route 1 carries 2 (2 + 0.5 x 2 = 3 min), route 0 one (1 + 0.5 = 1.5)
    _, _, rewards, _, info = env.step(jax.random.PRNGKey(1), state, jnp.array([1, 0]))
    np.testing.assert_allclose(info["times"], [3.0, 3.0, 1.5])
    # fleet 0, social: -0.5 x 3 - 0.5 x (3 + 3 + 1.5) / 3 = -2.75; fleet 1, cooperative over its own
    # CAVs only: -1.5 (over every CAV it would be -(3 + 1.5) / 2 = -2.25)
    np.testing.assert_allclose(rewards, [-2.75, -1.5])
    # the fleet's T_HDV is the humans' alone (malicious: + the human's 3 min, not the other CAV's)
    env = _tiny_fleets_env((BEHAVIOURS["malicious"], BEHAVIOURS["malicious"]))
    _, _, rewards, _, _ = env.step(jax.random.PRNGKey(1), state, jnp.array([1, 0]))
    np.testing.assert_allclose(rewards, [3.0, 3.0])


def test_the_fleets_split_the_one_fleet_draw():
    n = 50
    is_cav = draw_cavs(42, n, 0.4)  # 20 CAVs
    fleet = split_fleets(42, is_cav, (0.1, 0.3))
    np.testing.assert_array_equal(fleet >= 0, is_cav)  # together: exactly the 40% task's CAVs
    assert np.bincount(fleet[is_cav]).tolist() == [5, 15]  # cut at round(20 x 0.1 / 0.4) = 5
    np.testing.assert_array_equal(fleet, split_fleets(42, is_cav, (0.1, 0.3)))  # reproducible
    assert not np.array_equal(fleet, split_fleets(43, is_cav, (0.1, 0.3)))  # from the env seed
    assert np.bincount(split_fleets(1, is_cav, (0.2, 0.1, 0.1))[is_cav]).tolist() == [10, 5, 5]


def test_each_fleet_acts_by_its_own_policy():
    rows = (np.array([0, 2]), np.array([1]))  # CAV rows 0 and 2: fleet 0; row 1: fleet 1

    def policy(base):  # acts base + the CAV's position among its fleet's CAVs
        def act(key, obs, idx=None):
            return base + (jnp.arange(obs.shape[0]) if idx is None else idx)
        return act

    pol = fleets_policy([policy(10), policy(20)], rows, 3)
    obs = jnp.zeros((3, 4))
    np.testing.assert_array_equal(pol(jax.random.PRNGKey(0), obs), [10, 20, 11])
    # departure-order acting names the rows: row 2 is fleet 0's second CAV, row 1 fleet 1's first
    np.testing.assert_array_equal(pol(jax.random.PRNGKey(0), obs, jnp.array([2, 0, 1])), [11, 10, 20])


def test_fleet_days_and_updates_per_iteration():
    c = 3
    day = Day(jnp.arange(2 * c * 2.0).reshape(1, 2, c, 2), jnp.array([[[0, 1, 2], [3, 4, 5]]]),
              jnp.array([[[-1.0, -2.0, -3.0], [-4.0, -5.0, -6.0]]]), jnp.ones((1, 2, c), bool),
              jnp.zeros((1, 2, c, 2)), jnp.zeros((1, 2)), jnp.zeros((1, 2)))
    own = fleet_days(day, np.array([0, 2]))
    np.testing.assert_array_equal(own.action, [[[0, 2], [3, 5]]])
    np.testing.assert_array_equal(own.reward, [[[-1.0, -3.0], [-4.0, -6.0]]])
    assert own.obs.shape == (1, 2, 2, 2) and own.active is None
    assert fleet_updates_per_iter([1, 20]) == (20, (20, 1))  # IQL* updates 20 times on MAPPO's 20 days
    assert fleet_updates_per_iter([4, 6]) == (12, (3, 2))


def test_each_fleets_learner_learns_from_its_own_cavs_only():
    env = _tiny_fleets_env((BEHAVIOURS["selfish"], BEHAVIOURS["selfish"]))
    assert [r.tolist() for r in fleet_rows(env)] == [[0], [1]]
    views = [fleet_env(env, f) for f in (0, 1)]
    assert [v.n_cavs for v in views] == [1, 1] and views[1].cav_index.tolist() == [2]
    config = IQLStarConfig(num_envs=2, batch_size=1, buffer_size=8)
    learner = make_fleets_learner(env, [iql_star_learner(config, v) for v in views], ("a", "b"), 2)
    runner = learner.init(jax.random.PRNGKey(0))
    days = Day(jnp.zeros((1, 1, 2, env.obs_size)), jnp.array([[[1, 0]]]), jnp.array([[[-1.0, -7.0]]]),
               jnp.ones((1, 1, 2), bool), jnp.zeros((1, 1, 2, env.obs_size)), jnp.zeros((1, 1)),
               jnp.zeros((1, 1)))
    runner, metrics = learner.update_from_days(runner, days, jax.random.PRNGKey(1))
    a, b = runner.fleets
    assert int(a.buffer.size) == 1 and int(b.buffer.size) == 1
    assert float(a.buffer.data.reward[0, 0]) == -1.0 and int(a.buffer.data.action[0, 0]) == 1
    assert float(b.buffer.data.reward[0, 0]) == -7.0 and int(b.buffer.data.action[0, 0]) == 0
    assert {"a_loss", "b_loss", "loss"} <= set(metrics)
    # an iteration on the surrogate: the fleets act together, each learner updates once (IQL*, 1 day)
    runner, metrics = jax.jit(learner.iteration)(runner, jax.random.PRNGKey(2))
    # + 1 day x 2 envs each
    assert int(runner.fleets[0].buffer.size) == 3 and int(runner.fleets[1].buffer.size) == 3
    assert np.isfinite(float(metrics["loss"]))


def test_per_fleet_metrics_on_a_hand_computed_case():
    # agents 0 (human), 1 (fleet a), 2 and 3 (fleet b); days 1-2 human days (H = 2), day 3 training
    # (T = 1), days 4-5 test
    times = {1: [3, 3, 3, 3], 2: [3, 3, 3, 3], 3: [3, 4, 2, 3], 4: [3, 2, 4, 2], 5: [3, 2, 4, 4]}
    records = pd.DataFrame([{"day": d, "agent": a, "travel_time": float(t)}
                            for d, row in times.items() for a, t in enumerate(row)])
    m = fleet_metrics(records, 2, 1, {"a": [1], "b": [2, 3]})
    # t_pre = 3 for both; a: test mean 2 (wins), training excess 4 - 3 = 1; b: test days
    # (4 + 2) / 2 = 3 and (4 + 4) / 2 = 4, mean 3.5 (loses), training excess (2 - 3 + 3 - 3) / 2 = -0.5
    assert m == {"t_pre_a": 3.0, "t_CAV_a": 2.0, "winrate_a": 1.0, "cost_of_learning_CAVs_a": 1.0,
                 "t_pre_b": 3.0, "t_CAV_b": 3.5, "winrate_b": 0.0, "cost_of_learning_CAVs_b": -0.5}
    hybrid = fleet_metrics(records, 2, 1, {"a": [1], "b": [2, 3]}, hybrid=True)
    assert list(hybrid) == ["t_pre_a", "t_CAV_a", "winrate_a", "cost_of_learning_CAVs_a_sumo_days",
                            "t_pre_b", "t_CAV_b", "winrate_b", "cost_of_learning_CAVs_b_sumo_days"]
    # each fleet is judged against its own drivers' pre-CAV time: fleet b's drivers had long trips
    # (5 min) and end at 4.5, a win, though above the all-agent pre-CAV mean (3.75)
    times = {1: [2, 2, 5, 5], 2: [2, 2, 5, 5], 3: [2, 2, 5, 5], 4: [2, 2, 4, 5], 5: [2, 2, 5, 4]}
    records = pd.DataFrame([{"day": d, "agent": a, "travel_time": float(t)}
                            for d, row in times.items() for a, t in enumerate(row)])
    m = fleet_metrics(records, 2, 1, {"a": [1], "b": [2, 3]})
    assert (m["t_pre_b"], m["t_CAV_b"], m["winrate_b"]) == (5.0, 4.5, 1.0)
    assert (m["t_pre_a"], m["t_CAV_a"], m["winrate_a"]) == (2.0, 2.0, 0.0)


def test_fleets_config_validation(tmp_path: Path):
    task = TaskConfig(ratio_machines=0.4, fleets=tuple(TWO))
    assert [f.name for f in task.fleets] == ["a", "b"] and task.fleet_shares == (0.2, 0.2)
    assert task.fleets[1].reward_coefficients == BEHAVIOURS["cooperative"]
    assert TaskConfig(fleets=({**TWO[0], "alg": "iql_torchrl"}, TWO[1])).fleets[0].alg == "iql"  # URB's name
    bad = {
        "add up to 0.3": dict(fleets=(TWO[0], {**TWO[1], "share": 0.1})),
        "declares one fleet": dict(ratio_machines=0.2, fleets=(TWO[0],)),
        "own name": dict(fleets=(TWO[0], {**TWO[1], "name": "a"})),
        "is no algorithm": dict(fleets=(TWO[0], {**TWO[1], "alg": "ppo"})),
        "key 'share'": dict(ratio_machines=1.0, fleets=(TWO[0], {**TWO[1], "share": 1.2})),
        "unknown av_behavior": dict(fleets=(TWO[0], {**TWO[1], "av_behavior": "greedy"})),
        "unknown key": dict(fleets=(TWO[0], {**TWO[1], "ratio": 0.2})),
        "reward_credit": dict(fleets=tuple(TWO), reward_credit="marginal"),
        "day_participation": dict(fleets=tuple(TWO), day_participation=0.9),
    }
    for match, kwargs in bad.items():
        with pytest.raises(ConfigError, match=match):
            TaskConfig(**kwargs)
    path = tmp_path / "fleets.json"
    path.write_text(json.dumps({"ratio_machines": 0.4, "fleets": [TWO[0], {**TWO[1], "share": -0.2}]}))
    with pytest.raises(ConfigError, match=r"fleets\.json.*fleets' entry 1.*'share'"):
        load_task_config(str(path))
    shipped, _ = load_task_config("two_fleets_20_20")
    assert [(f.alg, f.share, f.av_behavior) for f in shipped.fleets] == [("iql_star", 0.2, "selfish"),
                                                                        ("mappo", 0.2, "selfish")]
    assert shipped.ratio_machines == 0.4


def _fleets_task(tmp_path: Path) -> str:
    path = tmp_path / "tiny_fleets.json"
    path.write_text(json.dumps({"ratio_machines": 0.1, "human_learning_episodes": 10, "human_beta": 1.5,
                                "test_eps": 10, "fleets": [{**TWO[0], "share": 0.05},
                                                           {**TWO[1], "share": 0.05}]}))
    return str(path)


@pytest.mark.parametrize("args, said", [
    (["baseline", "--model", "aon"], "a baseline's CAVs all follow its one model"),
    (["train", "--alg", "qmix"], "--alg is qmix"),
    (["train", "--alg-conf", "fast"], "--alg-conf fast"),
    (["train", "--set", "alg.lr=0.1"], "--set alg"),
])
def test_modes_that_cannot_support_fleets_refuse_them(tmp_path: Path, capsys, args, said):
    code = main([*args, "--task-conf", _fleets_task(tmp_path), "--results-dir", str(tmp_path / "res"),
                 "--dry-run"] if args[0] == "train" else
                [*args, "--task-conf", _fleets_task(tmp_path), "--results-dir", str(tmp_path / "res")])
    assert code == 2
    assert said in capsys.readouterr().err
    assert not (tmp_path / "res").exists() or not any((tmp_path / "res").iterdir())


@pytest.mark.slow
def test_a_tiny_fleets_run_reports_each_fleet(tmp_path: Path):
    """End to end on the embedded network (test configs): both fleets train in one run, exp_config.json
    names their CAVs (together the one-fleet draw), BenchmarkMetrics.csv appends each fleet's columns
    after URB's, computed from the records, and the fleets' plot is drawn."""
    from urb_jax.reporting.metrics import BENCHMARK_COLUMNS
    from urb_jax.reporting.records import read_records

    code = main(["train", "--task-conf", _fleets_task(tmp_path), "--env-conf", "test", "--hybrid-conf",
                 "test", "--results-dir", str(tmp_path / "res"), "--id", "fleets", "--no-progress",
                 "--no-day-store"])
    assert code == 0
    run = tmp_path / "res" / "fleets"
    config = json.loads((run / "exp_config.json").read_text())
    assert config["alg"] == "iql_star"  # the first fleet's names the run
    fleets = config["fleet_agents"]
    assert sorted(fleets) == ["a", "b"] and len(fleets["a"]) == len(fleets["b"]) == 20  # 400 x 0.05 each
    bench = pd.read_csv(run / "metrics" / "BenchmarkMetrics.csv")
    assert list(bench.columns) == [*BENCHMARK_COLUMNS, "t_pre_a", "t_CAV_a", "winrate_a",
                                   "cost_of_learning_CAVs_a", "t_pre_b", "t_CAV_b", "winrate_b",
                                   "cost_of_learning_CAVs_b"]
    records = read_records(run)
    cavs = set(records.loc[records["kind"] == "CAV", "agent"])
    assert cavs == set(fleets["a"]) | set(fleets["b"])
    test = records[records["phase"] == "test"]
    t_a = test[test["agent"].isin(fleets["a"])].groupby("day")["travel_time"].mean().mean()
    assert bench["t_CAV_a"][0] == pytest.approx(t_a, rel=1e-6)
    assert (run / "plots" / "fleets_travel_times.png").is_file()


@pytest.mark.slow
def test_a_stopped_fleets_run_resumes_to_the_uninterrupted_runs_results(tmp_path: Path):
    """Both fleets' learners are in the round checkpoint: a fleets run stopped after its first round
    and resumed ends with the records and metric files of the same run never stopped."""
    from support.tiny_runs import stopped_and_whole, tiny_reward_run

    confs = tiny_reward_run(tmp_path)
    task = json.loads(Path(confs["task_conf"]).read_text())
    Path(confs["task_conf"]).write_text(json.dumps({**task, "ratio_machines": 0.1, "fleets": [
        {**TWO[0], "share": 0.05}, {**TWO[1], "share": 0.05}]}))
    resumed, whole = stopped_and_whole(confs, tmp_path)
    assert whole is not None and resumed == whole
