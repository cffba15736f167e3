"""Every round checkpoint records the sha256 of its files in meta.json; a resume verifies them, and a
damaged checkpoint is named and set aside, and the run resumes from the previous one (the last two
rounds are kept). Before, a damaged checkpoint was restored as it was (or failed deep in orbax)."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from support.digests import result_digests
from support.fakeday import FakeExecutor
from support.tiny_runs import train_iql

from urb_jax.core.errors import UrbJaxError
from urb_jax.runs.request import ResumeRequest
from urb_jax.runs.train import resume_train
from urb_jax.surrogate.calibrate import SumoSample
from urb_jax.training.checkpoints import (
    CKPT_DIR,
    RoundMeta,
    file_digests,
    latest_checkpoint,
    restore_round,
    save_round,
)

TARGET = {"w": np.zeros((2, 3), np.float32)}


def _save(folder, r: int) -> None:
    samples = [SumoSample(np.full((r, 4), r, np.int32), np.zeros((r, 4), np.float32), np.ones((r, 4), bool))]
    meta = RoundMeta(r, r, [0], [folder.name], [r], [[{"round": i + 1} for i in range(r)]], 5, float(r))
    save_round(folder, {"w": np.full((2, 3), r, np.float32)}, samples, meta)


def _flip_a_byte(path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def _rounds(folder) -> list[str]:
    return sorted(p.name for p in (folder / CKPT_DIR).iterdir())


@pytest.fixture
def saved(tmp_path):
    folder = tmp_path / "run"
    for r in (1, 2, 3):
        _save(folder, r)
    return folder


def test_meta_records_every_file_and_the_last_two_rounds_are_kept(saved):
    assert _rounds(saved) == ["round_00002", "round_00003"]
    ckpt = saved / CKPT_DIR / "round_00003"
    digests = json.loads((ckpt / "meta.json").read_text())["digests"]
    assert "sumo_days.npz" in digests and any(name.startswith("state/") for name in digests)
    assert digests == file_digests(ckpt) and "meta.json" not in digests
    state, _, meta = restore_round(saved, TARGET, [0])
    assert meta.rounds_done == 3 and float(state["w"][0, 0]) == 3.0


@pytest.mark.parametrize("damage", ["sumo_days.npz", "a state file", "a missing state file"])
def test_a_damaged_checkpoint_is_named_and_the_previous_one_used(saved, caplog, damage):
    ckpt = saved / CKPT_DIR / "round_00003"
    if damage == "sumo_days.npz":
        _flip_a_byte(ckpt / "sumo_days.npz")
        named = "sumo_days.npz"
    else:
        victim = max((p for p in (ckpt / "state").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
        named = victim.relative_to(ckpt).as_posix()
        _flip_a_byte(victim) if damage == "a state file" else victim.unlink()
    with caplog.at_level(logging.WARNING, logger="urb_jax.training.checkpoints"):
        state, samples, meta = restore_round(saved, TARGET, [0])
    assert meta.rounds_done == 2 and float(state["w"][0, 0]) == 2.0 and samples[0].choices.shape == (2, 4)
    assert f"round_00003: damaged checkpoint ({named} do(es) not match" in caplog.text, caplog.text
    assert _rounds(saved) == ["damaged_round_00003", "round_00002"]
    assert latest_checkpoint(saved)[0] == 2


def test_every_checkpoint_damaged_is_an_error_naming_them(saved):
    for r in (2, 3):
        _flip_a_byte(saved / CKPT_DIR / f"round_{r:05d}" / "sumo_days.npz")
    with pytest.raises(UrbJaxError, match=r"every checkpoint is damaged .*round_00003: sumo_days.npz; .*"
                                          r"round_00002: sumo_days.npz.*Fix: start the run again"):
        restore_round(saved, TARGET, [0])


def test_a_checkpoint_from_before_digests_is_trusted(saved):
    meta_file = saved / CKPT_DIR / "round_00003" / "meta.json"
    meta = json.loads(meta_file.read_text())
    del meta["digests"]
    meta_file.write_text(json.dumps(meta))
    assert restore_round(saved, TARGET, [0])[2].rounds_done == 3


@pytest.mark.slow
def test_a_run_resumed_past_a_damaged_checkpoint_ends_byte_identical(confs, tmp_path, tiny_iql_reference):
    """The tiny IQL run killed after round 2, its round-2 checkpoint damaged: the resume redoes round 2
    from round 1's checkpoint and ends with the uninterrupted run's records and metrics."""
    (stopped,) = train_iql(confs, tmp_path, "k", stop_after_round=2)
    _flip_a_byte(stopped.folder / CKPT_DIR / "round_00002" / "sumo_days.npz")
    (out,) = resume_train(ResumeRequest("k", results_dir=str(tmp_path), progress=False),
                          executor=FakeExecutor())
    assert result_digests(out.folder) == result_digests(tiny_iql_reference[0].folder)
    assert "damaged checkpoint (sumo_days.npz" in (out.folder / "run.log").read_text()
