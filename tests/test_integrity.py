"""A result is either right or refused: record parts carry sha256 digests that a resume checks when
it starts (and the merge before it writes), the metric files come only from records that match their
digest, a SUMO-day journal entry that is not the day its key names is a miss, and memory exhaustion
or a hung checkpoint save ends a run with a message (exit 2) instead of a traceback or a hang."""

from __future__ import annotations

import logging
import shutil
import time

import numpy as np
import pytest
from support.digests import result_digests
from support.fakeday import FakeExecutor
from support.tiny_runs import train_iql

from urb_jax.core.atomic import file_sha256
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.phase import enter_phase, is_out_of_memory
from urb_jax.reporting.records import (
    PARTS_DIR,
    RECORDS_FILE,
    DamagedRecordsError,
    DayRecord,
    RecordsWriter,
    adopt_undigested_parts,
    damaged_parts,
    digest_path,
    write_run_metrics,
)
from urb_jax.runs.request import ResumeRequest
from urb_jax.runs.setup import OutOfMemoryError, stops_cleanly
from urb_jax.runs.train import resume_train
from urb_jax.sumo_bridge import SumoConfig
from urb_jax.sumo_bridge.keys import day_key
from urb_jax.sumo_bridge.memo import MemoExecutor
from urb_jax.sumo_bridge.types import ARRIVED, DayResult
from urb_jax.surrogate.calibrate import SumoSample
from urb_jax.training.checkpoints import CKPT_DIR, RoundMeta, save_round, wait_bounded
from urb_jax.training.hybrid import trainer as trainer_module
from urb_jax.training.hybrid.trainer import check_group_records

N = 6


def _day(n: int = N, shift: float = 0.0) -> DayResult:
    tt = np.linspace(1.0, 2.0, n) + shift
    return DayResult(travel_time=tt, duration=tt * 60, route_length=np.full(n, 100.0),
                     mean_speed=np.full(n, 5.0), time_loss=np.zeros(n), depart_delay=np.zeros(n),
                     status=np.full(n, ARRIVED, np.int8), seed=1, stat_mean_speed=5.0,
                     stat_mean_route_length=100.0, stat_mean_duration=60.0, teleports=0, n_removed=0,
                     sim_end_time=100.0, wall_time=0.5)


def _flip(path, at: float = 0.5) -> None:
    data = bytearray(path.read_bytes())
    data[int(len(data) * at)] ^= 0xFF
    path.write_bytes(bytes(data))


def _writer(folder, days: int = 4) -> RecordsWriter:
    """A writer with `days` days, one part each (flush_every=1)."""
    w = RecordsWriter(folder, np.arange(N), np.zeros(N, np.int32), np.arange(N, dtype=np.int32),
                      flush_every=1)
    for d in range(days):
        w.add(DayRecord(d + 1, "human", np.zeros(N, np.int8), np.zeros(N, bool), _day(shift=d),
                        -np.ones(N), None))
    return w


# ---- record parts


def test_every_part_has_its_digest_and_a_damaged_or_missing_one_is_named(tmp_path):
    _writer(tmp_path)
    parts = tmp_path / PARTS_DIR
    for i in range(4):
        p = parts / f"part-{i:05d}.parquet"
        assert digest_path(p).read_text().strip() == file_sha256(p)
    assert damaged_parts(tmp_path, 4) == []
    _flip(parts / "part-00002.parquet")
    (parts / "part-00003.parquet").unlink()
    bad = damaged_parts(tmp_path, 4)
    assert [i for i, _ in bad] == [2, 3]
    assert "part-00002.parquet: does not match its digest" in bad[0][1] and bad[1][1].endswith("missing")


