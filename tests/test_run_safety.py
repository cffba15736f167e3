"""Nothing lost: a run killed at any instant of its finish resumes to the same records and
metrics; ids are plain names; --overwrite removes only a urb-jax run; one writer per folder."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from support.digests import result_digests
from support.fakeday import FakeExecutor
from support.tiny_runs import train_iql

from urb_jax.core.errors import UrbJaxError
from urb_jax.reporting import records as records_module
from urb_jax.runs import folder as run_folder
from urb_jax.runs import train as run_module
from urb_jax.runs.folder import ResultsExistError, create_results_dir
from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.train import resume_train


class Killed(BaseException):
    """A kill -9 stand-in: nothing after the raising step runs (not an Exception, no cleanup)."""


@pytest.mark.slow
@pytest.mark.parametrize("instant", ["after_merge", "after_metrics", "after_done"])
def test_kill_at_every_instant_of_the_finish_resumes_identically(confs, tmp_path, monkeypatch, instant,
                                                                 tiny_iql_reference):
    """The case that lost data: records merged and parts deleted before `status: done`, so the
    resume replayed the test days over a test-only records file (123,200 rows became 40,000)."""
    want = result_digests(tiny_iql_reference[0].folder)  # the run on `confs`, uninterrupted (conftest.py)
    assert want is not None

    def die(*_, **__):
        raise Killed(instant)

    if instant == "after_merge":  # records.parquet written, nothing else
        monkeypatch.setattr(run_module, "write_outputs", die)
    elif instant == "after_metrics":  # metric files written too, exp_config still says running
        real = run_folder.write_config
        monkeypatch.setattr(run_module, "mark_done", lambda folder, config, **u: die())
        monkeypatch.setattr(run_folder, "write_config", real)
    else:  # exp_config says done, the merged parts not yet removed
        monkeypatch.setattr(run_folder, "remove_parts", die)
    with pytest.raises(Killed):
        train_iql(confs, tmp_path, "k")
    monkeypatch.undo()
    folder = tmp_path / "k"
    assert (folder / "records.parts").is_dir()  # the parts outlive every instant before done
    if instant == "after_done":
        with pytest.raises(UrbJaxError, match="already complete"):
            resume_train(ResumeRequest("k", results_dir=str(tmp_path), progress=False),
                         executor=FakeExecutor())
        assert not (folder / "records.parts").exists()  # the interrupted last step, finished
    else:
        resume_train(ResumeRequest("k", results_dir=str(tmp_path), progress=False), executor=FakeExecutor())
    assert json.loads((folder / "exp_config.json").read_text())["status"] == "done"
    assert result_digests(folder) == want
    assert not (folder / "records.parts").exists()


def test_truncate_drops_a_merged_file_from_a_later_instant(tmp_path):
    (tmp_path / records_module.RECORDS_FILE).write_bytes(b"stale")
    writer = records_module.RecordsWriter(tmp_path, [1], [0], [0])
    writer.truncate(0)
    assert not (tmp_path / records_module.RECORDS_FILE).exists()


@pytest.mark.parametrize("bad", [".", "..", "../x", "/tmp/x", "a/b", "", ".hidden", "a b"])
def test_an_id_is_one_plain_name(tmp_path, bad):
    """`--id . --overwrite` deleted every run in the results dir; '..' or an absolute path any folder."""
    keep = tmp_path / "other_run"
    keep.mkdir()
    (keep / "exp_config.json").write_text("{}")
    with pytest.raises(UrbJaxError, match=r"one plain name.*Fix: pass e.g. --id"):
        create_results_dir(tmp_path, bad, overwrite=True)
    assert (keep / "exp_config.json").is_file()


def test_overwrite_removes_only_a_urb_jax_run(tmp_path):
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    with pytest.raises(ResultsExistError, match=r"not a urb-jax run.*will not remove it"):
        create_results_dir(tmp_path, "notes", overwrite=True)
    assert (mine / "thesis.tex").read_text() == "precious"


def test_results_dir_that_is_a_file_is_named(tmp_path):
    f = tmp_path / "results"
    f.write_text("")
    with pytest.raises(UrbJaxError, match="is a file, not a folder"):
        create_results_dir(f, "x")


HOLD = """
import sys, time
from urb_jax.runs.folder import create_results_dir
folder = create_results_dir(sys.argv[1], "same", overwrite=True)
(folder / "exp_config.json").write_text("{}")
print("locked", flush=True)
time.sleep(60)
"""


def test_one_writer_per_run_folder(tmp_path):
    """Two runs with one id and --overwrite both wrote into one folder (30 of 30 tries)."""
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(UrbJaxError, match=rf"being written by process {holder.pid}\. Fix: wait"):
            create_results_dir(tmp_path, "same", overwrite=True)
    finally:
        holder.kill()
        holder.wait()
    # the owner died: its lock is gone with it, the next run takes the folder over
    create_results_dir(tmp_path, "same", overwrite=True)
    assert (tmp_path / ".same.lock").read_text().strip() == str(os.getpid())


def test_resume_of_an_unknown_id(tmp_path):
    """(A run without a checkpoint now resumes from its start: tests/test_faults.py.)"""
    with pytest.raises(UrbJaxError, match="no urb-jax run 'nope' here"):
        resume_train(ResumeRequest("nope", results_dir=str(tmp_path), progress=False))


@pytest.mark.parametrize("days", [0, -5])
def test_train_days_zero_or_negative_is_refused(tmp_path, days):
    """--train-days 0 silently trained the 1,000-day default; negative budgets ran a full round."""
    from urb_jax.core.errors import ConfigError

    with pytest.raises(ConfigError, match=rf"--train-days {days}: .*Fix: pass --train-days 1 or more"):
        run_module.run_train(TrainRequest(train_days=days, results_dir=str(tmp_path), progress=False),
                             executor=FakeExecutor())
    assert not any(tmp_path.iterdir())  # refused before any folder or SUMO day


def test_hybrid_config_values_are_validated(tmp_path):
    from urb_jax.core.configio import load_json
    from urb_jax.core.errors import ConfigError
    from urb_jax.training.hybrid.plan import HybridConfig

    bad = tmp_path / "hyb.json"
    bad.write_text(json.dumps({"num_envs": 0}))
    with pytest.raises(ConfigError, match=r"hyb.json: key 'num_envs' is 0\. Fix: use an integer in "
                                          r"\[1, 16384\]"):
        load_json(HybridConfig, bad)
    bad.write_text(json.dumps({"seed_axis": "pmap"}))
    with pytest.raises(ConfigError, match=r"key 'seed_axis' is 'pmap'\. Fix: use one of auto, vmap, map"):
        load_json(HybridConfig, bad)



def test_a_run_killed_outright_keeps_its_time_up_to_its_last_checkpoint(confs, tmp_path, monkeypatch):
    """A kill -9 writes no wall_time_s to exp_config.json: the resumed run's wall time still counts
    the killed process's time up to its newest checkpoint (before: only the resume's own time)."""
    from urb_jax.training.hybrid.trainer import HybridTrainer

    real_round = HybridTrainer.run_round

    def dies_in_round_2(self, r):
        if r == 1:
            raise Killed("round 2")
        return real_round(self, r)

    monkeypatch.setattr(HybridTrainer, "run_round", dies_in_round_2)
    with pytest.raises(Killed):
        train_iql(confs, tmp_path, "k")
    monkeypatch.undo()
    folder = tmp_path / "k"
    config = json.loads((folder / "exp_config.json").read_text())
    assert config["status"] == "running" and "wall_time_s" not in config  # what the kill left
    meta = json.loads((folder / "checkpoints" / "round_00001" / "meta.json").read_text())
    (row,) = meta["rounds"][0]  # round 1 was checkpointed: its time and the human phase's are in
    assert meta["wall_s"] >= config["human_phase_s"] + row["surrogate_s"] + row["sumo_s"]
    (out,) = resume_train(ResumeRequest("k", results_dir=str(tmp_path), progress=False),
                          executor=FakeExecutor())
    done = json.loads((folder / "exp_config.json").read_text())
    assert done["status"] == "done" and done["wall_time_s"] == round(out.wall_time_s, 2)
    assert out.wall_time_s > meta["wall_s"]
