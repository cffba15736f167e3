"""Faults and bad input: a run stopped in its human phase resumes to the
same results; Ctrl-C and a full disk end a run with a message that says how to go on; tasks whose
metrics could not exist are refused before any SUMO day; --seeds and config paths."""

from __future__ import annotations

import errno
import json
import os
import re
import sys
from collections import namedtuple
from pathlib import Path

import pytest
from support.digests import result_digests
from support.fakeday import FakeExecutor

from urb_jax.commands.cli import main
from urb_jax.core.errors import ConfigError
from urb_jax.core.interrupt import DiskFullError, InterruptedRunError, no_space
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.folder import machine
from urb_jax.runs.request import BaselineRequest, ResumeRequest, TrainRequest
from urb_jax.runs.train import resume_train, run_train
from urb_jax.training import checkpoints
from urb_jax.training.checkpoints import latest_checkpoint
from urb_jax.training.human_phase import JOURNAL_DIR

H = 10  # configs/task/test.json



def _train(confs, tmp_path, exp_id, executor=None, stop_after_round=None, **kw):
    req = TrainRequest(alg="iql", exp_id=exp_id, results_dir=str(tmp_path), progress=False, **{**confs, **kw})
    return run_train(req, executor=executor or FakeExecutor(), stop_after_round=stop_after_round)


@pytest.fixture(scope="module")
def reference(tiny_iql_reference):
    """The run on `confs`, uninterrupted (tests/conftest.py)."""
    ref, ex = tiny_iql_reference
    assert result_digests(ref.folder) is not None
    return {"digest": result_digests(ref.folder), "days": sum(len(b) for b, _ in ex.batches)}


def test_a_run_stopped_in_its_human_phase_resumes_to_the_same_results(confs, tmp_path, reference):
    """Before: exp_config.json came after the human phase, so such a folder was neither resumable
    nor replaceable by --overwrite; now the run resumes, reading its finished human days back."""
    with pytest.raises(InterruptedRunError, match=r"no checkpoint yet; the SUMO days of its human phase "
                                                  r"are kept\. Continue with: urb-jax train --resume k "):
        _train(confs, tmp_path, "k", FakeExecutor(fail_on_call=5))  # the 2 varied days, then human day 4
    folder = tmp_path / "k"
    assert json.loads((folder / "exp_config.json").read_text())["status"] == "running"
    assert 0 < len(list((folder / JOURNAL_DIR).rglob("*.npz"))) <= 5  # a repeated day is stored once
    ex = FakeExecutor()
    (out,) = resume_train(ResumeRequest("k", results_dir=str(tmp_path), progress=False), executor=ex)
    assert sum(len(b) for b, _ in ex.batches) <= reference["days"] - 5  # those 5 (and repeats) read back
    assert result_digests(out.folder) == reference["digest"]
    assert not (folder / JOURNAL_DIR).exists()  # the run's own journal goes once it is done
    cfg = json.loads((folder / "exp_config.json").read_text())
    assert cfg["resumed"] == 1 and cfg["resumed_on"] == [machine()]  # where the resume computed too


def test_a_stopped_run_can_be_replaced_with_overwrite(confs, tmp_path):
    with pytest.raises(InterruptedRunError):
        _train(confs, tmp_path, "k", FakeExecutor(fail_on_call=1))
    (out,) = _train(confs, tmp_path, "k", overwrite=True)
    assert json.loads((out.folder / "exp_config.json").read_text())["status"] == "done"


def test_a_full_disk_keeps_the_last_checkpoint_and_resumes(confs, tmp_path, monkeypatch, reference):
    """Before: orbax's traceback per array, and a partial checkpoint directory."""
    real = checkpoints.shutil.disk_usage
    usage = namedtuple("usage", "total used free")
    calls = []

    def filling(path):
        calls.append(path)
        return usage(1, 1, 1000) if len(calls) >= 3 else real(path)  # round 2's checkpoint

    monkeypatch.setattr(checkpoints.shutil, "disk_usage", filling)
    want = (rf"no space left on device in {re.escape(str(tmp_path))}\. .*needs about .* MiB, 0\.0 MiB are "
            r"free.*last complete checkpoint \(round 1\) is kept\. Continue with: urb-jax train --resume k")
    with pytest.raises(DiskFullError, match=want):
        _train(confs, tmp_path, "k")
    monkeypatch.undo()
    folder = tmp_path / "k"
    assert latest_checkpoint(folder)[0] == 1  # the partial round_00002 (no meta.json) is skipped
    (out,) = resume_train(ResumeRequest("k", results_dir=str(tmp_path), progress=False),
                          executor=FakeExecutor())
    assert result_digests(out.folder) == reference["digest"]