def test_parts_of_a_run_from_before_digests_are_adopted_once(tmp_path):
    """An unfinished run started by a version without record digests resumes: its parts get their
    digests at the resume (trusted, as they were), and a missing digest after that is damage."""
    _writer(tmp_path)
    for d in (tmp_path / PARTS_DIR).glob("*.sha256"):
        d.unlink()
    assert adopt_undigested_parts(tmp_path) == 4 and damaged_parts(tmp_path, 4) == []
    assert adopt_undigested_parts(tmp_path) == 0
    (tmp_path / PARTS_DIR / "part-00001.sha256").unlink()
    assert adopt_undigested_parts(tmp_path) == 0
    assert damaged_parts(tmp_path, 4) == [(1, f"{tmp_path / PARTS_DIR / 'part-00001.parquet'}: its digest "
                                              "file is missing")]


def test_truncate_drops_parts_and_their_digests(tmp_path):
    w = _writer(tmp_path)
    w.truncate(2)
    assert sorted(p.name for p in (tmp_path / PARTS_DIR).iterdir()) == [
        "part-00000.parquet", "part-00000.sha256", "part-00001.parquet", "part-00001.sha256"]


def test_the_merge_refuses_a_damaged_part_and_writes_nothing(tmp_path):
    w = _writer(tmp_path)
    _flip(tmp_path / PARTS_DIR / "part-00001.parquet", 0.9)
    with pytest.raises(DamagedRecordsError, match=r"part-00001.parquet: does not match its digest.*--resume"):
        w.close()
    assert not (tmp_path / RECORDS_FILE).exists() and not digest_path(tmp_path / RECORDS_FILE).exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file left


def test_metrics_only_from_a_merged_file_that_matches_its_digest(tmp_path):
    w = _writer(tmp_path)
    w.close()
    assert digest_path(tmp_path / RECORDS_FILE).read_text().strip() == file_sha256(tmp_path / RECORDS_FILE)
    write_run_metrics(tmp_path, 2, 1)  # intact: metrics written
    shutil.rmtree(tmp_path / "metrics")
    _flip(tmp_path / RECORDS_FILE)
    with pytest.raises(DamagedRecordsError, match=r"records.parquet: does not match its digest; no metric"):
        write_run_metrics(tmp_path, 2, 1)
    assert not (tmp_path / "metrics").exists()


def test_a_later_seed_groups_records_are_checked_before_the_first_group_trains(tmp_path):
    """check_group_records (what a multi-group --resume runs for every group after the first):
    intact, or damage a kept checkpoint comes before, passes quietly; damage none comes before is
    refused, naming the file."""
    folder = tmp_path / "g"
    _writer(folder)  # parts 0-3
    for r, parts in ((1, 3), (2, 4)):
        meta = RoundMeta(r, r, [0], [folder.name], [parts], [[{"round": i + 1} for i in range(r)]], 5, 0.0)
        save_round(folder, {"w": np.zeros(2, np.float32)}, [SumoSample(np.zeros((1, 2), np.int32),
                                                                       np.zeros((1, 2), np.float32),
                                                                       np.ones((1, 2), bool))], meta)
    check_group_records([folder])
    _flip(folder / PARTS_DIR / "part-00003.parquet")
    check_group_records([folder])  # round 1's checkpoint counts parts 0-2: its own start falls back
    _flip(folder / PARTS_DIR / "part-00001.parquet")
    with pytest.raises(UrbJaxError, match=r"part-00001.parquet: does not match its digest.*no kept"):
        check_group_records([folder])


@pytest.mark.slow
def test_a_resume_falls_back_past_a_damaged_last_part_and_ends_byte_identical(confs, tmp_path,
                                                                              tiny_iql_reference):
    """Round 2's record part damaged after a kill: the resume names it, goes back to round 1's
    checkpoint (its records intact) and ends with the uninterrupted run's records and metrics."""
    (stopped,) = train_iql(confs, tmp_path, "p", stop_after_round=2)
    last = max((stopped.folder / PARTS_DIR).glob("part-*.parquet"))
    _flip(last)
    (out,) = resume_train(ResumeRequest("p", results_dir=str(tmp_path), progress=False),
                          executor=FakeExecutor())
    assert result_digests(out.folder) == result_digests(tiny_iql_reference[0].folder)
    log = (out.folder / "run.log").read_text()
    assert f"{last.name}: does not match its digest" in log and "checkpoint after round 1" in log


