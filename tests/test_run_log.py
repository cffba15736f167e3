"""What happened to a run stays with it: urb-jax's warnings (a restarted SUMO worker, a rebuilt
cache) land once on stderr and once in the results folder's run.log, and every file urb-jax
writes in a results folder or the cache has the mode open() gives (0644 under umask 022)."""

from __future__ import annotations

import json
import logging
import os
import stat
from pathlib import Path

import numpy as np
import pytest
from support.fakeday import FakeDay, FakeExecutor
from support.tiny_runs import train_iql

from urb_jax.city.routes import RouteParams
from urb_jax.city.scenario import load_scenario
from urb_jax.core import atomic
from urb_jax.core.paths import cache_dir
from urb_jax.game.config import load_env_config
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.request import BaselineRequest
from urb_jax.runs.run_log import RUN_LOG, log_run_to, run_log
from urb_jax.sumo_bridge.memo import MemoExecutor

TINY = {"human_learning_episodes": 3, "training_eps": 2, "test_eps": 2}


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _route_params(env_conf: str = "config1") -> RouteParams:
    return load_env_config(env_conf)[0].route_params()


def _corrupt_scenario_cache() -> Path:
    """The urb_grid scenario cache entry a run with env config1 and seed 42 reads, made junk."""
    load_scenario("urb_grid", env_seed=42, route_params=_route_params())
    (entry,) = (cache_dir() / "scenarios").glob("urb_grid-*.npz")
    entry.write_bytes(b"not an npz")
    return entry


def test_warnings_before_and_after_the_folder_is_known_reach_run_log_once(tmp_path, caplog):
    log = logging.getLogger("urb_jax.test")
    with caplog.at_level(logging.WARNING, logger="urb_jax"), run_log():
        log.warning("before the folder")  # a train run loads its scenario before creating the folder
        log.info("not a warning")
        log_run_to(tmp_path)
        log.warning("after the folder")
    log.warning("after the run")
    lines = (tmp_path / RUN_LOG).read_text().splitlines()
    assert len(lines) == 2 and lines[0].endswith("WARNING urb_jax.test: before the folder")
    assert lines[1].endswith("WARNING urb_jax.test: after the folder")
    assert [r.getMessage() for r in caplog.records if r.name == "urb_jax.test"] == [
        "before the folder", "after the folder", "after the run"]  # each once through the root logger


def test_a_corrupt_scenario_cache_is_rebuilt_with_one_warning_in_the_run_log(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("URB_JAX_CACHE", str(tmp_path / "cache"))
    entry = _corrupt_scenario_cache()
    with caplog.at_level(logging.WARNING, logger="urb_jax"):
        out = run_baseline(BaselineRequest(model="aon", task_conf="config1",
                                           results_dir=str(tmp_path / "results"),
                                           progress=False), executor=FakeDay(), task_overrides=TINY)
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and str(entry) in warnings[0] and "rebuilding it" in warnings[0]
    (line,) = (out.folder / RUN_LOG).read_text().splitlines()
    assert line.endswith(warnings[0])
    load_scenario("urb_grid", env_seed=42, route_params=_route_params())  # rebuilt: read without a warning
    assert len([r for r in caplog.records if r.levelno >= logging.WARNING]) == 1


def test_the_atomic_writer_gives_the_mode_open_gives(tmp_path):
    old = os.umask(0o027)
    try:
        atomic.write_text(tmp_path / "atomic.txt", "x")
        (tmp_path / "plain.txt").write_text("x")
    finally:
        os.umask(old)
    assert _mode(tmp_path / "atomic.txt") == _mode(tmp_path / "plain.txt") == 0o640


@pytest.fixture(scope="module")
def train_run(confs, tmp_path_factory):
    """A short train run (fake SUMO) on a fresh cache whose scenario entry is damaged, plus a
    day cache entry on disk as the surrogate's SUMO days keep them."""
    root = tmp_path_factory.mktemp("train-run")
    old_cache = os.environ["URB_JAX_CACHE"]
    os.environ["URB_JAX_CACHE"] = str(root / "cache")
    try:
        entry = _corrupt_scenario_cache()
        (out,) = train_iql(confs, root / "results", "run")
        scn = load_scenario("urb_grid")
        MemoExecutor(FakeExecutor(), store_dir=cache_dir() / "sumo_days").run_days(
            scn, np.zeros((1, scn.n_agents), np.int64), [42])
    finally:
        os.environ["URB_JAX_CACHE"] = old_cache
    return out.folder, root / "cache", entry


def test_a_train_run_logs_the_rebuilt_scenario_cache_in_its_folder(train_run):
    folder, _, entry = train_run
    (line,) = (folder / RUN_LOG).read_text().splitlines()  # logged before the folder existed
    assert "WARNING urb_jax.city.scenario" in line and str(entry) in line and "rebuilding it" in line


def test_every_file_in_the_results_folder_and_the_cache_has_the_config_files_mode(train_run):
    folder, cache, _ = train_run
    want = _mode(folder / "exp_config.json")
    umask = atomic.umask()
    assert want == 0o666 & ~umask  # 0644 under umask 022
    files = [p for root in (folder, cache) for p in root.rglob("*") if p.is_file()]
    names = {p.name for p in files}
    assert {"records.parquet", "human_phase.npz", "rounds.csv", RUN_LOG, "surrogate_error.png"} <= names
    assert any(p.parent.name == "state" for p in files)  # orbax's checkpoint files
    assert any("sumo_days" in p.parts for p in files) and any("scenarios" in p.parts for p in files)
    assert {str(p): oct(_mode(p)) for p in files if _mode(p) != want} == {}
    assert json.loads((folder / "exp_config.json").read_text())["status"] == "done"
