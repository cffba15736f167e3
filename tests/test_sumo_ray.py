"""RayExecutor on a local Ray instance: same days as in-process and pool runs, order, files shipped
through the object store, a killed actor replaced with its day retried, failures reported."""

from __future__ import annotations

import logging
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from support.kill_worker import run_killing_a_busy_worker

from urb_jax.core.errors import UrbJaxError
from urb_jax.runs.request import ResumeRequest
from urb_jax.sumo_bridge import InProcessExecutor, SumoDayError, SumoPool

pytestmark = pytest.mark.sumo


@pytest.fixture(scope="module")
def ray_local():
    ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'urb-jax[ray]')")
    # Logical CPUs: the shared executor (2 actors), a one-off executor and the trainer's own
    # 2 actors can coexist; they all share the machine's real cores.
    ray.init(address="local", num_cpus=5, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def rex(ray_local, tmp_path_factory):
    from urb_jax.sumo_bridge.ray_executor import RayExecutor

    ex = RayExecutor(2, log_dir=tmp_path_factory.mktemp("ray-logs"), day_timeout_s=120)
    assert not ex.owns_ray  # an initialised Ray is used as is and left running
    yield ex
    ex.close()


@pytest.fixture(scope="module")
def days(grid_scenario):
    rng = np.random.default_rng(11)
    choices = rng.integers(0, grid_scenario.k, size=(4, grid_scenario.n_agents))
    choices[1] = choices[0]  # days 0 and 1 are the same day, run by different actors at once
    seeds = [5, 5, 6, 7]
    ref = InProcessExecutor().run_days(grid_scenario, choices, seeds)
    return choices, seeds, ref


def test_ray_days_equal_in_process_and_pool_days_in_order(rex, grid_scenario, days, tmp_path):
    choices, seeds, ref = days
    out = rex.run_days(grid_scenario, choices, seeds)
    assert [r.seed for r in out] == seeds
    assert all(a.same_as(b) for a, b in zip(out, ref, strict=True))
    assert out[0].same_as(out[1]) and not out[0].same_as(out[2])
    with SumoPool(2, log_dir=tmp_path) as pool:
        pooled = pool.run_days(grid_scenario, choices, seeds)
    assert all(a.same_as(b) for a, b in zip(out, pooled, strict=True))
    assert all(np.array_equal(a.travel_time, b.travel_time) for a, b in zip(out, pooled, strict=True))
    back = rex.run_days(grid_scenario, choices[::-1], seeds[::-1])  # batch order, not completion order
    assert all(a.same_as(b) for a, b in zip(back, ref[::-1], strict=True))
    assert all(Path(s.log_path).exists() for s in rex.slots)


def test_ray_takes_per_day_cav_masks_and_rejects_bad_batches(rex, grid_scenario):
    from urb_jax.sumo_bridge import run_day

    rng = np.random.default_rng(2)
    choices = rng.integers(0, grid_scenario.k, size=(2, grid_scenario.n_agents))
    cav = rng.random((2, grid_scenario.n_agents)) < 0.5
    out = rex.run_days(grid_scenario, choices, [9, 9], is_cav=cav)
    for b in range(2):
        assert out[b].same_as(run_day(grid_scenario, choices[b], seed=9, is_cav=cav[b]))
    with pytest.raises(ValueError, match="route indices"):
        rex.run_days(grid_scenario, np.full((2, grid_scenario.n_agents), 99), [1, 2])


def test_network_file_travels_through_the_object_store(rex, grid_scenario, days, tmp_path):
    import dataclasses

    choices, seeds, ref = days
    net = tmp_path / "copy.net.xml"
    # an XML comment more: a scenario no actor has seen yet (keys hash the file's content)
    net.write_bytes(Path(grid_scenario.net_file).read_bytes() + b"\n<!-- copy -->\n")
    scn = dataclasses.replace(grid_scenario, net_file=str(net))
    rex.put_scenario(scn)  # the driver reads the file once, into the object store
    net.unlink()  # actors cannot read the driver's copy: they must use the shipped bytes
    out = rex.run_days(scn, choices[:2], seeds[:2])
    assert all(a.same_as(b) for a, b in zip(out, ref[:2], strict=True))


def test_killed_actor_is_replaced_and_its_day_repeated(rex, grid_scenario, days, caplog):
    choices, seeds, ref = days
    restarts = rex.restarts
    with caplog.at_level(logging.WARNING, logger="urb_jax"):
        out, killed = run_killing_a_busy_worker(rex, lambda: rex.run_days(grid_scenario, choices, seeds))
    assert killed and rex.restarts == restarts + 1
    assert killed[0] not in [s.pid for s in rex.slots]
    # one warning for the one restart, naming the actor and its SUMO log
    (warning,) = [r.getMessage() for r in caplog.records if r.name.startswith("urb_jax")
                  and r.levelno >= logging.WARNING]
    assert f"(pid {killed[0]}) died" in warning and "restarting it" in warning and "sumo_actor" in warning
    assert all(a.same_as(b) for a, b in zip(out, ref, strict=True))
    # the replacement removes the killed actor's /dev/shm files (asynchronously)
    base = Path(rex.config.shm_dir)
    deadline = time.monotonic() + 10
    while list(base.glob(f"urbjax-*-{killed[0]}-*")) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not list(base.glob(f"urbjax-*-{killed[0]}-*"))


def test_second_failure_raises_with_day_seed_and_log(ray_local, grid_scenario, tmp_path):
    from urb_jax.sumo_bridge.ray_executor import RayExecutor

    with RayExecutor(1, log_dir=tmp_path, day_timeout_s=0.05) as ex:  # no day fits in 50 ms
        with pytest.raises(SumoDayError) as err:
            ex.run_days(grid_scenario, grid_scenario.fft.argmin(1)[None], [3])
        msg = str(err.value)
        assert "urb_grid" in msg and "day 0" in msg and "seed 3" in msg and "failed twice" in msg
        assert "exceeded" in msg and str(tmp_path / "sumo_actor0.log") in msg
        assert ex.restarts == 2
        ex.day_timeout_s = 120  # still usable afterwards
        ok = ex.run_days(grid_scenario, grid_scenario.fft.argmin(1)[None], [3])
        assert ok[0].n == grid_scenario.n_agents


def test_sumo_error_is_reported_with_its_output(ray_local, grid_scenario, tmp_path):
    from urb_jax.sumo_bridge import SumoConfig
    from urb_jax.sumo_bridge.ray_executor import RayExecutor

    bad = SumoConfig(additional_files=(str(tmp_path / "missing.add.xml"),))
    with RayExecutor(1, config=bad, log_dir=tmp_path) as ex, pytest.raises(SumoDayError) as err:
        ex.run_days(grid_scenario, grid_scenario.fft.argmin(1)[None], [1])
    msg = str(err.value)
    assert "raised" in msg and "missing.add.xml" in msg.split("SUMO log tail")[1]  # SUMO's own words


def test_missing_ray_gives_the_install_command(monkeypatch):
    from urb_jax.sumo_bridge.ray_executor import import_ray

    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now raises ImportError
    with pytest.raises(UrbJaxError, match=r"pip install 'urb-jax\[ray\]'"):
        import_ray()


LISTENERS = """
import json, socket, sys
import psutil
from urb_jax.city.scenario import load_scenario
from urb_jax.sumo_bridge.ray_executor import RayExecutor

scn = load_scenario("urb_grid")
with RayExecutor(1, log_dir=sys.argv[1]) as ex:
    (day,) = ex.run_days(scn, scn.fft.argmin(1)[None], [1])  # the actors work on the loopback Ray
    me = psutil.Process()
    found = []
    for p in [me, *me.children(recursive=True)]:  # the driver, Ray's daemons, agents and actors
        for c in p.net_connections(kind="inet"):  # TCP listeners and bound UDP sockets
            if c.status == psutil.CONN_LISTEN or (c.type == socket.SOCK_DGRAM and not c.raddr):
                found.append([p.pid, p.name(), c.laddr.ip, c.laddr.port])
print(json.dumps({"n": day.n, "found": found}))
"""


def test_a_local_ray_listens_on_the_loopback_interface_only(grid_scenario, tmp_path):
    """No process of a Ray that RayExecutor starts accepts connections from other machines."""
    pytest.importorskip("ray", reason="ray is not installed (pip install 'urb-jax[ray]')")
    pytest.importorskip("psutil", reason="psutil lists the sockets")
    import ipaddress
    import json
    import subprocess

    # a fresh interpreter: this one has imported Ray already (Ray reads its single-node switch then)
    env = {k: v for k, v in os.environ.items() if k != "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"}
    out = subprocess.run([sys.executable, "-c", LISTENERS, str(tmp_path)], capture_output=True, text=True,
                         timeout=300, env=env, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["n"] == grid_scenario.n_agents
    names = {name for _, name, _, _ in got["found"]}
    assert "gcs_server" in names and "raylet" in names  # Ray's own servers were seen
    wide = [f for f in got["found"] if not ipaddress.ip_address(f[2].removeprefix("::ffff:")).is_loopback]
    assert wide == []


TINY_IQL = {"agent_frames_per_batch": 2, "mlp_depth": 1, "mlp_cells": 16, "minibatch_size": 64}
HYB = {"train_days": 12, "num_envs": 2, "surrogate_days_per_round": 4, "sumo_days_per_round": 2,
       "sumo_workers": 2, "calib_human_days": 5, "calib_varied_days": 2, "calib_steps": 20, "refit_days": 4,
       "refit_steps": 5}


def _confs(tmp_path: Path) -> list[str]:
    import json

    (tmp_path / "alg.json").write_text(json.dumps(TINY_IQL))
    (tmp_path / "hyb.json").write_text(json.dumps(HYB))
    return ["--task-conf", "test", "--alg-conf", str(tmp_path / "alg.json"), "--hybrid-conf",
            str(tmp_path / "hyb.json"), "--results-dir", str(tmp_path / "r"), "--no-progress"]


@pytest.mark.slow
def test_train_with_executor_ray_gives_the_pool_metrics(ray_local, tmp_path):
    import json

    import pandas as pd

    from urb_jax.commands.cli import main

    flags = _confs(tmp_path)
    assert main(["train", *flags, "--id", "ray", "--executor", "ray"]) == 0
    assert main(["train", *flags, "--id", "pool"]) == 0
    r = tmp_path / "r"
    cfg = json.loads((r / "ray" / "exp_config.json").read_text())
    assert cfg["train_args"]["executor"] == "ray" and cfg["status"] == "done"
    assert json.loads((r / "pool" / "exp_config.json").read_text())["train_args"]["executor"] == "pool"
    assert (r / "ray" / "sumo_actor1.log").exists()  # the actors' SUMO logs sit in the results folder
    m_ray = pd.read_csv(r / "ray" / "metrics" / "BenchmarkMetrics.csv")
    m_pool = pd.read_csv(r / "pool" / "metrics" / "BenchmarkMetrics.csv")
    pd.testing.assert_frame_equal(m_ray, m_pool)
    assert np.isfinite(m_ray.select_dtypes("number").to_numpy()).any()


def test_resume_uses_the_recorded_executor_unless_overridden(tmp_path, monkeypatch):
    import json
    import types

    from urb_jax.runs import train as run

    for exp in ("a", "b"):  # a killed run recorded with --executor ray --ray-address ...
        (tmp_path / exp).mkdir()
        (tmp_path / exp / "exp_config.json").write_text(json.dumps(
            {"status": "running", "hybrid_seed_axis": "auto", "num_agents": 3,
             "train_args": {"executor": "ray", "ray_address": "ray://head:10001", "seed": 0}}))
        ckpt = tmp_path / exp / "checkpoints" / "round_00001"  # a complete checkpoint: resumable
        ckpt.mkdir(parents=True)
        (ckpt / "meta.json").write_text("{}")
    asked = []

    class StopError(Exception):
        pass

    def fake_executor(hyb, log_dir, kind="pool", ray_address=None):
        asked.append((kind, ray_address))
        raise StopError

    scn = types.SimpleNamespace(n_agents=3, net_file="net.xml")  # the run's own network, found again
    from urb_jax.runs import setup as run_setup

    monkeypatch.setattr(run_setup, "load_setup", lambda args: run.TrainSetup(scn, *(None,) * 7))
    monkeypatch.setattr(run, "make_executor", fake_executor)
    monkeypatch.setattr(run, "check_recorded_configs", lambda *a, **k: None)  # the stub setup has no configs
    with pytest.raises(StopError):
        run.resume_train(ResumeRequest("a", results_dir=str(tmp_path), progress=False))
    with pytest.raises(StopError):
        run.resume_train(ResumeRequest("b", results_dir=str(tmp_path), progress=False, executor="pool"))
    assert asked == [("ray", "ray://head:10001"), ("pool", "ray://head:10001")]


# --- memory running out in an actor, as the pool reads it (no cluster: Ray's own error classes) --------


def _answering(ray_exceptions, answer):
    """A stand-in for the `ray` module whose one finished day gives `answer` (a value or an error)."""
    from types import SimpleNamespace

    def get(ref):
        if isinstance(answer, BaseException):
            raise answer
        return answer

    return SimpleNamespace(exceptions=ray_exceptions, get=get,
                           wait=lambda refs, num_returns, timeout: (list(refs), []))


@pytest.mark.parametrize("answer, memory, says", [
    (("oom", "Traceback ...\nMemoryError"), True, "ran out of memory (MemoryError)"),
    ("monitor", True, "ran out of memory (Ray's memory monitor)"),
    ("died_low_memory", True, "died: "),
    ("died", False, "died: The actor died unexpectedly"),  # a crash is not taken for memory
    (("err", "Traceback ...\nValueError: bad"), False, "raised:\nTraceback"),
])
def test_an_actor_out_of_memory_is_a_memory_failure_like_a_pool_worker(tmp_path, answer, memory, says):
    exceptions = pytest.importorskip("ray.exceptions", reason="ray is not installed")
    from urb_jax.sumo_bridge.ray_executor import RayExecutor, _Slot

    low = "the node was running low on memory."
    answer = {"monitor": exceptions.OutOfMemoryError(f"Task was killed due to {low}"),
              "died_low_memory": exceptions.RayActorError(error_msg=f"The actor is dead: killed, {low}"),
              "died": exceptions.ActorDiedError()}.get(answer, answer)
    (tmp_path / "sumo_actor0.log").write_text("SUMO's last words\n")
    ex = RayExecutor.__new__(RayExecutor)  # no actors: only the reading of their answers is tested
    ex._ray = _answering(exceptions, answer)
    slot = _Slot(index=0, actor=None, pid=4242, log_path=str(tmp_path / "sumo_actor0.log"), ref=object())
    (failed,) = ex.wait([slot], timeout=1).values()
    assert failed.memory is memory
    assert says in failed.text and "actor 0 (pid 4242)" in failed.text
    assert slot.ref is None
    if not (isinstance(answer, tuple) and answer[0] == "err"):  # an actor's own error carries its log tail
        assert "SUMO's last words" in failed.text
