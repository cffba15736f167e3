"""Adapting humans (task `should_humans_adapt`) in every mode: one human population per seed lives
every training day in order, surrogate days and SUMO days alike, and the test days in order, as in
URB; frozen humans keep the P side-by-side SUMO days (tests/test_hybrid_loop.py covers those).

SUMO days are the deterministic stand-in of tests/support/fakeday.py, so a replay of the human learning rule
over the records is an independent check of which days the humans lived."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeExecutor

from urb_jax.city.scenario import load_scenario
from urb_jax.core.configio import find_config
from urb_jax.game.humans import HumanParams, HumanState, act, learn
from urb_jax.reporting.records import read_records
from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.train import resume_train, run_train
from urb_jax.training.hybrid.trainer import HybridTrainer

H, E, P = 10, 10, 2


@pytest.fixture(scope="module")
def confs(tmp_path_factory):
    d = tmp_path_factory.mktemp("adapt_confs")
    hyb = {"train_days": 18, "num_envs": 2, "surrogate_days_per_round": 4, "sumo_days_per_round": P,
           "sumo_updates": 1, "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2,
           "calib_steps": 20, "refit_days": 4, "refit_steps": 5, "reuse_identical_test_days": False}
    alg = {"agent_frames_per_batch": 2, "n_iters": 10, "num_epochs": 1, "minibatch_size": 64,
           "mlp_depth": 1, "mlp_cells": 16, "memory_size": 400}
    # URB's `test` task (5% CAVs, deterministic humans), but the humans keep learning, and 20% CAVs
    # so that the CAVs' exploration moves the humans
    task = {**json.loads(find_config("task", "test").read_text()), "should_humans_adapt": True,
            "ratio_machines": 0.2}
    for name, conf in (("hyb", hyb), ("iql", alg), ("task", task)):
        (d / f"{name}.json").write_text(json.dumps(conf))
    return {"hybrid_conf": str(d / "hyb.json"), "alg_conf": str(d / "iql.json"),
            "task_conf": str(d / "task.json")}


def _train(confs, tmp_path, exp_id, executor, monkeypatch, **kw):
    """Runs; returns the runs (one per seed), the population's day counter just before the test
    days and after them, and the executor's batches from training's start."""
    days: dict[str, np.ndarray] = {}
    real_test, real_start = HybridTrainer.test, HybridTrainer.start

    def spy_start(self, human):
        days["first_batch"] = len(executor.batches)
        return real_start(self, human)

    def spy_test(self):
        days["before_test"] = np.asarray(self.state.real.day)  # [S, R]
        aon = real_test(self)
        days["after_test"] = np.asarray(self.state.real.day)
        return aon

    monkeypatch.setattr(HybridTrainer, "test", spy_test)
    monkeypatch.setattr(HybridTrainer, "start", spy_start)
    outs = run_train(TrainRequest(alg="iql", exp_id=exp_id, results_dir=str(tmp_path), progress=False,
                                  **confs, **kw), executor=executor)
    batches = [len(b[0]) for b in executor.batches[days["first_batch"]:]]
    return outs, days, batches


def _replay_humans(folder: Path, params: HumanParams) -> tuple[int, int]:
    """Replays the human learning rule from the human phase's humans over every recorded post-human
    day in order; returns (human choices that matched, human choices compared)."""
    z = np.load(folder / "human_phase.npz")
    humans = HumanState(*(jnp.asarray(z[f"humans_{k}"]) for k in HumanState._fields))
    rec = read_records(folder)
    rec = rec[rec["phase"] != "human"].sort_values(["day", "agent"])
    agents = load_scenario("urb_grid").agent_id  # the humans' arrays are in the scenario's order
    key = jax.random.PRNGKey(0)  # deterministic humans without exploration ignore it
    matched = compared = 0
    for _, day in rec.groupby("day", sort=True):
        day = day.set_index("agent").loc[agents]
        is_cav = (day["kind"] == "CAV").to_numpy()
        chosen = day["action"].to_numpy(np.int32)
        predicted = np.asarray(act(key, humans, params))
        matched += int((predicted[~is_cav] == chosen[~is_cav]).sum())
        compared += int((~is_cav).sum())
        times = jnp.asarray(day["travel_time"].to_numpy(np.float32))
        humans = learn(key, humans, jnp.asarray(chosen), times, params, learning=jnp.asarray(~is_cav))
    return matched, compared


def test_mode_sumo_population_lives_every_day_in_order(confs, tmp_path, monkeypatch):
    ex = FakeExecutor()
    (out,), days, batches = _train(confs, tmp_path, "sumo", ex, monkeypatch, mode="sumo")
    cfg = json.loads((out.folder / "exp_config.json").read_text())
    assert cfg["sumo_training_days"] == 18
    # one population: every training and test day is its own batch (S = 1 seed), in order
    assert batches == [1] * (18 + E + 1)  # + the AON reference day
    assert days["before_test"].tolist() == [[18]] and days["after_test"].tolist() == [[18 + E]]
    # the recorded human choices are exactly those of one population learning from every day in order
    matched, compared = _replay_humans(out.folder, HumanParams(beta=1.5, beta_randomness=0.1))
    n_humans = int((read_records(out.folder).query("day == @H + 1")["kind"] == "HDV").sum())
    assert compared == (18 + E) * n_humans and matched == compared


@pytest.fixture(scope="module")
def two_seeds(confs, tmp_path_factory):
    """Seeds 0 and 1 trained together (vmapped), uninterrupted, in hybrid mode: the population
    test below and the resume test's reference (one run serves both)."""
    root = tmp_path_factory.mktemp("two_seeds")
    ex = FakeExecutor()
    with pytest.MonkeyPatch.context() as mp:
        outs, days, batches = _train(confs, root, "ref", ex, mp, seeds=[0, 1])
    return outs, days, batches


