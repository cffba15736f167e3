"""`urb-jax train --log tensorboard`: each round's rounds.csv values, live, as TensorBoard scalars
under results/<id>/tensorboard/, read back with TensorBoard's own EventAccumulator; a resumed run
shows each round once; without the extra the flag fails with exit 2 naming it, and a run without
the flag never needs it."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeExecutor
from support.tiny_runs import tiny_iql_run

from urb_jax.commands import cli
from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.round_log import round_log
from urb_jax.runs.train import resume_train, run_train

pytest.importorskip("tensorboardX", reason="the 'tensorboard' extra (tensorboardX) is not installed")
event_accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator",
                                        reason="tensorboard (the dev extra's event reader) is not installed")


@pytest.fixture(scope="module")
def confs(tmp_path_factory):
    return tiny_iql_run(tmp_path_factory.mktemp("confs"))


def _train(confs, tmp_path, exp_id, stop_after_round=None, **kw):
    req = TrainRequest(alg="iql", exp_id=exp_id, results_dir=str(tmp_path), progress=False, **confs, **kw)
    return run_train(req, executor=FakeExecutor(), stop_after_round=stop_after_round)


def _scalars(folder: Path) -> dict[str, list[tuple[int, float]]]:
    acc = event_accumulator.EventAccumulator(str(folder / "tensorboard"))
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def _assert_scalars_are_rounds_csv(folder: Path) -> None:
    rounds = pd.read_csv(folder / "rounds.csv")
    scalars = _scalars(folder)
    assert set(scalars) == {f"rounds/{c}" for c in rounds.columns if c != "round"}
    for column in rounds.columns.drop("round"):
        steps, values = zip(*scalars[f"rounds/{column}"], strict=True)
        assert list(steps) == rounds["round"].tolist(), column  # each round once, in order
        # TensorBoard stores scalars as float32
        np.testing.assert_array_equal(np.float32(values), rounds[column].to_numpy(np.float32), err_msg=column)


def test_scalars_equal_rounds_csv(confs, tmp_path):
    (out,) = _train(confs, tmp_path, "tb", log="tensorboard")
    rounds = pd.read_csv(out.folder / "rounds.csv")
    assert len(rounds) == 3  # 18 budget days in rounds of 4 surrogate + 2 SUMO days
    for column in ("sur_time_cav", "sumo_time_cav", "sur_loss", "sumo_loss", "surrogate_mape"):
        assert np.isfinite(rounds[column]).all(), column  # the means and the learner's losses
    _assert_scalars_are_rounds_csv(out.folder)


@pytest.mark.slow
def test_a_resumed_run_shows_each_round_once(confs, tmp_path):
    """Killed after round 2 (its events written), resumed: the purge marker drops the killed
    run's events, the restored rounds are written again, and the scalars equal rounds.csv."""
    (killed,) = _train(confs, tmp_path, "tb_killed", log="tensorboard", stop_after_round=2)
    assert [s for s, _ in _scalars(killed.folder)["rounds/sur_loss"]] == [1, 2]
    (final,) = resume_train(ResumeRequest("tb_killed", results_dir=str(tmp_path), progress=False),
                            executor=FakeExecutor())
    assert len(list((final.folder / "tensorboard").iterdir())) == 2  # the killed run's file and the resume's
    _assert_scalars_are_rounds_csv(final.folder)


def test_without_the_extra_log_tensorboard_exits_2_naming_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # `import tensorboardX` raises ImportError
    for extra in ([], ["--dry-run"]):
        argv = ["train", "--log", "tensorboard", "--results-dir", str(tmp_path / "r"), "--no-progress",
                *extra]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert "pip install 'urb-jax[tensorboard]'" in err and "--log tensorboard" in err
    assert not (tmp_path / "r").exists()  # refused before any folder or SUMO day


def test_a_run_without_log_does_not_need_the_extra(tmp_path, monkeypatch):
    """Without --log nothing imports tensorboardX: not the run's modules, not the round hook."""
    import subprocess

    code = ("import sys, urb_jax.commands.cli, urb_jax.runs.train, urb_jax.runs.round_log; "
            "print('tensorboardX' in sys.modules)")
    env = {"PYTHONPATH": str(Path(__file__).resolve().parents[1]), "PATH": ""}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == "False"
    monkeypatch.setitem(sys.modules, "tensorboardX", None)
    with round_log([tmp_path], None, resumed=False) as on_round:
        assert on_round is None
    assert not (tmp_path / "tensorboard").exists()
