"""URB's marginal-cost task family (config_marginal_*, marginal_cost_coefficient_beta): the reward
by hand, URB's files loading with their beta, a hybrid run whose SUMO-day rewards carry beta x the
surrogate's externality, and runs without a surrogate refused."""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from support.fakeday import FakeExecutor
from support.linear_congestion import linear_model
from support.tiny_runs import tiny_reward_run

from urb_jax.commands.cli import main
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import TaskConfig, load_task
from urb_jax.game.rewards import behaviour_coefficients, cav_rewards, externalities, marginal_cost_rewards
from urb_jax.reporting.records import read_records
from urb_jax.runs.request import TrainRequest
from urb_jax.runs.train import run_train

URB_TASKS = Path(__file__).resolve().parents[2] / "shared" / "urb" / "config" / "task_config"


def test_marginal_cost_reward_by_hand():
    choices = jnp.asarray([0, 0, 0, 1, 1])  # linear congestion: 0.1 min per vehicle on a route
    is_cav = jnp.asarray([True, False, True, True, False])
    ext, times = externalities(linear_model, choices, is_cav, 2)
    selfish = cav_rewards(times, is_cav, behaviour_coefficients("selfish"))
    r = marginal_cost_rewards(selfish, ext, 0.5)
    # agent 0 shares route 0 with 2 others: its trip adds 0.1 min to each of the 3 (itself included)
    np.testing.assert_allclose(r, -np.asarray(times) - 0.5 * 0.1 * np.asarray([3, 3, 3, 2, 2]), rtol=1e-5)
    np.testing.assert_array_equal(marginal_cost_rewards(selfish, ext, 0.0), selfish)  # beta 0: URB's reward


@pytest.mark.skipif(not URB_TASKS.is_dir(), reason=f"URB's task configs not found at {URB_TASKS}")
@pytest.mark.parametrize("name, share, beta", [("config_marginal_10_beta_0_5", 0.1, 0.5),
                                               ("config_marginal_20_beta_5", 0.2, 5.0),
                                               ("config_marginal_10_beta_0_0", 0.1, 0.0)])
def test_urbs_marginal_tasks_load_with_their_beta(name, share, beta):
    loaded = load_task(str(URB_TASKS / f"{name}.json"))
    task = loaded.config
    assert (task.ratio_machines, task.marginal_cost_beta, task.av_behavior) == (share, beta, "selfish")
    assert loaded.resolution.aliases == {"marginal_cost_coefficient_beta": "marginal_cost_beta"}


def test_a_negative_beta_is_refused():
    with pytest.raises(ConfigError, match="marginal_cost_beta"):
        TaskConfig(marginal_cost_beta=-1.0)


@pytest.fixture(scope="module")
def confs(tmp_path_factory):
    # URB's key name, as in its config_marginal_* files
    return tiny_reward_run(tmp_path_factory.mktemp("marginal"), marginal_cost_coefficient_beta=2.0)


def test_hybrid_run_charges_cavs_their_marginal_cost(confs, tmp_path):
    (out,) = run_train(TrainRequest(alg="iql_star", exp_id="mc", results_dir=str(tmp_path), progress=False,
                                    **confs), executor=FakeExecutor())
    rec = read_records(out.folder)
    cav = rec[(rec["kind"] == "CAV") & (rec["phase"] != "human")]
    # selfish with beta 2: -(own SUMO time) - 2 x (the delay the surrogate says the trip adds), >= 0
    charge = -cav["reward"] - cav["travel_time"]
    assert (charge >= -1e-5).all() and (charge > 1e-4).any()
    cfg = json.loads((out.folder / "exp_config.json").read_text())
    assert cfg["marginal_cost_beta"] == 2.0


def test_marginal_cost_without_a_surrogate_is_refused(confs, tmp_path):
    with pytest.raises(ConfigError, match=r"marginal_cost_beta.*--mode sumo"):
        run_train(TrainRequest(alg="iql_star", exp_id="x", results_dir=str(tmp_path), progress=False,
                               mode="sumo", **confs), executor=FakeExecutor())
    assert main(["baseline", "--model", "aon", "--task-conf", confs["task_conf"],
                 "--results-dir", str(tmp_path)]) == 2
    assert not any(tmp_path.iterdir())


def test_the_pettingzoo_envs_refuse_rewards_they_cannot_pay(grid_scenario):
    from urb_jax.interop.pettingzoo import UrbParallelEnv

    for task in (TaskConfig(marginal_cost_beta=1.0), TaskConfig(reward_credit="marginal")):
        with pytest.raises(ConfigError, match="without a surrogate"):
            UrbParallelEnv(grid_scenario, task=task)