@pytest.mark.slow
def test_a_damaged_first_part_is_refused_before_any_round(confs, tmp_path):
    """The human phase's part damaged: no checkpoint comes before it, so the resume refuses at once,
    naming the file and what to do, and runs no SUMO day."""
    (stopped,) = train_iql(confs, tmp_path, "q", stop_after_round=2)
    _flip(stopped.folder / PARTS_DIR / "part-00000.parquet")
    kept = sorted(p.name for p in (stopped.folder / CKPT_DIR).iterdir())
    ex = FakeExecutor()
    with pytest.raises(UrbJaxError, match=r"part-00000.parquet: does not match its digest.*no kept "
                                          r"checkpoint comes before them.*Fix: start the run again"):
        resume_train(ResumeRequest("q", results_dir=str(tmp_path), progress=False), executor=ex)
    assert ex.batches == [] and sorted(p.name for p in (stopped.folder / CKPT_DIR).iterdir()) == kept


# ---- the SUMO-day journal


class _Counting:
    config = SumoConfig()

    def __init__(self) -> None:
        self.runs = 0

    def run_days(self, scenario, choices, seeds, is_cav=None):
        self.runs += len(seeds)
        return [_day(scenario.n_agents, float(np.asarray(c).any())) for c in choices]

    def close(self) -> None:
        pass


@pytest.mark.parametrize("damage", ["another day's entry", "arrays changed"])
def test_a_journal_entry_that_is_not_its_day_is_run_again_and_rewritten(grid_scenario, tmp_path, caplog,
                                                                        damage):
    n, k = grid_scenario.n_agents, grid_scenario.k
    a, b = np.zeros(n, np.int64), np.arange(n) % k
    inner = _Counting()
    memo = MemoExecutor(inner, store_dir=tmp_path)
    day_a, _ = memo.run_days(grid_scenario, np.stack([a, b]), [1, 1])
    (entry_a,) = tmp_path.rglob(f"{day_key(grid_scenario, a, 1, None, SumoConfig())}.npz")
    (entry_b,) = tmp_path.rglob(f"{day_key(grid_scenario, b, 1, None, SumoConfig())}.npz")
    if damage == "another day's entry":  # e.g. a file copied over another
        shutil.copy(entry_b, entry_a)
    else:  # the arrays changed but the file reads (a stale digest)
        z = dict(np.load(entry_a))
        z["travel_time"] = z["travel_time"] + 1.0
        np.savez(entry_a, **z)
    again = MemoExecutor(_Counting(), store_dir=tmp_path)
    with caplog.at_level(logging.WARNING, logger="urb_jax.sumo_bridge.memo"):
        (back,) = again.run_days(grid_scenario, a[None], [1])
    assert again.inner.runs == 1 and back.same_as(day_a)
    assert f"{entry_a}" in caplog.text and "does not match its key" in caplog.text
    third = MemoExecutor(_Counting(), store_dir=tmp_path)  # rewritten: read back now
    assert third.run_days(grid_scenario, a[None], [1])[0].same_as(day_a) and third.inner.runs == 0


# ---- memory exhaustion, a hung save


class XlaRuntimeError(RuntimeError):
    """Stands in for jaxlib's error type of that name (only the name and the status are looked at)."""


