"""Per-CAV credit from the surrogate (`reward_credit: marginal`): externalities by hand on a linear
congestion model, against finite differences through the real surrogate, the reward formula,
and a hybrid run whose SUMO-day rewards carry them; runs without a surrogate are refused."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from support.fakeday import FakeExecutor
from support.linear_congestion import ALPHA, linear_model
from support.tiny_runs import tiny_reward_run

from urb_jax.commands.cli import main
from urb_jax.core.errors import ConfigError
from urb_jax.game.rewards import behaviour_coefficients, credit_rewards, externalities
from urb_jax.reporting.records import read_records
from urb_jax.runs.request import TrainRequest
from urb_jax.runs.train import run_train
from urb_jax.surrogate import build_static, init_params, predict


def test_externalities_by_hand():
    choices = jnp.asarray([0, 0, 0, 1, 1])  # 3 on route 0, 2 on route 1
    is_cav = jnp.asarray([True, False, True, True, False])
    ext, times = externalities(linear_model, choices, is_cav, 2)
    np.testing.assert_allclose(times, [1.8, 1.8, 1.8, 2.7, 2.7], rtol=1e-6)
    # agent i on route a delays every *other* member of g on route a by ALPHA, and itself by ALPHA
    # (its own flow's effect on its own route time, kept: a congestion model's self-term)
    on = np.asarray(choices)[None] == np.asarray(choices)[:, None]  # [N, N] same route
    groups = np.stack([np.asarray(is_cav), ~np.asarray(is_cav), np.ones(5, bool)])
    expected = ALPHA * (on[None] & groups[:, None, :]).sum(-1)  # [3, N]: members of g on i's route
    np.testing.assert_allclose(ext, expected, rtol=1e-5, atol=1e-6)


def test_credit_reward_formula():
    times = jnp.asarray([3.0, 4.0, 5.0])
    is_cav = jnp.asarray([True, True, False])
    ext = jnp.asarray([[0.2, 0.3, 0.1], [0.05, 0.0, 0.4], [0.25, 0.3, 0.5]])  # [3, N]
    coop = credit_rewards(times, is_cav, behaviour_coefficients("cooperative"), ext)
    np.testing.assert_allclose(coop[:2], [-(3.0 + 0.2), -(4.0 + 0.3)], rtol=1e-6)
    social = credit_rewards(times, is_cav, behaviour_coefficients("social"), ext)  # -t/2 - M_all/2
    np.testing.assert_allclose(social[:2], [-3.0 / 2 - (3.0 + 0.25) / 2, -4.0 / 2 - (4.0 + 0.3) / 2],
                               rtol=1e-6)
    malicious = credit_rewards(times, is_cav, behaviour_coefficients("malicious"), ext)  # + delay on humans
    np.testing.assert_allclose(malicious[:2], [0.05, 0.0], atol=1e-7)
    selfish = credit_rewards(times, is_cav, behaviour_coefficients("selfish"), ext)  # no group term
    np.testing.assert_allclose(selfish, -times)


def test_surrogate_externalities_match_finite_differences(grid_scenario):
    scn = grid_scenario
    static = build_static(scn)
    params = init_params(static)
    rng = np.random.default_rng(1)
    choices = jnp.asarray((rng.random(scn.n_agents) * scn.route_valid.sum(1)).astype(np.int32))
    is_cav = jnp.asarray(rng.random(scn.n_agents) < 0.4)
    model = lambda probs: predict(params, static, probs)  # noqa: E731
    ext, times = externalities(model, choices, is_cav, scn.k)
    assert (np.asarray(ext) >= -1e-6).all()  # congestion: a trip never speeds anyone up
    onehot = jax.nn.one_hot(choices, scn.k)
    base = np.asarray(model(jnp.zeros_like(onehot)))
    for i in [int(j) for j in np.argsort(-np.asarray(ext[2]))[:3]]:  # the three largest delays
        # forward mode, one agent at a time (the backward pass did all agents at once)
        tangent = jnp.zeros_like(onehot).at[i, choices[i]].set(1.0)
        _, dt = jax.jvp(model, (onehot,), (tangent,))
        dt = np.asarray(dt)
        others = np.arange(scn.n_agents) != i
        self_congestion = dt[i] - (float(times[i]) - base[i])  # its own flow on its own route time
        assert float(ext[2, i]) == pytest.approx(dt[others].sum() + self_congestion, rel=1e-3)
        assert 0 <= self_congestion < 0.1 * dt[others].sum()
        # and a finite difference (float32: a step large enough to rise above rounding)
        bumped = np.asarray(model(onehot.at[i, choices[i]].add(0.1)))
        assert float(ext[2, i]) == pytest.approx((bumped - np.asarray(times))[others].sum() / 0.1, rel=0.1)


@pytest.fixture(scope="module")
def confs(tmp_path_factory):
    return tiny_reward_run(tmp_path_factory.mktemp("credit"), av_behavior="cooperative",
                           reward_credit="marginal")


@pytest.mark.slow
def test_hybrid_run_pays_cavs_their_credit(confs, tmp_path):
    (out,) = run_train(TrainRequest(alg="iql_star", exp_id="credit", results_dir=str(tmp_path),
                                    progress=False, **confs), executor=FakeExecutor())
    rec = read_records(out.folder)
    cav = rec[(rec["kind"] == "CAV") & (rec["phase"] != "human")]
    # cooperative credit: -(own SUMO time + the delay the CAV adds to the other CAVs), delay >= 0
    delay = -cav["reward"] - cav["travel_time"]
    assert (delay >= -1e-5).all() and (delay > 1e-4).any()
    # not URB's group reward, which pays every CAV of a day the same: -(mean CAV time)
    group = cav.groupby("day")["travel_time"].transform("mean")
    assert not np.allclose(cav["reward"], -group)
    assert json.loads((out.folder / "exp_config.json").read_text())["reward_credit"] == "marginal"


def test_credit_without_a_surrogate_is_refused(confs, tmp_path):
    with pytest.raises(ConfigError, match=r"reward_credit.*--mode sumo"):
        run_train(TrainRequest(alg="iql_star", exp_id="x", results_dir=str(tmp_path), progress=False,
                               mode="sumo", **confs), executor=FakeExecutor())
    assert main(["baseline", "--model", "aon", "--task-conf", confs["task_conf"],
                 "--results-dir", str(tmp_path)]) == 2
    assert not any(tmp_path.iterdir())  # refused before any folder was created
