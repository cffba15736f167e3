"""The surrogate leg's clock (urb_jax.experiment.hybrid.clock): a long round says early, from
inside the jitted scan, what the training will cost."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_hybrid_loop import FakeExecutor

from urb_jax.experiment.hybrid.clock import LINE_EVERY_S, IterationClock, fmt_duration


class FakeTime:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_one_iteration_gives_the_estimate_and_the_hint_when_slow():
    t, notes = FakeTime(), []
    clock = IterationClock(n_iters=10, n_rounds=4, hint="use --alg-conf hybrid", note=notes.append, clock=t)
    clock.start_round(0)
    clock(np.array([0, 0]))  # one call per seed under vmap: a repeated index counts once
    t.now = 500.0
    clock(np.array([1, 1]))
    clock(np.array(1))
    assert len(notes) == 1
    # 500 s an iteration: 5,000 s a round, 20,000 s for 4 rounds: slow, so the hint follows
    assert "takes 8.3 min" in notes[0] and "about 83.3 min" in notes[0] and "about 5.6 h" in notes[0]
    assert notes[0].endswith("use --alg-conf hybrid")
    t.now += LINE_EVERY_S  # later iterations: a line at most every LINE_EVERY_S
    clock(2)
    clock(3)
    assert len(notes) == 2 and "iteration 2/10" in notes[1]
    clock.start_round(1)  # the estimate is said once per run
    clock(0)
    t.now += 1
    clock(1)
    assert len(notes) == 2


def test_a_fast_training_gets_no_hint():
    t, notes = FakeTime(), []
    clock = IterationClock(n_iters=4, n_rounds=2, hint="HINT", note=notes.append, clock=t)
    clock(0)
    t.now = 2.0
    clock(1)
    assert notes and "HINT" not in notes[0] and "16 s" in notes[0]
    assert fmt_duration(42) == "42 s" and fmt_duration(600) == "10.0 min" and fmt_duration(9000) == "2.5 h"


def test_a_training_run_prints_its_estimate(tmp_path, capsys):
    from urb_jax.experiment.run import run_train

    hyb = {"train_days": 20, "num_envs": 2, "surrogate_days_per_round": 8, "sumo_days_per_round": 2,
           "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2, "calib_steps": 20,
           "refit_days": 4, "refit_steps": 5}
    alg = {"agent_frames_per_batch": 2, "n_iters": 10, "num_epochs": 1, "minibatch_size": 64,
           "mlp_depth": 1, "mlp_cells": 16, "memory_size": 400}
    (tmp_path / "hyb.json").write_text(json.dumps(hyb))
    (tmp_path / "iql.json").write_text(json.dumps(alg))
    run_train(alg="iql", task_conf="test", hybrid_conf=str(tmp_path / "hyb.json"),
              alg_conf=str(tmp_path / "iql.json"), results_dir=str(tmp_path / "r"), progress=False,
              executor=FakeExecutor())
    err = capsys.readouterr().err
    # 8 surrogate env-days a round over 2 envs of 2 days: 2 iterations a round, timed from the scan
    lines = [line for line in err.splitlines() if line.startswith("estimate: one surrogate iteration")]
    assert len(lines) == 1 and "a round's 2 iterations" in lines[0]
