"""A budget that is not a whole number of rounds ends with a shorter last round (plan.plan_rounds):
the tiny IQL run on urb_grid (tests/support/tiny_runs.py, SUMO days from FakeExecutor) trains
exactly the days its plan says, counted where they happen (the surrogate iterations the trainer
runs, the SUMO training days in the records), and a kill inside the short round resumes to the
same bytes as the uninterrupted run."""

from __future__ import annotations

import hashlib
import json
import math

import pandas as pd
import pytest
from support.fakeday import FakeExecutor
from support.tiny_runs import E, H, train_iql

from urb_jax.core.interrupt import InterruptedRunError
from urb_jax.reporting.records import read_records
from urb_jax.runs.dry_run import describe, plan_train
from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.standing import _per_round
from urb_jax.runs.train import resume_train
from urb_jax.training.checkpoints import latest_checkpoint
from urb_jax.training.hybrid import clock, trainer

ITER_DAYS = 4  # the tiny IQL learner: 2 days in each of 2 envs per iteration
# name -> (--set overrides, train_days, [(surrogate iterations, SUMO days) per round])
CASES = {
    # rounds of 1 iteration (4 days) + 2 SUMO days; 13 = 2 x 6 + 1: one SUMO day, no iteration
    "fewer_sumo_days": ((), 13, [(1, 2), (1, 2), (0, 1)]),
    # rounds of 2 iterations + 2 SUMO days; 26 = 2 x 10 + 6: 2 SUMO days and one iteration
    "fewer_iterations": (("hybrid.surrogate_days_per_round=8",), 26, [(2, 2), (2, 2), (1, 2)]),
}


def _train(confs, folder, case, **request):
    """The tiny IQL run of `case` in `folder`."""
    overrides, days, _ = CASES[case]
    return train_iql(confs, folder, case, overrides=list(overrides), train_days=days, **request)


@pytest.fixture(scope="module")
def uninterrupted(tiny_iql_confs, tmp_path_factory):
    """case -> (the uninterrupted run's folder, the iterations of each surrogate leg, executor)."""
    out = {}
    for case in CASES:
        legs: list[int] = []

        def counting(fn, carry, keys, clk, programs, chunk=None, legs=legs):
            legs.append(int(keys.shape[1]))  # the iterations this leg really runs
            return clock.run_chunks(fn, carry, keys, clk, programs, chunk)

        ex = FakeExecutor()
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(trainer, "run_chunks", counting)
            (run,) = _train(tiny_iql_confs, tmp_path_factory.mktemp(case), case, executor=ex)
        out[case] = (run, legs, ex)
    return out


@pytest.mark.parametrize("case", list(CASES))
def test_the_days_trained_are_the_plan(uninterrupted, tiny_iql_confs, tmp_path, case):
    run, legs, ex = uninterrupted[case]
    _, train_days, rounds = CASES[case]
    folder = run.folder
    cfg = json.loads((folder / "exp_config.json").read_text())
    rec = read_records(folder)
    table = pd.read_csv(folder / "rounds.csv")
    sumo_days = sum(p for _, p in rounds)
    assert legs == [n for n, _ in rounds if n]  # the surrogate iterations the trainer ran
    sur_days = ITER_DAYS * sum(legs)
    assert sur_days + sumo_days == train_days  # exact here: what is left fits whole iterations
    # the SUMO training days in the records, numbered after the human days, then the test days
    train = rec.query("phase == 'train'")["day"].unique()
    assert sorted(train) == list(range(H + 1, H + sumo_days + 1))
    assert sorted(rec.query("phase == 'test'")["day"].unique()) == list(
        range(H + sumo_days + 1, H + sumo_days + E + 1))
    # the last round's SUMO batch has its p days (one seed, frozen humans: one batch a round)
    round_batches = [len(b) for b, _ in ex.batches][-(E // 2 + 1 + len(rounds)):-(E // 2 + 1)]
    assert round_batches == [p for _, p in rounds]
    # what the run records says the same
    assert (cfg["sumo_training_days"], cfg["surrogate_training_days"], cfg["rounds"]) == (
        sumo_days, sur_days, len(rounds))
    assert table["sumo_days"].tolist() == [p for _, p in rounds]
    assert table["surrogate_days"].tolist() == [ITER_DAYS * n for n, _ in rounds]
    assert math.isfinite(_per_round(table.to_dict("records")))  # the status pace: a leg not run is 0 s
    # the epsilon schedule spans the iterations and updates trained (TorchRL family: n_iters
    # iterations of agent_frames_per_batch frames, a SUMO update counted as one frame)
    per_iter = cfg["alg_config_values"]["agent_frames_per_batch"]
    assert cfg["alg_config_values"]["n_iters"] == math.ceil((sum(legs) * per_iter + len(rounds)) / per_iter)
    # and the dry run said so before
    plan = plan_train(TrainRequest(alg="iql", exp_id="dry", results_dir=str(tmp_path), train_days=train_days,
                                   overrides=list(CASES[case][0]), **tiny_iql_confs))
    (line,) = [x for x in describe(plan) if x.startswith("budget")]
    last_sumo = f"{rounds[-1][1]} SUMO day" + ("s" if rounds[-1][1] > 1 else "")
    assert line.endswith(f"and a last round of {ITER_DAYS * rounds[-1][0]} surrogate + {last_sumo} "
                         f"= {train_days:,} training days (as asked)")


def _digests(folder):
    files = [folder / "records.parquet", *sorted((folder / "metrics").glob("*.csv"))]
    return {f.relative_to(folder).as_posix(): hashlib.sha256(f.read_bytes()).hexdigest() for f in files}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_a_kill_inside_the_short_last_round_resumes_to_the_same_bytes(uninterrupted, tiny_iql_confs,
                                                                    tmp_path, case):
    """Killed after round 2's checkpoint, then inside round 3 (after its surrogate leg, if any, in
    its SUMO batch): the resume recomputes the short round's plan and ends byte-identical."""
    ref = uninterrupted[case][0]
    (out,) = _train(tiny_iql_confs, tmp_path, case, stop_after_round=2)
    assert out.stopped == 2
    meta = json.loads((out.folder / "checkpoints" / "round_00002" / "meta.json").read_text())
    assert meta["rounds_total"] == 3 and meta["last_round"] == list(CASES[case][2][-1])
    resume = ResumeRequest(case, results_dir=str(tmp_path), progress=False)
    with pytest.raises(InterruptedRunError, match="Continue with: urb-jax train --resume"):
        resume_train(resume, executor=FakeExecutor(fail_on_call=1))  # the last round's SUMO batch
    assert latest_checkpoint(out.folder)[0] == 2
    (final,) = resume_train(resume, executor=FakeExecutor())
    assert _digests(final.folder) == _digests(ref.folder)
    pd.testing.assert_frame_equal(pd.read_csv(final.folder / "rounds.csv").filter(like="time"),
                                  pd.read_csv(ref.folder / "rounds.csv").filter(like="time"))