def test_hybrid_population_lives_surrogate_and_sumo_days(two_seeds):
    outs, days, batches = two_seeds
    cfg = json.loads((outs[0].folder / "exp_config.json").read_text())
    budget = cfg["surrogate_training_days"] + cfg["sumo_training_days"]
    assert cfg["surrogate_training_days"] > 0 and cfg["sumo_training_days"] > 0
    # each seed's population day counter [S, 1]: every URB-equivalent training day, then the test days
    assert days["before_test"].tolist() == [[budget]] * 2
    assert days["after_test"].tolist() == [[budget + E]] * 2
    # one day of each seed's population per batch (S = 2 rows), in order; then one AON day per group
    assert batches == [2] * (cfg["sumo_training_days"] + E) + [1]
    for out in outs:
        rounds = pd.read_csv(out.folder / "rounds.csv")
        assert np.isfinite(rounds["population_time_hdv"]).all()


def test_frozen_humans_keep_p_copies(tmp_path, monkeypatch, confs):
    frozen = {**confs, "task_conf": "test"}
    (out,), days, batches = _train(frozen, tmp_path, "frozen", FakeExecutor(), monkeypatch, mode="sumo")
    assert days["before_test"].tolist() == [[9, 9]]  # P copies, one day each per round
    assert batches == [P] * (9 + E // P) + [1]  # side by side; then the AON reference day
    assert "population_time_hdv" not in pd.read_csv(out.folder / "rounds.csv")


def test_two_seeds_resume_like_uninterrupted(confs, tmp_path, two_seeds):
    """The population [S, 1] of two vmapped seeds survives a kill after round 1 exactly."""
    ref = two_seeds[0]
    kw = dict(alg="iql", results_dir=str(tmp_path), progress=False, seeds=[0, 1], **confs)
    run_train(TrainRequest(exp_id="killed", **kw), executor=FakeExecutor(), stop_after_round=1)
    resumed = resume_train(ResumeRequest("killed_s0", results_dir=str(tmp_path), progress=False),
                           executor=FakeExecutor())
    for a, b in zip(ref, resumed, strict=True):
        pd.testing.assert_frame_equal(read_records(a.folder), read_records(b.folder))
    assert not read_records(ref[0].folder).equals(read_records(ref[1].folder))  # the seeds differ
