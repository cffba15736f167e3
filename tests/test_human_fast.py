"""The fast human phase (`human_surrogate_days`): leading human days on the surrogate, the rest,
t_pre's window included, in SUMO. On urb_grid with FakeDay (tests/support/fakeday.py) standing in for SUMO."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeDay, FakeExecutor

from urb_jax.city.scenario import load_scenario
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.progress import Progress
from urb_jax.game.config import TaskConfig
from urb_jax.reporting.records import read_records
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.request import BaselineRequest, TrainRequest
from urb_jax.runs.train import run_train
from urb_jax.training.human_phase import run_human_phase, surrogate_human_days
from urb_jax.training.hybrid.plan import HybridConfig
from urb_jax.training.protocol import train_humans, train_humans_on_model

H, S = 70, 20  # 70 human days: up to 20 may run on the surrogate, t_pre's last 50 stay SUMO days


def fake_day_model(scn):
    """FakeDay's travel time as a jax function of the choices (an exact 'surrogate' of that SUMO)."""
    od = jnp.asarray(scn.agent_od, jnp.int32)
    fft = jnp.asarray(scn.fft, jnp.float32)
    size = int(scn.agent_od.max() + 1) * scn.k

    def times(choices: jnp.ndarray) -> jnp.ndarray:
        key = od * scn.k + choices
        load = jnp.zeros(size).at[key].add(1.0)[key] - 1.0
        return fft[jnp.arange(od.shape[0]), choices] * (1.0 + load / 20.0)

    return times


def _same(a, b) -> bool:
    return all(jax.tree_util.tree_leaves(jax.tree_util.tree_map(
        lambda x, y: bool(np.allclose(np.asarray(x), np.asarray(y), equal_nan=True)), a, b)))


def test_surrogate_days_then_sumo_days_equal_all_sumo_days_when_the_model_is_exact():
    """Days 1..S on a model that is exactly the day function, then S+1..H through it, give the
    knowledge H days through it give: the same day keys and the same day rule on both paths."""
    scn = load_scenario("urb_grid")
    task = TaskConfig(human_learning_episodes=H)
    hp = task.human_params()
    fake = FakeDay()
    all_days = train_humans(scn, hp, H, env_seed=42, executor=fake)
    switch, means = train_humans_on_model(scn, hp, S, env_seed=42, travel_times=fake_day_model(scn))
    first_s = train_humans(scn, hp, S, env_seed=42, executor=FakeDay())
    assert _same(switch, first_s) and means.shape == (S,)
    rest = FakeDay()
    fast = train_humans(scn, hp, H, env_seed=42, executor=rest, first_day=S + 1, humans=switch)
    assert len(rest.calls) == H - S
    assert _same(fast, all_days)
    # and the model really drives them: a model twice as slow leaves other knowledge
    slow, _ = train_humans_on_model(scn, hp, S, env_seed=42,
                                    travel_times=lambda c: 2.0 * fake_day_model(scn)(c))
    assert not _same(slow, switch)


@pytest.mark.parametrize(("asked", "calibrate", "expected"), [(S, True, S), (1000, True, H - 50),
                                                             (S, False, 0), (0, True, 0)])
def test_fast_phase_runs_the_leading_days_on_the_surrogate(asked, calibrate, expected):
    scn = load_scenario("urb_grid")
    task = TaskConfig(human_learning_episodes=H)
    cfg = HybridConfig(human_surrogate_days=asked, calib_varied_days=3, calib_human_days=5, calib_steps=10)
    assert surrogate_human_days(cfg, H, calibrate) == expected
    ex = FakeExecutor()
    human = run_human_phase(scn, task, cfg, ex, 42, Progress(H, False), calibrate=calibrate)
    sizes = [len(b) for b, _ in ex.batches]
    # the varied calibration days first, together; then one SUMO day per remaining human day
    assert sizes == ([3] if calibrate else []) + [1] * (H - expected)
    assert [r.day for r in human.records] == list(range(expected + 1, H + 1))
    assert human.surrogate_days == expected and human.surrogate_means.shape == (expected,)
    assert (human.switch_humans is None) == (expected == 0)
    if calibrate:  # the calibration: the last 5 human (SUMO) days, then the varied days
        last5 = np.stack([r.choices for r in human.records[-5:]])
        np.testing.assert_array_equal(human.calib_choices[:5], last5)
        np.testing.assert_array_equal(human.calib_choices[5:], ex.batches[0][0])


@pytest.fixture(scope="module")
def fast_confs(confs, tmp_path_factory):
    d = tmp_path_factory.mktemp("fast_confs")
    hyb = json.loads(Path(confs["hybrid_conf"]).read_text()) | {"human_surrogate_days": S}
    (d / "hyb.json").write_text(json.dumps(hyb))
    task = json.loads((Path(__file__).parents[1] / "urb_jax" / "configs" / "task" / "test.json").read_text())
    (d / "task.json").write_text(json.dumps(task | {"human_learning_episodes": H, "test_eps": 4}))
    return confs | {"hybrid_conf": str(d / "hyb.json"), "task_conf": str(d / "task.json")}


@pytest.fixture(scope="module")
def fast_run(fast_confs, tmp_path_factory):
    root = tmp_path_factory.mktemp("fast_run")
    ex = FakeExecutor()
    (out,) = run_train(TrainRequest(alg="iql", exp_id="src", results_dir=str(root), progress=False,
                                    **fast_confs), executor=ex)
    return root, out, ex


def test_a_train_run_records_its_sumo_human_days_and_says_how_many_ran_on_the_surrogate(fast_run):
    _, out, _ = fast_run
    cfg = json.loads((out.folder / "exp_config.json").read_text())
    assert cfg["human_surrogate_days"] == S and cfg["hybrid_human_surrogate_days"] == S
    rec = read_records(out.folder)
    human_days = sorted(rec.loc[rec["phase"] == "human", "day"].unique())
    assert human_days == list(range(S + 1, H + 1))  # t_pre's 50 days all SUMO days
    metrics = pd.read_csv(out.folder / "metrics" / "BenchmarkMetrics.csv")
    assert np.isfinite(metrics["t_pre"].iloc[0])


@pytest.mark.slow
def test_reusing_a_fast_human_phase_replays_its_sumo_days(fast_run, fast_confs, tmp_path):
    _, src, _ = fast_run
    shutil.copytree(src.folder, tmp_path / "src")
    ex = FakeExecutor()
    (out,) = run_train(TrainRequest(alg="iql", exp_id="again", results_dir=str(tmp_path), progress=False,
                                    human_phase_from="src", **fast_confs), executor=ex)
    assert all(cav is not None for _, cav in ex.batches)  # no human or calibration day ran
    pd.testing.assert_frame_equal(read_records(out.folder), read_records(src.folder))


def test_a_baseline_refuses_to_replay_a_human_phase_that_began_on_the_surrogate(fast_run, fast_confs):
    root, _, _ = fast_run
    with pytest.raises(UrbJaxError, match="ran on the surrogate"):
        run_baseline(BaselineRequest(model="aon", results_dir=str(root), exp_id="base", progress=False,
                                     task_conf=fast_confs["task_conf"],
                                     human_phase_from="src"), executor=FakeDay())
    assert not (root / "base").exists()