def test_a_full_disk_is_recognised_through_library_wrappers():
    orbax_like = ValueError("RESOURCE_EXHAUSTED: Error writing: No space left on device [os_error_code='28']")
    assert no_space(orbax_like)
    try:
        try:
            raise OSError(errno.ENOSPC, "write")
        except OSError as inner:
            raise RuntimeError("pyarrow failed") from inner
    except RuntimeError as outer:
        assert no_space(outer)
    assert not no_space(ValueError("RESOURCE_EXHAUSTED: out of memory"))
    assert not no_space(OSError(errno.EACCES, "denied"))


def _task(tmp_path: Path, **values) -> str:
    task = json.loads((Path(__file__).parents[1] / "configs" / "task" / "test.json").read_text())
    path = tmp_path / "task.json"
    path.write_text(json.dumps({**task, **values}))
    return str(path)


def test_a_task_without_cavs_is_refused_before_any_sumo_day(confs, tmp_path):
    """Before: the whole human phase ran, then orbax crashed on zero-size arrays."""
    ex = FakeExecutor()
    results = tmp_path / "results"
    with pytest.raises(ConfigError, match=r"task.json: key 'ratio_machines' 0.001 makes 0 of the 400 agents "
                                          r"CAVs.*Fix: .*urb-jax baseline --task-conf"):
        _train(confs, results, "k", ex, task_conf=_task(tmp_path, ratio_machines=0.001))
    assert ex.batches == [] and not results.exists()


class _NoDays:
    """A DayExecutor for runs that must be refused before their first day."""

    def run_days(self, *_args, **_kwargs):
        pytest.fail("no SUMO day")

    def close(self) -> None:
        pass


@pytest.mark.parametrize(("key", "metric"), [("test_eps", "t_CAV"), ("human_learning_episodes", "t_pre")])
def test_a_task_whose_metrics_cannot_exist_is_refused(confs, tmp_path, key, metric):
    """Before: exit 0 with N/A metrics."""
    task = _task(tmp_path, **{key: 0})
    with pytest.raises(ConfigError, match=rf"key '{key}' is 0, but .*{metric}.*Fix: set it to 1 or more"):
        _train(confs, tmp_path / "results", "k", task_conf=task)
    with pytest.raises(ConfigError, match=rf"key '{key}' is 0"):
        run_baseline(BaselineRequest(task_conf=task, results_dir=str(tmp_path / "results"), progress=False),
                     executor=_NoDays())
    assert not (tmp_path / "results").exists()


@pytest.mark.parametrize(("seeds", "message"), [("a,b", "seeds are comma-separated integers"),
                                                ("0,0", "seed 0 is given twice")])
def test_bad_seeds_are_refused_before_any_folder(tmp_path, capsys, seeds, message):
    with pytest.raises(SystemExit) as exit_:
        main(["train", "--seeds", seeds, "--results-dir", str(tmp_path / "r")])
    assert exit_.value.code == 2
    assert f"argument --seeds: {seeds!r}: {message}" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_resume_from_another_folder_finds_a_relative_task_config(confs, tmp_path, monkeypatch):
    (tmp_path / "a").mkdir()
    monkeypatch.chdir(tmp_path / "a")
    _task(tmp_path / "a")
    (out,) = _train(confs, tmp_path / "r", "k", task_conf="task.json", stop_after_round=1)
    args = json.loads((out.folder / "exp_config.json").read_text())["train_args"]
    assert args["task_conf"] == str(tmp_path / "a" / "task.json")  # recorded resolved
    monkeypatch.chdir(tmp_path)
    (done,) = resume_train(ResumeRequest("k", results_dir=str(tmp_path / "r"), progress=False),
                           executor=FakeExecutor())
    assert json.loads((done.folder / "exp_config.json").read_text())["status"] == "done"


