"""`urb_jax.runs.suite`: a list of runs as one resumable job, then its tables and figures."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pandas as pd
import pytest
from support.fakeday import FakeDay, FakeExecutor

from urb_jax.reporting.records import read_records
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.request import BaselineRequest, ResumeRequest
from urb_jax.runs.suite import SuiteRun, run_progress, run_suite, status, write_report


def _runs(conf: Path, executor: FakeExecutor, day: FakeDay, **train_options) -> list[SuiteRun]:
    return [SuiteRun("train", "iqls", {"alg": "iql_star", "task_conf": "test", "hybrid_conf": str(conf),
                                       "seeds": [0, 1]}, {"executor": executor, **train_options}),
            SuiteRun("baseline", "aon", {"model": "aon", "task_conf": "test"}, {"executor": day})]


@pytest.mark.slow
def test_suite_resumes_skips_and_reports(tmp_path):
    conf = tmp_path / "hyb.json"
    conf.write_text(json.dumps({"train_days": 18, "num_envs": 2, "surrogate_days_per_round": 4,
                                "sumo_days_per_round": 2, "sumo_workers": 1, "calib_human_days": 5,
                                "calib_varied_days": 2, "calib_steps": 20, "refit_days": 4,
                                "refit_steps": 5}))
    results = tmp_path / "results"
    # a reference suite, run straight through
    ref = run_suite(_runs(conf, FakeExecutor(), FakeDay()), tmp_path / "ref", progress=False,
                    log=lambda _: None)
    # the same suite killed after the train run's first round (the baseline never started) ...
    killed = _runs(conf, FakeExecutor(), FakeDay(), stop_after_round=1)
    run_suite(killed[:1], results, progress=False, log=lambda _: None)
    assert [status(results, r) for r in killed] == ["stopped", "new"]
    planned = len(pd.read_csv(ref[0] / "rounds.csv"))  # the finished run's rounds
    [line] = run_progress(results, killed[0])  # the seeds were trained together: one group, one line
    assert re.fullmatch(rf"seeds 0, 1: 1 of {planned} rounds done, checkpoint saved [-\d: ]+; its rounds "
                        rf"took \d+ s each here, so the {planned - 1} left about \d+ s, then the test days",
                        line)
    # ... then run again: the train run resumes from its checkpoint, the baseline starts
    lines: list[str] = []
    folders = run_suite(_runs(conf, FakeExecutor(), FakeDay()), results, progress=False, log=lines.append)
    assert "resuming" in lines[0] and "starting" in lines[2]
    assert lines[1] == f"suite:   {line}"  # where the resumed run stood, from the same checkpoint
    assert [f.name for f in folders] == ["iqls_s0", "iqls_s1", "aon"]
    for a, b in zip(ref, folders, strict=True):  # the resumed suite ends exactly like the straight one
        pd.testing.assert_frame_equal(read_records(a), read_records(b))
    # the baseline replayed the train run's human phase instead of simulating it, to the same records
    assert json.loads((results / "aon" / "exp_config.json").read_text())["human_phase_from"] == "iqls_s0"
    alone = run_baseline(BaselineRequest(model="aon", task_conf="test", exp_id="aon",
                                         results_dir=str(tmp_path / "alone"),
                                         progress=False), executor=FakeDay())
    pd.testing.assert_frame_equal(read_records(alone.folder), read_records(results / "aon"))
    # a third time: everything finished, nothing simulated
    ex, day = FakeExecutor(), FakeDay()
    lines.clear()
    run_suite(_runs(conf, ex, day), results, progress=False, log=lines.append)
    assert all("skipped" in line for line in lines) and not ex.batches and not day.calls
    # the report: a table row per algorithm with both seeds, and a figure per run group
    report = write_report("test suite", folders, tmp_path / "report")
    text = report.read_text()
    assert "| iql_star | 2 |" in text and "| baseline_aon | 1 |" in text
    # each run's wall time, the two seeds trained together once, as their exp_config.json says
    walls = {f.name: json.loads((f / "exp_config.json").read_text()) for f in folders}
    iql = walls["iqls_s0"]
    assert walls["iqls_s1"]["wall_time_s"] == iql["wall_time_s"]
    assert (f"| urb_grid | iql_star | 2 | {iql['wall_time_s']:.0f} s | {iql['human_phase_s']:.0f} s |"
            in text), text
    assert f"| urb_grid | baseline_aon | 1 | {walls['aon']['wall_time_s']:.0f} s |  |" in text
    # the trained run against the humans and AON (its two seeds), and every run drawn against t_pre
    assert "## Against the humans and the baselines" in text and "| urb_grid, test | iql_star | 2 |" in text
    assert sorted(p.name for p in (tmp_path / "report" / "figures").iterdir()) == [
        "against_the_humans.png", "urb_grid_baseline_aon_test.png", "urb_grid_iql_star_test.png"]


def test_a_run_another_process_is_writing_is_running_not_stopped(tmp_path):
    """--status tells a run being written now from a stopped one (same unfinished folder), and the
    suite refuses to touch it, naming the writer, instead of resuming it under it."""
    import subprocess

    from urb_jax.core.errors import UrbJaxError

    results = tmp_path / "results"
    (results / "aon").mkdir(parents=True)
    (results / "aon" / "exp_config.json").write_text(json.dumps({"status": "created"}))
    run = SuiteRun("baseline", "aon", {"model": "aon", "task_conf": "test"}, {"executor": FakeDay()})
    assert status(results, run) == "stopped"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, pathlib; from urb_jax.runs.folder import lock_run; "
         f"lock_run(pathlib.Path({str(results / 'aon')!r})); print('locked', flush=True); sys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert status(results, run) == "running"
        with pytest.raises(UrbJaxError, match=f"being written by process {holder.pid}"):
            run_suite([run], results, progress=False, log=lambda _: None)
        assert json.loads((results / "aon" / "exp_config.json").read_text()) == {"status": "created"}
    finally:
        holder.communicate("")
    assert status(results, run) == "stopped"  # the writer ended: resumable again


@pytest.mark.slow
def test_a_suite_simulates_each_human_phase_once(tmp_path):
    """Two train runs on the same humans: the second replays the first's human phase (its executor
    sees CAV days only); a run whose human phase differs (another env seed) simulates its own."""
    conf = tmp_path / "hyb.json"
    conf.write_text(json.dumps({"train_days": 18, "num_envs": 2, "surrogate_days_per_round": 4,
                                "sumo_days_per_round": 2, "sumo_workers": 1, "calib_human_days": 5,
                                "calib_varied_days": 2, "calib_steps": 20, "refit_days": 4,
                                "refit_steps": 5}))
    args = {"task_conf": "test", "hybrid_conf": str(conf)}
    ex = [FakeExecutor() for _ in range(3)]
    runs = [SuiteRun("train", "first", {"alg": "iql_star", **args}, {"executor": ex[0]}),
            SuiteRun("train", "second", {"alg": "iql", **args}, {"executor": ex[1]}),
            SuiteRun("train", "other_seed", {"alg": "iql", "env_seed": 7, **args}, {"executor": ex[2]})]
    run_suite(runs, tmp_path / "r", progress=False, log=lambda _: None)
    cfg = {f.parent.name: json.loads(f.read_text()) for f in (tmp_path / "r").glob("*/exp_config.json")}
    assert cfg["second"]["human_phase_from"] == "first"
    assert cfg["first"]["human_phase_from"] is None and cfg["other_seed"]["human_phase_from"] is None
    assert all(cav is not None for _, cav in ex[1].batches)  # no human day simulated again
    assert any(cav is None for _, cav in ex[2].batches)
    # (a replayed human phase gives the records a simulated one would: test_hybrid_seeds.py)
    # another suite in the same folder (a second catalogue entry on the same network) replays it too
    ex4 = FakeExecutor()
    run_suite([SuiteRun("train", "later", {"alg": "iql_star", **args}, {"executor": ex4})],
              tmp_path / "r", progress=False, log=lambda _: None)
    later = json.loads((tmp_path / "r" / "later" / "exp_config.json").read_text())
    assert later["human_phase_from"] == "first" and all(cav is not None for _, cav in ex4.batches)


@pytest.mark.slow
def test_a_suite_runs_only_the_seeds_the_ledger_lacks_to_the_same_bytes(tmp_path):
    """Seeds finished on another machine (`recorded`: the paper page's ledger) are not run again: the
    suite trains the others, into the folders the whole run would have written, and a seed trained
    one at a time gets the same records whether its run's other seeds ran beside it or elsewhere."""
    conf = tmp_path / "hyb.json"
    conf.write_text(json.dumps({"train_days": 18, "num_envs": 2, "surrogate_days_per_round": 4,
                                "sumo_days_per_round": 2, "sumo_workers": 1, "calib_human_days": 5,
                                "calib_varied_days": 2, "calib_steps": 20, "refit_days": 4,
                                "refit_steps": 5, "max_vmapped_seeds": 1}))
    def run(seeds: list[int]) -> SuiteRun:
        return SuiteRun("train", "iqls", {"alg": "iql_star", "task_conf": "test", "hybrid_conf": str(conf),
                                          "seeds": seeds}, {"executor": FakeExecutor()})

    ref = run_suite([run([1, 2])], tmp_path / "ref", progress=False, log=lambda _: None)
    results, lines = tmp_path / "results", []
    assert status(results, run([1, 2]), {"iqls_s1"}) == "new"
    folders = run_suite([run([1, 2])], results, progress=False, log=lines.append, recorded={"iqls_s1"})
    assert lines[1] == "suite:   iqls_s1 finished (here or in the ledger); running iqls_s2"
    assert [f.name for f in folders] == ["iqls_s2"] and not (results / "iqls_s1").exists()
    pd.testing.assert_frame_equal(read_records(ref[1]), read_records(folders[0]))
    assert (ref[1] / "metrics" / "BenchmarkMetrics.csv").read_bytes() == \
        (folders[0] / "metrics" / "BenchmarkMetrics.csv").read_bytes()
    assert status(results, run([1, 2]), {"iqls_s1"}) == "recorded"  # nothing left: skipped from now on
    assert status(results, run([1, 2])) == "new"  # without the ledger, seed 1 is not here


@pytest.mark.parametrize("runs, message", [
    ([{"kind": "train", "id": "a", "args": {"alg": "iql", "lr": 0.1}}],
     "args \\['lr'\\] are not train arguments"),
    ([{"kind": "sweep", "id": "a"}], "needs 'kind'"),
    ([{"kind": "baseline", "id": "a", "args": {"model": "aon"}}, {"kind": "baseline", "id": "a"}],
     "used twice"),
])
def test_bad_suite_files_exit_2_naming_the_field(tmp_path, capsys, runs, message):
    from urb_jax.commands.cli import main

    path = tmp_path / "suite.json"
    path.write_text(json.dumps({"title": "t", "runs": runs}))
    assert main(["suite", str(path), "--results-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "Fix:" in err
    assert re.search(message, err)
    assert not (tmp_path / "r").exists()


def test_every_shipped_suite_loads():
    from urb_jax.core.configio import configs_dir
    from urb_jax.runs.suite import load_suite

    files = sorted((configs_dir() / "suites").glob("*.json"))
    assert files
    for path in files:
        spec = load_suite(path)
        assert spec.runs and len({r.exp_id for r in spec.runs}) == len(spec.runs)


def _fake_run(folder: Path, group: list[str], meta: dict | None = None, human: bool = True) -> None:
    folder.mkdir(parents=True)
    (folder / "exp_config.json").write_text(json.dumps({"status": "running", "group": group}))
    if human:
        (folder / "human_phase.npz").write_bytes(b"")
    if meta is not None:
        ckpt = folder / "checkpoints" / f"round_{meta['rounds_done']:05d}"
        ckpt.mkdir(parents=True)
        (ckpt / "meta.json").write_text(json.dumps(meta))


def test_progress_says_where_each_seed_group_stands(tmp_path):
    """--status between sessions: a line per group of seeds trained together, from its checkpoint's
    meta.json (rounds done of planned, the pace of its rounds so far), without reading arrays."""
    run = SuiteRun("train", "r", {"seeds": [0, 1, 2, 3, 4]})
    rows = [{"surrogate_s": 50.0, "sumo_s": 10.0}, {"surrogate_s": 70.0, "sumo_s": 10.0}]  # 70 s a round
    _fake_run(tmp_path / "r_s0", ["r_s0", "r_s1"],
              {"rounds_done": 2, "rounds_total": 5, "rounds": [rows, rows]})
    _fake_run(tmp_path / "r_s1", ["r_s0", "r_s1"])
    _fake_run(tmp_path / "r_s2", ["r_s2"])  # its group's turn has not come: the human phase is saved
    _fake_run(tmp_path / "r_s3", ["r_s3"], human=False)
    lines = run_progress(tmp_path, run)
    assert lines[0].startswith("seeds 0, 1: 2 of 5 rounds done, checkpoint saved ")
    assert lines[0].endswith("; its rounds took 70 s each here, so the 3 left about 3.5 min, then the "
                             "test days")
    assert lines[1:] == ["seed 2: no round checkpoint yet: its training starts from its saved human phase",
                         "seed 3: no checkpoint yet: its human phase and calibration come first",
                         "seed 4: not started"]
    # a checkpoint from before meta.json recorded the plan; a group past its last round; a finished group
    old = SuiteRun("train", "o", {"seeds": [0, 1, 2]})
    _fake_run(tmp_path / "o_s0", ["o_s0"], {"rounds_done": 3, "rounds": [rows]})
    _fake_run(tmp_path / "o_s1", ["o_s1"], {"rounds_done": 4, "rounds_total": 4, "rounds": [rows]})
    (tmp_path / "o_s2").mkdir()
    (tmp_path / "o_s2" / "exp_config.json").write_text(json.dumps({"status": "done", "group": ["o_s2"]}))
    lines = run_progress(tmp_path, old)
    assert lines[0].startswith("seed 0: 3 rounds done")
    assert lines[0].endswith("(the checkpoint does not say of how many)")
    assert lines[1].startswith("seed 1: 4 of 4 rounds done") and lines[1].endswith("; the test days are left")
    assert lines[2] == "seed 2: done"
    assert run_progress(tmp_path, SuiteRun("baseline", "aon")) == []


def test_progress_estimates_the_groups_not_started_and_the_run(tmp_path):
    """Seeds one at a time (Ingolstadt's QMIX): a group not started is estimated at the pace of the
    first group measured (a finished one's rounds.csv), and the run's time left is the sum."""
    run = SuiteRun("train", "e", {"seeds": [0, 1, 2]})
    (tmp_path / "e_s0").mkdir()
    (tmp_path / "e_s0" / "exp_config.json").write_text(json.dumps({"status": "done", "group": ["e_s0"]}))
    pd.DataFrame({"round": [1, 2, 3], "surrogate_s": [90.0, 95.0, 100.0], "sumo_s": [10.0, 5.0, 0.0]}
                 ).to_csv(tmp_path / "e_s0" / "rounds.csv", index=False)  # 100 s a round, 3 rounds
    _fake_run(tmp_path / "e_s1", ["e_s1"],
              {"rounds_done": 1, "rounds_total": 3, "rounds": [[{"surrogate_s": 50.0, "sumo_s": 10.0}]]})
    _fake_run(tmp_path / "e_s2", ["e_s2"])
    _fake_run(tmp_path / "e_s3", ["e_s3"], {"rounds_done": 0, "rounds_total": 3, "rounds": [[]]})
    run = SuiteRun("train", "e", {"seeds": [0, 1, 2, 3]})
    lines = run_progress(tmp_path, run)
    assert lines[0] == "seed 0: done"
    assert lines[1].endswith("its rounds took 60 s each here, so the 2 left about 2.0 min, then the test "
                             "days")
    assert lines[2] == ("seed 2: no round checkpoint yet: its training starts from its saved human phase; at "
                        "the pace of seed 0 its 3 rounds take about 5.0 min, then the test days")
    assert lines[3].startswith("seed 3: 0 of 3 rounds done, checkpoint saved ")  # no round measured yet
    assert lines[3].endswith("; at the pace of seed 0 the 3 left take about 5.0 min, then the test days")
    assert lines[4] == "the run: about 12.0 min left, plus the test days"  # 0 + 120 s + 300 s + 300 s


def test_progress_of_a_sumo_only_run_counts_its_sumo_days(tmp_path):
    """A --mode sumo run's rounds have no surrogate leg: its pace is its SUMO days' seconds."""
    rows = [{"round": 1, "sumo_days": 4, "sumo_s": 8.0}, {"round": 2, "sumo_days": 4, "sumo_s": 12.0}]
    _fake_run(tmp_path / "c_s0", ["c_s0", "c_s1"],
              {"rounds_done": 2, "rounds_total": 32, "rounds": [rows, rows]})
    _fake_run(tmp_path / "c_s1", ["c_s0", "c_s1"])
    lines = run_progress(tmp_path, SuiteRun("train", "c", {"seeds": [0, 1]}))
    assert lines[0].endswith("its rounds took 10 s each here, so the 30 left about 5.0 min, then the test "
                             "days")


@pytest.mark.slow
def test_resume_finishes_every_seed_group_of_the_run(tmp_path):
    """Seeds trained one group at a time (Ingolstadt's QMIX): a resume, by the suite or by any
    seed's id, finishes every unfinished group, not only the named seed's (a resume that continued seed 0's
    group alone, then reported, would leave seeds 1 and 2 never trained)."""
    from urb_jax.runs.train import _resume_group, resume_train

    conf = tmp_path / "hyb.json"
    conf.write_text(json.dumps({"train_days": 12, "num_envs": 2, "surrogate_days_per_round": 4,
                                "sumo_days_per_round": 2, "sumo_workers": 1, "calib_human_days": 5,
                                "calib_varied_days": 2, "calib_steps": 20, "refit_days": 4,
                                "refit_steps": 5, "max_vmapped_seeds": 1}))
    ref = run_suite(_runs(conf, FakeExecutor(), FakeDay())[:1], tmp_path / "ref", progress=False,
                    log=lambda _: None)
    for results in (tmp_path / "suite", tmp_path / "by_id"):  # both groups killed after round 1
        run_suite(_runs(conf, FakeExecutor(), FakeDay(), stop_after_round=1)[:1], results, progress=False,
                  log=lambda _: None)
        # seed 0's group finished alone (the old resume): the run is still unfinished
        _resume_group(["iqls_s0"], ResumeRequest("iqls_s0", results_dir=str(results), progress=False),
                      FakeExecutor())
        assert [json.loads((results / f"iqls_s{s}" / "exp_config.json").read_text())["status"]
                for s in (0, 1)] == ["done", "running"]
    run_suite(_runs(conf, FakeExecutor(), FakeDay())[:1], tmp_path / "suite", progress=False,
              log=lambda _: None)
    resume_train(ResumeRequest("iqls_s0", results_dir=str(tmp_path / "by_id"), progress=False),
                 executor=FakeExecutor())
    for results in (tmp_path / "suite", tmp_path / "by_id"):
        for a in ref:  # every seed finished, with the uninterrupted run's records
            pd.testing.assert_frame_equal(read_records(a), read_records(results / a.name))
        with pytest.raises(Exception, match="already complete"):
            resume_train(ResumeRequest("iqls_s1", results_dir=str(results), progress=False),
                         executor=FakeExecutor())