def test_what_counts_as_out_of_memory():
    assert is_out_of_memory(MemoryError())
    assert is_out_of_memory(XlaRuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 123 bytes."))
    assert not is_out_of_memory(XlaRuntimeError("INTERNAL: something else"))
    assert not is_out_of_memory(ValueError("RESOURCE_EXHAUSTED in a message of a user's value"))


@pytest.mark.parametrize("exc", [MemoryError(), XlaRuntimeError("RESOURCE_EXHAUSTED: Out of memory while "
                                                                "trying to allocate 4.00GiB.")])
def test_memory_exhaustion_names_the_phase_a_hint_and_the_resume_line(tmp_path, exc):
    folder = tmp_path / "run"
    folder.mkdir()
    with pytest.raises(OutOfMemoryError) as caught, stops_cleanly([folder]):
        enter_phase("round 3 of 9: the surrogate leg")
        raise exc
    msg = str(caught.value)
    assert isinstance(caught.value, UrbJaxError)  # the CLI's exit 2
    assert "out of memory during round 3 of 9: the surrogate leg" in msg
    for hint in ("hybrid.num_envs", "alg.num_envs", "hybrid.seed_axis=map", "hybrid.max_vmapped_seeds"):
        assert hint in msg
    assert f"urb-jax train --resume run --results-dir {tmp_path}" in msg


@pytest.mark.slow
def test_a_run_out_of_memory_mid_round_exits_with_the_message(confs, tmp_path, monkeypatch):
    """A MemoryError injected into round 2's SUMO leg of the tiny run: OutOfMemoryError naming the
    round and leg; the run resumes from round 1's checkpoint."""
    real = trainer_module.HybridTrainer.sumo_leg

    def failing(self, r, *args):
        if r == 1:
            raise MemoryError
        return real(self, r, *args)

    monkeypatch.setattr(trainer_module.HybridTrainer, "sumo_leg", failing)
    with pytest.raises(OutOfMemoryError, match=r"out of memory during round 2 of 3: the SUMO leg .*"
                                               r"hybrid.seed_axis=map.*round 1\) is kept.*--resume m "):
        train_iql(confs, tmp_path, "m")


def test_a_checkpoint_save_that_does_not_finish_is_an_error_not_a_hang(tmp_path):
    t0 = time.perf_counter()
    with pytest.raises(UrbJaxError, match=r"did not finish within 0 s.*previous round's checkpoint is kept"):
        wait_bounded(lambda: time.sleep(30), 0.2, tmp_path)
    assert time.perf_counter() - t0 < 5
    with pytest.raises(OSError, match="disk"):  # the wait's own error comes through
        wait_bounded(lambda: (_ for _ in ()).throw(OSError("disk")), 5, tmp_path)


# --- memory running out in a SUMO worker process ---------------------------------------------------


@pytest.fixture
def oom_workers(monkeypatch):
    """SumoPool workers on support.oom_worker's stand-in simulator; returns the mode setter."""
    from support import oom_worker

    from urb_jax.sumo_bridge import pool as pool_module

    monkeypatch.setattr(pool_module, "_worker_main", oom_worker.worker_main)
    return lambda mode: monkeypatch.setenv(oom_worker.MODE, mode)


def _stop_message(tmp_path, phase: str, error: Exception) -> str:
    """What a run in `phase` says when `error` ends it (its clean stop's OutOfMemoryError)."""
    folder = tmp_path / "run"
    folder.mkdir()
    with pytest.raises(OutOfMemoryError) as stopped, stops_cleanly([folder]):
        enter_phase(phase)
        raise error
    return str(stopped.value)


@pytest.mark.parametrize("mode, reason", [("memory", "ran out of memory (MemoryError)"),
                                          ("kill", "killed by SIGKILL")])
def test_a_sumo_worker_out_of_memory_twice_is_a_memory_error_with_sumos_hint(oom_workers, grid_scenario,
                                                                              tmp_path, mode, reason):
    from urb_jax.core.phase import SUMO_MEMORY_HINT
    from urb_jax.sumo_bridge import SumoOutOfMemoryError, SumoPool

    oom_workers(mode)
    with SumoPool(1, log_dir=tmp_path, day_timeout_s=60) as p:
        with pytest.raises(SumoOutOfMemoryError) as caught:
            p.run_days(grid_scenario, grid_scenario.fft.argmin(1)[None], [3])
        assert p.restarts == 2  # restarted once for the retry, once after it: the pool stays usable
    msg = str(caught.value)
    assert msg.splitlines()[0].startswith("SUMO day 0 (seed 3) of network urb_grid failed twice, memory ")
    assert SUMO_MEMORY_HINT in msg and "hybrid.sumo_workers" in msg and msg.count(reason) == 2
    assert is_out_of_memory(caught.value)
    out = _stop_message(tmp_path, "the human phase (human SUMO days, calibration days)", caught.value)
    assert "out of memory during the human phase (human SUMO days, calibration days)" in out
    assert "SumoOutOfMemoryError: SUMO day 0 (seed 3)" in out and SUMO_MEMORY_HINT in out
    assert "hybrid.num_envs" not in out  # the main process's hint is not SUMO's
    assert f"urb-jax train --resume run --results-dir {tmp_path}" in out


def test_a_sumo_day_out_of_memory_in_process_names_sumo_and_the_learners(grid_scenario, tmp_path,
                                                                         monkeypatch):
    """With one SUMO worker the day runs in the trainer's own process: memory running out there is
    SUMO's (not a learner's traceback), and the hint names what frees memory in that process."""
    from urb_jax.core.phase import IN_PROCESS_MEMORY_HINT, MEMORY_HINT
    from urb_jax.sumo_bridge import InProcessExecutor, SumoOutOfMemoryError
    from urb_jax.sumo_bridge.sim import Simulator

    def no_memory(self, *args, **kwargs):
        raise MemoryError("std::bad_alloc")

    monkeypatch.setattr(Simulator, "run_day", no_memory)
    with pytest.raises(SumoOutOfMemoryError) as caught:
        InProcessExecutor().run_days(grid_scenario, grid_scenario.fft.argmin(1)[None], [3])
    assert "a SUMO day of network urb_grid ran out of memory in this process" in str(caught.value)
    assert "std::bad_alloc" in str(caught.value) and is_out_of_memory(caught.value)
    out = _stop_message(tmp_path, "round 2 of 3: the SUMO leg", caught.value)
    assert "out of memory during round 2 of 3: the SUMO leg" in out and IN_PROCESS_MEMORY_HINT in out
    assert MEMORY_HINT not in out and "hybrid.sumo_workers=N" not in out


def test_a_sumo_worker_out_of_memory_once_is_restarted_and_its_day_retried(oom_workers, grid_scenario,
                                                                          tmp_path, caplog):
    from support.fakeday import FakeDay

    from urb_jax.sumo_bridge import SumoPool

    oom_workers(f"memory-once:{tmp_path / 'failed_once'}")
    choices = grid_scenario.fft.argmin(1)[None]
    with SumoPool(1, log_dir=tmp_path, day_timeout_s=60) as p, \
            caplog.at_level(logging.WARNING, logger="urb_jax"):
        (day,) = p.run_days(grid_scenario, choices, [3])
        assert p.restarts == 1
    assert day.same_as(FakeDay()(grid_scenario, choices[0], seed=3))
    (warning,) = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert "ran out of memory (MemoryError)" in warning and "retrying the day" in warning


# --- exp_config.json's digest ----------------------------------------------------------------------


def test_exp_config_carries_the_sha256_of_its_canonical_content(tmp_path):
    import hashlib
    import json

    from urb_jax.core.atomic import JSON_DIGEST_KEY
    from urb_jax.runs.folder import read_run_config, write_config

    write_config(tmp_path, {"status": "running", "seeds": (1, 2), "lr": np.float32(0.5)})
    recorded = json.loads((tmp_path / "exp_config.json").read_text())
    by_hand = hashlib.sha256(b'{"lr":0.5,"seeds":[1,2],"status":"running"}').hexdigest()
    assert recorded[JSON_DIGEST_KEY] == by_hand
    assert read_run_config(tmp_path) == {"status": "running", "seeds": [1, 2], "lr": 0.5}
    # indentation and key order are no content: the same record, written otherwise, still reads
    (tmp_path / "exp_config.json").write_text(json.dumps(dict(reversed(recorded.items()))))
    assert read_run_config(tmp_path)["seeds"] == [1, 2]
    # a record from before digests reads as it is
    (tmp_path / "exp_config.json").write_text(json.dumps({"status": "running"}))
    assert read_run_config(tmp_path) == {"status": "running"}


def test_an_exp_config_that_is_not_its_digest_is_refused_by_every_reader(tmp_path, capsys):
    import json

    from urb_jax.commands.cli import main
    from urb_jax.reporting.records import run_config
    from urb_jax.runs.folder import read_run_config, read_train_config, write_config

    folder = tmp_path / "r"
    write_config(folder, {"status": "running", "train_args": {"seed": 0}, "env_seed": 42})
    path = folder / "exp_config.json"
    path.write_text(path.read_text().replace('"env_seed": 42', '"env_seed": 43'))
    for read in (read_run_config, read_train_config, run_config):
        with pytest.raises(UrbJaxError, match=r"exp_config.json: its content does not match the sha256 "
                                              r"recorded in it \('content_sha256' .*Fix: undo the edit"):
            read(folder)
    assert main(["train", "--resume", "r", "--results-dir", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"urb-jax: error: {path}: its content does not match" in err and "--overwrite" in err
    assert json.loads(path.read_text())["env_seed"] == 43  # nothing rewritten


# --- the algorithm config a resume re-reads --------------------------------------------------------


def test_a_resume_compares_the_algorithm_config_it_rereads_with_the_record(tmp_path):
    import dataclasses

    from urb_jax.runs.request import TrainRequest
    from urb_jax.runs.setup import ALG_GIVEN_KEY, check_recorded_configs, load_setup, recorded_values

    setup = load_setup(TrainRequest(alg="iql", task_conf="test", results_dir=str(tmp_path)))
    recorded = {**recorded_values(setup), "train_args": {"alg_conf": "config1"}}
    check_recorded_configs(tmp_path / "exp_config.json", recorded, setup)  # the same values
    lr = recorded[ALG_GIVEN_KEY]["lr"]
    edited = setup._replace(alg_config=dataclasses.replace(setup.alg_config, lr=lr * 2))
    with pytest.raises(UrbJaxError, match=rf"configs changed since it started \('alg.lr' was {lr!r}, now "
                                          rf"{lr * 2!r}; read from .*the algorithm config 'config1'"):
        check_recorded_configs(tmp_path / "exp_config.json", recorded, edited)
    before = {k: v for k, v in recorded.items() if k != ALG_GIVEN_KEY}  # a run from before the key
    check_recorded_configs(tmp_path / "exp_config.json", before, edited)


# --- --human-phase-from: the source's files ---------------------------------------------------------


def _source(folder):
    from urb_jax.reporting.records import write_with_digest
    from urb_jax.training.human_phase import HUMAN_FILE

    w = _writer(folder)
    w.close()
    write_with_digest(folder / HUMAN_FILE, lambda tmp: tmp.write_bytes(b"an npz file's bytes" * 10))
    return folder / RECORDS_FILE, folder / HUMAN_FILE


@pytest.mark.parametrize("damaged", [RECORDS_FILE, "human_phase.npz"])
def test_a_human_phase_source_with_a_damaged_file_is_refused_naming_it(tmp_path, damaged):
    from urb_jax.training.human_phase import check_source_files

    _source(tmp_path)
    check_source_files(tmp_path)  # intact
    _flip(tmp_path / damaged, 0.5)
    with pytest.raises(UrbJaxError, match=rf"{tmp_path / damaged}: does not match its digest: the human "
                                          r"phase of .* cannot be reused.*drop --human-phase-from"):
        check_source_files(tmp_path)


def test_a_human_phase_source_from_before_digests_is_used_as_it_is(tmp_path):
    from urb_jax.training.human_phase import check_source_files

    for f in _source(tmp_path):
        digest_path(f).unlink()
    check_source_files(tmp_path)