def test_ctrl_c_restarts_no_worker():
    """Before: the scheduler restarted every busy worker while handling Ctrl-C."""
    import numpy as np

    from urb_jax.city.scenario import load_scenario
    from urb_jax.sumo_bridge.scheduler import schedule_days

    class Slot:
        def __init__(self, index):
            self.index, self.task, self.started, self.finished = index, None, 0.0, 0.0

    class Backend:
        def __init__(self):
            self.slots, self.restarts = [Slot(0), Slot(1)], 0

        def submit(self, slot, job):
            return None

        def wait(self, busy, timeout):
            raise KeyboardInterrupt

        def overdue(self, slot):
            raise AssertionError

        def restart(self, slot):
            self.restarts += 1

    scn = load_scenario("urb_grid")
    backend = Backend()
    with pytest.raises(KeyboardInterrupt):
        schedule_days(backend, scn, np.zeros((2, scn.n_agents), np.int32), [1, 2], None, day_timeout_s=60)
    assert backend.restarts == 0
    assert all(s.task is not None for s in backend.slots)  # busy: closing the executor kills them


@pytest.mark.slow
@pytest.mark.sumo
@pytest.mark.parametrize(("presses", "sig"), [(1, "SIGINT"), (2, "SIGINT"), (1, "SIGTERM"), (1, "SIGHUP")])
def test_ctrl_c_stops_a_real_run_within_seconds(confs, tmp_path, presses, sig):
    """Before: the first SIGINT was swallowed and the second hung for over a minute. Now one press
    stops the run (exit 130, the resume command printed, SUMO workers gone); two exit at once.
    SIGTERM and SIGHUP, sent to the whole group as Slurm and a closing terminal do, stop it alike
    (exit 143, 129), and the SUMO workers, which leave the signal to the run, print no traceback."""
    import signal
    import subprocess
    import time

    signum = getattr(signal, sig)

    hyb = json.loads(Path(confs["hybrid_conf"]).read_text())
    (tmp_path / "hyb.json").write_text(json.dumps({**hyb, "sumo_workers": 2}))
    cmd = [sys.executable, "-m", "urb_jax.commands.cli", "train", "--results-dir", str(tmp_path), "--id", "k",
           "--task-conf", "test", "--hybrid-conf", str(tmp_path / "hyb.json"), "--alg-conf",
           confs["alg_conf"], "--no-progress"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    journal = tmp_path / "k" / JOURNAL_DIR
    deadline = time.monotonic() + 240
    while not (journal.is_dir() and any(journal.rglob("*.npz"))):  # SUMO days are running
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.poll() else ""
        time.sleep(0.2)
    workers = [int(p) for p in subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True,
                                              text=True).stdout.split()]
    t0 = time.monotonic()
    for _ in range(presses):
        os.killpg(proc.pid, signum)  # as a terminal does: the whole foreground group
        time.sleep(0.3)
    err = proc.communicate(timeout=60)[1]
    took = time.monotonic() - t0
    assert proc.returncode == 128 + signum, err
    assert took < 15, took
    if presses == 1:
        assert "Continue with: urb-jax train --resume k" in err and "Traceback" not in err
        assert f"stopped by {'Ctrl-C' if sig == 'SIGINT' else sig}." in err
        logs = [p.read_text() for p in (tmp_path / "k").rglob("sumo_worker*.log")]
        assert len(logs) == 2 and not any("Traceback" in log for log in logs), logs
    else:  # the first press may already have ended the run before the second is handled
        assert "interrupted twice: exiting now" in err or "Continue with: urb-jax train --resume k" in err
    time.sleep(0.5)
    alive = [p for p in workers if Path(f"/proc/{p}").exists()
             and "zombie" not in Path(f"/proc/{p}/status").read_text()]
    assert not alive, alive
    assert (tmp_path / ".k.lock").read_text() == ""  # no owner left to "take over" from


def test_mode_sumo_checkpoints_stay_bounded(confs, tmp_path):
    """--mode sumo wrote every SUMO day so far into each round's checkpoint (about 175 GB over a
    mantes-sized run); only the hybrid refit reads them."""
    import numpy as np

    (out,) = _train(confs, tmp_path, "s", mode="sumo", stop_after_round=3)
    with np.load(out.folder / "checkpoints" / "round_00003" / "sumo_days.npz") as z:
        assert z["choices_0"].shape[0] == 0
