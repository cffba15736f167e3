"""SIGTERM (Slurm, systemd, kill) and SIGHUP (a closed terminal) stop a run like Ctrl-C: the resume
line, no traceback, exit 128 + the signal (143, 129). SUMO workers leave the signals to their parent
and end quietly when it is gone. Before: exit 143/129 with no resume line, and a worker's
BrokenPipeError traceback in the human phase."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from urb_jax.core import interrupt

TESTS = Path(__file__).resolve().parent

# A tiny train run whose SUMO days are FakeDays, each batch taking 0.3 s; writes `marker` when the
# first batch starts (the human phase), so the test signals a run that is computing.
SLOW_RUN = """
import sys, time
from pathlib import Path
from support.fakeday import FakeExecutor
import urb_jax.runs.train as train

marker = Path(sys.argv[1])


class Slow(FakeExecutor):
    def run_days(self, *args, **kwargs):
        marker.write_text("running")
        time.sleep(0.3)
        return super().run_days(*args, **kwargs)


train.make_executor = lambda *args, **kwargs: Slow()
from urb_jax.commands.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize(("sig", "code", "name"),
                         [(signal.SIGTERM, 143, "SIGTERM"), (signal.SIGHUP, 129, "SIGHUP")])
def test_a_signal_stops_a_run_with_its_resume_line(confs, tmp_path, sig, code, name):
    marker = tmp_path / "started"
    cmd = [sys.executable, "-c", SLOW_RUN, str(marker), "train", "--results-dir", str(tmp_path), "--id", "k",
           "--task-conf", confs["task_conf"], "--hybrid-conf", confs["hybrid_conf"], "--alg-conf",
           confs["alg_conf"], "--no-progress"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    deadline = time.monotonic() + 120
    while not marker.exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.1)
    os.killpg(proc.pid, sig)  # as Slurm and a closing terminal do: the whole process group
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert f"stopped by {name}. It had no checkpoint yet" in err, err
    assert "Continue with: urb-jax train --resume k" in err and "Traceback" not in err, err
    assert "t_CAV" not in out
    assert (tmp_path / ".k.lock").read_text() == ""  # no owner left to "take over" from


def test_the_stop_signal_names_the_stop_and_sets_the_exit_code(monkeypatch):
    monkeypatch.setattr(interrupt, "_presses", 0)
    monkeypatch.setattr(interrupt, "_received", signal.SIGINT)
    assert (interrupt.stop_cause(), interrupt.exit_code()) == ("Ctrl-C", 130)
    for sig, name, code in ((signal.SIGTERM, "SIGTERM", 143), (signal.SIGHUP, "SIGHUP", 129)):
        monkeypatch.setattr(interrupt, "_presses", 0)
        with pytest.raises(KeyboardInterrupt):  # what every layer takes as a clean stop
            interrupt._on_stop(sig, None)
        assert (interrupt.stop_cause(), interrupt.exit_code()) == (name, code)
    monkeypatch.setattr(interrupt, "_presses", 1)
    interrupt._note(signal.SIGINT)  # a later signal does not rename the stop
    assert interrupt.stop_cause() == "SIGHUP"


def test_handle_interrupts_installs_and_restores_every_stop_signal():
    before = {sig: signal.getsignal(sig) for sig in interrupt.STOP_SIGNALS}
    with interrupt.handle_interrupts():
        assert all(signal.getsignal(sig) is interrupt._on_stop for sig in interrupt.STOP_SIGNALS)
    assert {sig: signal.getsignal(sig) for sig in interrupt.STOP_SIGNALS} == before


@pytest.mark.sumo
def test_a_sumo_worker_leaves_stop_signals_to_its_parent_and_ends_quietly(grid_scenario, tmp_path):
    from urb_jax.sumo_bridge import SumoPool

    pool = SumoPool(1, log_dir=tmp_path)
    try:
        w = pool.slots[0]
        for sig in interrupt.STOP_SIGNALS:
            os.kill(w.proc.pid, sig)
        time.sleep(0.5)
        assert w.proc.is_alive()
        # the parent stops while the worker runs a day: its answer meets a closed pipe
        choices = np.zeros(grid_scenario.n_agents, np.int32)
        w.conn.send(("day", 0, "k", grid_scenario, choices, 1, None, None))
        w.conn.close()
        w.proc.join(timeout=60)
        assert w.proc.exitcode == 0
        log = w.log_path.read_text()
        assert "Traceback" not in log and "BrokenPipeError" not in log, log
    finally:
        pool.slots.clear()
        pool.close()
