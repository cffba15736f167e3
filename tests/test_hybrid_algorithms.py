"""Every algorithm through the hybrid loop (surrogate iterations + updates on SUMO-like days), and
one short run on real SUMO days through the process pool."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.digests import result_digests
from support.fakeday import FakeExecutor

from urb_jax.algorithms.registry import ALGORITHMS
from urb_jax.reporting.records import read_records
from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.train import resume_train, run_train

TINY = {
    "iql": {"agent_frames_per_batch": 2, "mlp_depth": 1, "mlp_cells": 16, "minibatch_size": 64},
    "ippo": {"agent_frames_per_batch": 2, "mlp_depth": 1, "mlp_cells": 16, "critic_depth": 1,
             "critic_cells": 16, "minibatch_size": 64},
    "mappo": {"agent_frames_per_batch": 2, "mlp_depth": 1, "mlp_cells": 16, "critic_depth": 1,
              "critic_cells": 16, "minibatch_size": 64},
    "qmix": {"agent_frames_per_batch": 2, "mlp_depth": 1, "mlp_cells": 16, "minibatch_size": 64,
             "mixing_embed_dim": 8, "num_epochs": 1},
    "vdn": {"agent_frames_per_batch": 2, "mlp_depth": 1, "mlp_cells": 16, "minibatch_size": 64,
            "num_epochs": 1},
    "iql_star": {"widths": [16], "batch_size": 4},
    "ippo_star": {"widths": [16], "batch_size": 4, "update_every": 1},
}
HYB = {"train_days": 12, "num_envs": 2, "surrogate_days_per_round": 4, "sumo_days_per_round": 2,
       "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2, "calib_steps": 20, "refit_days": 4,
       "refit_steps": 5}


@pytest.mark.slow
@pytest.mark.parametrize("alg", ALGORITHMS)
def test_every_algorithm_runs_the_loop_and_resumes_to_the_same_bytes(alg, tmp_path):
    """Each learner's whole state (replay memory, target networks, mixer, optimiser, exploration)
    survives a stop after round 1: the resumed run's records and metrics are the uninterrupted
    run's bytes (test_hybrid_loop.py kills IQL at more instants)."""
    (tmp_path / "alg.json").write_text(json.dumps(TINY[alg]))
    (tmp_path / "hyb.json").write_text(json.dumps(HYB))
    kw = dict(alg=alg, task_conf="test", alg_conf=str(tmp_path / "alg.json"),
              hybrid_conf=str(tmp_path / "hyb.json"), results_dir=str(tmp_path / "r"), progress=False)
    (out,) = run_train(TrainRequest(exp_id=alg, **kw), executor=FakeExecutor())
    cfg = json.loads((out.folder / "exp_config.json").read_text())
    assert cfg["status"] == "done" and cfg["sumo_training_days"] >= 2 and cfg["rounds"] == 2
    assert np.isfinite(out.metrics["t_CAV"]) and np.isfinite(out.metrics["t_train_sumo_days"])
    (stopped,) = run_train(TrainRequest(exp_id="stopped", **kw), executor=FakeExecutor(), stop_after_round=1)
    assert stopped.stopped == 1 and result_digests(stopped.folder) is None
    (resumed,) = resume_train(ResumeRequest("stopped", results_dir=str(tmp_path / "r"), progress=False),
                              executor=FakeExecutor())
    assert result_digests(resumed.folder) == result_digests(out.folder)


@pytest.mark.slow
def test_real_sumo_pool_end_to_end(tmp_path):
    (tmp_path / "alg.json").write_text(json.dumps(TINY["iql"]))
    hyb = {**HYB, "sumo_workers": 2}
    (tmp_path / "hyb.json").write_text(json.dumps(hyb))
    (out,) = run_train(TrainRequest(alg="iql", task_conf="test", alg_conf=str(tmp_path / "alg.json"),
                                    hybrid_conf=str(tmp_path / "hyb.json"), results_dir=str(tmp_path / "r"),
                                    exp_id="real", progress=False))
    rec = read_records(out.folder)
    assert rec["sumo"].all() and rec["day"].max() == 10 + out.summary.sumo_training_days + 10
    assert (rec["status"] == 0).mean() > 0.99  # SUMO arrived trips
    test = rec[rec["phase"] == "test"]
    t_cav = test[test["kind"] == "CAV"]["travel_time"].mean()
    assert out.metrics["t_CAV"] == pytest.approx(t_cav, rel=1e-4)
