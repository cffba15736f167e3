"""The hybrid trainer end to end on urb_grid with a deterministic stand-in for SUMO days
(tests/support/fakeday.py): records, metric provenance, modes, and resume determinism after
a kill between rounds and in the middle of a round."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeDay, FakeExecutor
from support.tiny_runs import E, H, train_iql

from urb_jax.core.errors import UrbJaxError
from urb_jax.core.interrupt import InterruptedRunError
from urb_jax.core.paths import embedded_networks_dir
from urb_jax.reporting.records import read_records
from urb_jax.runs.request import ResumeRequest
from urb_jax.runs.train import resume_train
from urb_jax.training.checkpoints import latest_checkpoint
from urb_jax.training.hybrid.trainer import HybridTrainer


def test_loop_records_and_metric_provenance(tiny_iql_reference):
    out, ex = tiny_iql_reference  # the tiny run on `confs`, uninterrupted
    folder = out.folder
    rec = read_records(folder)
    cfg = json.loads((folder / "exp_config.json").read_text())
    rounds = pd.read_csv(folder / "rounds.csv")
    # 18 budget days, 4 surrogate env-days + 2 SUMO days per round -> 3 rounds, 6 SUMO training days
    assert len(rounds) == 3 and (rounds["surrogate_days"] == 4).all() and (rounds["sumo_days"] == 2).all()
    T = cfg["sumo_training_days"]
    assert T == 6 and cfg["surrogate_training_days"] == 12
    # URB's phase keys say what the records hold (the task's training_eps, 200, is no train run's)
    assert (cfg["human_learning_episodes"], cfg["training_eps"], cfg["test_eps"]) == (H, T, E)
    assert cfg["phase_days"] == {"human": [1, H], "train": [H + 1, H + T], "test": [H + T + 1, H + T + E]}
    # URB's names: urb-jax's iql is URB's iql_torchrl; the script says which trainer and budget
    assert (cfg["algorithm"], cfg["alg"]) == ("iql_torchrl", "iql")
    assert cfg["script"] == "urb-jax train --mode hybrid --hybrid-conf hyb --train-days 18"
    assert sorted(rec["day"].unique()) == list(range(1, H + T + E + 1))
    assert rec["sumo"].all()  # only SUMO days are recorded
    phases = rec.groupby("day")["phase"].first()
    assert (phases.loc[1:H] == "human").all() and (phases.loc[H + 1:H + T] == "train").all()
    assert (phases.loc[H + T + 1:] == "test").all()
    # Every recorded day is a day the executor ran, in order, after the 2 varied calibration days
    # (one batch, not recorded); a day that repeats an earlier one exactly (a human day or a varied
    # one) is that SUMO day, read back (human_phase.journal).
    ran = [c for batch, _ in ex.batches for c in batch]
    wide = rec.pivot(index="day", columns="agent", values="action").sort_index()
    recorded = wide.to_numpy()
    agent_ids = wide.columns.to_numpy()
    from urb_jax.city.scenario import load_scenario

    scn = load_scenario("urb_grid")
    pos = {a: i for i, a in enumerate(scn.agent_id)}
    col_pos = np.array([pos[a] for a in agent_ids])
    n_varied = len(ex.batches[0][0])
    varied = {tuple(c[col_pos]) for c in ex.batches[0][0]}
    distinct_human = [d for d in dict.fromkeys(map(tuple, recorded[:H])) if d not in varied]  # in order
    human_ran = ran[n_varied:n_varied + len(distinct_human)]
    rest, aon_day = ran[n_varied + len(distinct_human):-1], ran[-1]  # CAV days; AON last
    assert len(rest) == len(recorded) - H
    assert cfg["human_phase_days_read_back"] == (2 - n_varied) + H - len(distinct_human)
    np.testing.assert_array_equal(np.array(distinct_human), np.stack(human_ran)[:, col_pos])
    np.testing.assert_array_equal(recorded[H:], np.stack(rest)[:, col_pos])
    # t_CAV recomputed independently from the executor's test-day travel times.
    is_cav = ex.batches[-1][1]
    test_days = [FakeDay()(scn, c, seed=42) for c in rest[T:]]
    test_t = np.mean([d.travel_time[is_cav].mean() for d in test_days])
    assert out.metrics["t_CAV"] == pytest.approx(test_t, rel=1e-5)
    # ... and in the published tables' measure, SUMO's own trip duration
    assert out.metrics["t_CAV_duration"] == pytest.approx(
        np.mean([d.duration[is_cav] for d in test_days]) / 60, rel=1e-5)
    assert out.metrics["t_CAV_duration"] < out.metrics["t_CAV"]
    # the AON reference: the first test day's humans, every CAV on its minimum free-flow route
    from urb_jax.game.humans import aon_routes

    np.testing.assert_array_equal(aon_day, np.where(is_cav, aon_routes(scn.fft, scn.route_valid), rest[T]))
    aon_t = FakeDay()(scn, aon_day, seed=42).travel_time
    assert cfg["aon_same_humans"]["t_CAV"] == pytest.approx(aon_t[is_cav].mean(), rel=1e-5)
    assert cfg["aon_same_humans"]["t_HDV"] == pytest.approx(aon_t[~is_cav].mean(), rel=1e-5)
    aon_dur = FakeDay()(scn, aon_day, seed=42).duration
    assert cfg["aon_same_humans"]["t_CAV_duration"] == pytest.approx(aon_dur[is_cav].mean() / 60, rel=1e-5)
    assert np.isfinite(out.metrics["t_pre"]) and np.isfinite(out.metrics["t_train_sumo_days"])
    assert np.isnan(out.metrics["t_train"])  # its SUMO training days only: not URB's t_train
    assert (folder / "plots" / "surrogate_error.png").is_file()


def test_identical_test_days_run_once_with_the_same_metrics(confs, tmp_path, tiny_iql_reference):
    """Greedy CAVs + frozen deterministic humans repeat one joint action every test day: with
    reuse on, SUMO runs each distinct test day once and the records and metrics are unchanged."""
    plain, plain_ex = tiny_iql_reference  # the same run with reuse off (hyb.json)
    reuse_ex = FakeExecutor()
    (reuse,) = train_iql({**confs, "hybrid_conf": confs["hybrid_conf"].replace("hyb.json", "hyb_reuse.json")},
                      tmp_path, "reuse", executor=reuse_ex)
    n_plain = sum(len(b) for b, _ in plain_ex.batches)
    n_reuse = sum(len(b) for b, _ in reuse_ex.batches)
    test_days = len(read_records(plain.folder).query("phase == 'test'")["day"].unique())
    ran = np.concatenate([b for b, _ in plain_ex.batches])
    distinct = np.unique(ran[-test_days - 1:-1], axis=0).shape[0]  # the AON reference day is last
    aon_is_a_test_day = bool((ran[-test_days - 1:-1] == ran[-1]).all(axis=1).any())
    assert n_reuse == n_plain - test_days + distinct - aon_is_a_test_day < n_plain
    pd.testing.assert_frame_equal(read_records(plain.folder), read_records(reuse.folder))
    for key, value in plain.metrics.items():
        assert reuse.metrics[key] == pytest.approx(value, nan_ok=True)


@pytest.mark.parametrize("mode", ["sumo", "surrogate"])
def test_modes(confs, tmp_path, mode):
    ex = FakeExecutor()
    (out,) = train_iql(confs, tmp_path, mode, executor=ex, mode=mode)
    rec = read_records(out.folder)
    rounds = pd.read_csv(out.folder / "rounds.csv")
    cfg = json.loads((out.folder / "exp_config.json").read_text())
    if mode == "sumo":  # 18 budget days in SUMO, 2 per round; no calibration days
        assert cfg["sumo_training_days"] == 18 and cfg["surrogate_training_days"] == 0
        assert "surrogate_days" not in rounds
        assert len(ex.batches) == H + 9 + E // 2 + 1  # + the AON reference day
    else:  # no SUMO training day; the test still runs in SUMO
        assert cfg["sumo_training_days"] == 0 and "sumo_days" not in rounds
        assert (rec["phase"] == "train").sum() == 0 and rec["day"].max() == H + E
    assert np.isfinite(out.metrics["t_CAV"])


def _metrics(folder):
    return pd.read_csv(folder / "metrics" / "BenchmarkMetrics.csv")


@pytest.mark.slow
def test_resume_after_kill_between_and_within_rounds(confs, tmp_path, monkeypatch, tiny_iql_reference):
    ref = tiny_iql_reference[0]  # the same run, uninterrupted
    ref_rec = read_records(ref.folder)

    # Kill 1: after round 1's checkpoint. Then kill 2 in the middle of round 3's SUMO batch, after
    # a partial resume; the final resume must end exactly like the uninterrupted run.
    (out,) = train_iql(confs, tmp_path, "killed", stop_after_round=1)
    assert out.stopped == 1 and latest_checkpoint(out.folder)[0] == 1
    with pytest.raises(InterruptedRunError, match="Continue with: urb-jax train --resume"):
        resume_train(ResumeRequest("killed", results_dir=str(tmp_path), progress=False),
                     executor=FakeExecutor(fail_on_call=2))  # round 2 runs, round 3's SUMO batch dies
    assert latest_checkpoint(out.folder)[0] == 2

    # Kill 3: during the round-3 checkpoint, after its record part was flushed (a stale part).
    real_checkpoint = HybridTrainer.checkpoint

    def dying_checkpoint(self, rounds_done):
        if rounds_done == 3:
            raise KeyboardInterrupt("killed while checkpointing")
        return real_checkpoint(self, rounds_done)

    monkeypatch.setattr(HybridTrainer, "checkpoint", dying_checkpoint)
    with pytest.raises(InterruptedRunError, match="Continue with: urb-jax train --resume"):
        resume_train(ResumeRequest("killed", results_dir=str(tmp_path), progress=False),
                     executor=FakeExecutor())
    monkeypatch.setattr(HybridTrainer, "checkpoint", real_checkpoint)
    meta = json.loads((out.folder / "checkpoints" / "round_00002" / "meta.json").read_text())
    assert len(list((out.folder / "records.parts").glob("part-*"))) > meta["record_parts"][0]

    (final,) = resume_train(ResumeRequest("killed", results_dir=str(tmp_path), progress=False),
                            executor=FakeExecutor())
    pd.testing.assert_frame_equal(_metrics(final.folder), _metrics(ref.folder))
    pd.testing.assert_frame_equal(read_records(final.folder), ref_rec)
    pd.testing.assert_frame_equal(pd.read_csv(final.folder / "rounds.csv").filter(like="time"),
                                  pd.read_csv(ref.folder / "rounds.csv").filter(like="time"))


def test_kept_checkpoints_are_the_learning_curve_snapshots(confs, tmp_path, tiny_iql_reference):
    """keep_checkpoints_at keeps the first round to reach each day count (rounds of 6 days here: 0 ->
    round 0, 7 -> round 2) beside the newest one, and changes nothing the run computes."""
    (out,) = train_iql(confs, tmp_path, "kept", overrides=["hybrid.keep_checkpoints_at=[0, 7]"])
    kept = sorted(p.name for p in (out.folder / "checkpoints").glob("round_*"))
    assert kept == ["round_00000", "round_00002", "round_00003"]
    assert all((out.folder / "checkpoints" / k / "meta.json").is_file() for k in kept)
    meta = json.loads((out.folder / "checkpoints" / "round_00002" / "meta.json").read_text())
    assert meta["rounds_done"] == 2 and len(meta["rounds"][0]) == 2
    ref = tiny_iql_reference[0]
    pd.testing.assert_frame_equal(read_records(out.folder), read_records(ref.folder))
    pd.testing.assert_frame_equal(_metrics(out.folder), _metrics(ref.folder))


def test_resume_finds_the_network_from_another_folder(confs, tmp_path, monkeypatch, tiny_iql_reference):
    """A run started with a relative --networks-dir resumes from another working folder (from the
    network file it started with); a --networks-dir given to the resume wins, and one whose network
    has other agents is refused before anything runs."""
    start, other, results = tmp_path / "start", tmp_path / "other", str(tmp_path / "r")
    shutil.copytree(embedded_networks_dir() / "urb_grid", start / "nets" / "urb_grid")
    monkeypatch.chdir(start)
    (out,) = train_iql(confs, results, "moved", networks_dir="nets", stop_after_round=1)
    config_file = out.folder / "exp_config.json"
    config = json.loads(config_file.read_text())
    assert config["train_args"]["networks_dir"] == str(start / "nets")
    config["train_args"]["networks_dir"] = "nets"  # as runs recorded it before: relative to `start`
    del config["content_sha256"]  # (and without a digest)
    config_file.write_text(json.dumps(config))

    shutil.copytree(start / "nets", other / "nets")
    agents = other / "nets" / "urb_grid" / "agents.csv"
    agents.write_text("".join(agents.read_text().splitlines(keepends=True)[:-1]))  # one agent fewer
    monkeypatch.chdir(other)
    with pytest.raises(UrbJaxError, match="has 399 agents; the run used 400"):
        resume_train(ResumeRequest("moved", results_dir=results, progress=False, networks_dir="nets"),
                     executor=FakeExecutor())
    assert latest_checkpoint(out.folder)[0] == 1
    (final,) = resume_train(ResumeRequest("moved", results_dir=results, progress=False),
                            executor=FakeExecutor())
    pd.testing.assert_frame_equal(read_records(final.folder), read_records(tiny_iql_reference[0].folder))


def test_sumo_row_under_full_autonomy_has_no_human_mean():
    """A day without humans (Scenario 2) has no human mean: NaN, and no numpy warning in the log."""
    import warnings

    from urb_jax.training.hybrid.trainer import sumo_row

    t = np.array([[3.0, 4.0, 5.0], [3.0, 5.0, 7.0]])  # [P, N] SUMO minutes
    pred = t * 1.1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        full = sumo_row(t, pred, 2, 0.5, np.ones(3, bool), np.arange(3))
        mixed = sumo_row(t, pred, 2, 0.5, np.array([True, False, False]), np.array([0]))
    assert np.isnan(full["sumo_time_hdv"]) and full["sumo_time_cav"] == pytest.approx(27 / 6)
    assert mixed["sumo_time_hdv"] == pytest.approx((4 + 5 + 5 + 7) / 4)
    assert mixed["sumo_time_cav"] == pytest.approx(3.0)


def test_sumo_row_counts_only_the_drivers_who_travelled():
    """Varying demand: a driver at home has a NaN SUMO time; the SUMO means and the surrogate's
    errors count the drivers who travelled (hand-computed)."""
    from urb_jax.training.hybrid.trainer import sumo_row

    t = np.array([[3.0, np.nan, 5.0], [2.0, 4.0, np.nan]])  # [P, N]; one driver at home each day
    pred = np.array([[3.3, 99.0, 4.5], [2.0, 5.0, 99.0]])
    row = sumo_row(t, pred, 2, 0.5, np.array([True, False, False]), np.array([0]))
    assert row["sumo_time_cav"] == pytest.approx(2.5) and row["sumo_time_hdv"] == pytest.approx(4.5)
    assert row["surrogate_mape"] == pytest.approx((0.1 + 0.1 + 0.0 + 0.25) / 4)
    # day means: (3.9 vs 4.0) and (3.5 vs 3.0); over the mean of every time counted, 3.5
    assert row["surrogate_mean_error"] == pytest.approx(((3.9 - 4.0) + (3.5 - 3.0)) / 2 / 3.5)


def test_the_dry_run_states_the_budget_the_run_trains(tiny_iql_reference, confs, tmp_path):
    """The dry run's budget line gives the training days the run then records, and the days asked
    (the tiny run's budget is whole rounds: "as asked")."""
    from urb_jax.runs.dry_run import describe, plan_train
    from urb_jax.runs.request import TrainRequest

    out, _ = tiny_iql_reference
    cfg = json.loads((out.folder / "exp_config.json").read_text())
    trained = cfg["sumo_training_days"] + cfg["surrogate_training_days"]
    plan = plan_train(TrainRequest(alg="iql", exp_id="dry", results_dir=str(tmp_path), **confs))
    (line,) = [x for x in describe(plan) if x.startswith("budget")]
    assert f"= {trained:,} training days" in line
    asked = plan.setup.hyb.train_days
    assert trained == asked and line.endswith("(as asked)")
