"""Tiny hybrid runs on urb_grid with FakeExecutor for SUMO: their config files, and the IQL run itself
(the fixtures tiny_iql_confs and tiny_iql_reference in tests/conftest.py run it once per session)."""

from __future__ import annotations

import json
from pathlib import Path

from support.fakeday import FakeExecutor
from urb_jax.core.configio import find_config
from urb_jax.runs.request import TrainRequest
from urb_jax.runs.train import run_train

H, E = 10, 10  # configs/task/test.json: human days, test days


def tiny_iql_run(d: Path) -> dict[str, str]:
    """A tiny IQL hybrid run's configs in `d` (3 rounds of 4 surrogate and 2 SUMO days, task `test`);
    also hyb_reuse.json, the same with repeated test days read back."""
    hyb = {"train_days": 18, "num_envs": 2, "surrogate_days_per_round": 4, "sumo_days_per_round": 2,
           "sumo_updates": 1, "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2,
           "calib_steps": 20, "refit_days": 4, "refit_steps": 5,
           "reuse_identical_test_days": False}  # every test day reaches the executor (provenance test)
    alg = {"agent_frames_per_batch": 2, "n_iters": 10, "num_epochs": 1, "minibatch_size": 64,
           "mlp_depth": 1, "mlp_cells": 16, "memory_size": 400}
    (d / "hyb.json").write_text(json.dumps(hyb))
    (d / "hyb_reuse.json").write_text(json.dumps({**hyb, "reuse_identical_test_days": True}))
    (d / "iql.json").write_text(json.dumps(alg))
    return {"hybrid_conf": str(d / "hyb.json"), "alg_conf": str(d / "iql.json"), "task_conf": "test"}


def train_iql(confs, tmp_path, exp_id, executor=None, stop_after_round=None, **request):
    """The IQL run on `confs` (tiny_iql_run's) in `tmp_path`, its SUMO days on `executor` (a fresh
    FakeExecutor by default); `request`: more TrainRequest fields."""
    req = TrainRequest(alg="iql", exp_id=exp_id, results_dir=str(tmp_path), progress=False, **confs,
                       **request)
    return run_train(req, executor=executor or FakeExecutor(), stop_after_round=stop_after_round)


def tiny_reward_run(d: Path, **task_keys) -> dict[str, str]:
    """A tiny hybrid run's configs (3 rounds of 4 surrogate and 2 SUMO days, 30% CAVs) with the
    task config `test` plus `task_keys`."""
    hyb = {"train_days": 18, "num_envs": 2, "surrogate_days_per_round": 4, "sumo_days_per_round": 2,
           "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2, "calib_steps": 20,
           "refit_days": 4, "refit_steps": 5}
    task = {**json.loads(find_config("task", "test").read_text()), "ratio_machines": 0.3, **task_keys}
    (d / "hyb.json").write_text(json.dumps(hyb))
    (d / "task.json").write_text(json.dumps(task))
    return {"hybrid_conf": str(d / "hyb.json"), "task_conf": str(d / "task.json")}


def stopped_and_whole(confs: dict[str, str], tmp_path: Path, alg: str = "iql_star") -> tuple[object, object]:
    """(the result digests of a run of `confs` stopped after its first round and resumed, those of the
    same run never stopped); asserts the stopped run had written no metrics before its resume."""
    from support.digests import result_digests
    from urb_jax.runs.request import ResumeRequest
    from urb_jax.runs.train import resume_train

    def train(exp_id: str, stop_after_round: int | None = None):
        req = TrainRequest(alg=alg, exp_id=exp_id, results_dir=str(tmp_path), progress=False, **confs)
        return run_train(req, executor=FakeExecutor(), stop_after_round=stop_after_round)

    (whole,) = train("whole")
    (stopped,) = train("stopped", stop_after_round=1)
    assert result_digests(stopped.folder) is None  # it did stop before its metrics
    (resumed,) = resume_train(ResumeRequest("stopped", results_dir=str(tmp_path), progress=False),
                              executor=FakeExecutor())
    return result_digests(resumed.folder), result_digests(whole.folder)
