"""The SUMO day store (`sumo_bridge.memo.day_store`): every input of a day is in its key, the store
keeps its cap by evicting the least recently used days, a day evicted under a reader is run again,
the opt-outs run SUMO, and a run gives the same bytes with the store off, cold and warm while a
second run runs no SUMO day at all."""

from __future__ import annotations

import dataclasses
import logging
import os

import numpy as np
import pytest
from support.digests import result_digests
from support.fakeday import FakeExecutor
from support.tiny_runs import train_iql

from urb_jax.core.errors import UrbJaxError
from urb_jax.core.paths import DAY_STORE_ENV, day_store_bytes
from urb_jax.sumo_bridge import InProcessExecutor, SumoConfig, keys, memo
from urb_jax.sumo_bridge.keys import day_key
from urb_jax.sumo_bridge.memo import MemoExecutor, day_store, evict, is_stored


@pytest.fixture
def store(tmp_path, monkeypatch):
    """The day store in a folder of this test's own."""
    where = tmp_path / "store"
    monkeypatch.setattr(memo, "day_store_dir", lambda: where)
    monkeypatch.delenv(DAY_STORE_ENV, raising=False)
    return where


def _choices(scn, shift: int = 0) -> np.ndarray:
    """A joint choice per `shift` (each a different one): the first `shift` agents one route on."""
    c = np.arange(scn.n_agents) % scn.k
    c[:shift] = (c[:shift] + 1) % scn.k
    return c


def test_every_input_of_a_day_changes_its_key(grid_scenario, tmp_path, monkeypatch):
    scn, a = grid_scenario, _choices(grid_scenario)
    base = day_key(scn, a, 42, None, SumoConfig(), "libsumo 1.28.0")
    assert base == day_key(scn, a, 42, None, SumoConfig(), "libsumo 1.28.0")
    other = {
        "choices": day_key(scn, _choices(scn, 1), 42, None, SumoConfig(), "libsumo 1.28.0"),
        "seed": day_key(scn, a, 43, None, SumoConfig(), "libsumo 1.28.0"),
        "cav mask": day_key(scn, a, 42, np.arange(scn.n_agents) == 0, SumoConfig(), "libsumo 1.28.0"),
        "SUMO version": day_key(scn, a, 42, None, SumoConfig(), "libsumo 1.29.0"),
        "unknown simulator": day_key(scn, a, 42, None, SumoConfig(), None),
    }
    changed = {"stuck_rule": "routerl", "stuck_time_s": 601, "stuck_penalty": "urb", "tt_offset_s": 0,
               "max_sim_time_s": 3600, "poll_every_s": 99, "extra_args": ("--lateral-resolution", "0.8"),
               "emissions": True}
    add = tmp_path / "add.xml"
    add.write_text("<additional/>\n")
    changed["additional_files"] = (str(add),)
    # every SumoConfig field but where files live is covered (a new field must be added here)
    assert set(changed) == {f.name for f in dataclasses.fields(SumoConfig)} - {"shm_dir"}
    for name, value in changed.items():
        other[name] = day_key(scn, a, 42, None, SumoConfig(**{name: value}), "libsumo 1.28.0")
    # the additional file's bytes, not only its name
    add.write_text("<additional><!-- changed --></additional>\n")
    keys._config_text.cache_clear()
    other["additional file bytes"] = day_key(scn, a, 42, None, SumoConfig(additional_files=(str(add),)),
                                             "libsumo 1.28.0")
    monkeypatch.setattr(keys, "day_code", lambda: "another day's code")
    other["day code"] = day_key(scn, a, 42, None, SumoConfig(), "libsumo 1.28.0")
    assert base not in other.values() and len(set(other.values())) == len(other), other
    # where files live changes nothing
    monkeypatch.undo()
    assert day_key(scn, a, 42, None, SumoConfig(shm_dir="/tmp"), "libsumo 1.28.0") == base


def test_the_day_code_ignores_comments_docstrings_and_layout_not_statements():
    src = 'def f(x):\n    """Why."""\n    return x + 1  # one more\n'
    same = '# a comment\ndef f(x):\n\n    """Why, said better."""\n    return (x +\n            1)\n'
    other = 'def f(x):\n    """Why."""\n    return x + 2\n'
    assert keys.code_text(same) == keys.code_text(src) != keys.code_text(other)
    assert keys.code_text('def g():\n    """Only a docstring."""\n') == keys.code_text("def g():\n    pass\n")


def test_the_day_code_covers_the_modules_that_make_a_day():
    assert {"sim.py", "tripinfo.py", "config.py", "types.py"} <= set(keys.DAY_MODULES)
    assert keys.sumo_version().split()[-1][0].isdigit()


def _fill(store_dir, scn, n: int) -> list:
    """n stored days with mtimes 1000 s apart (the first the oldest); their paths."""
    ex = MemoExecutor(FakeExecutor(simulator="fake"), store_dir=store_dir)
    ex.run_days(scn, np.stack([_choices(scn, i) for i in range(n)]), [42] * n)
    paths = sorted(store_dir.rglob("*.npz"), key=lambda p: p.stat().st_mtime_ns)
    assert len(paths) == n
    keyed = [ex._path(scn, day_key(scn, _choices(scn, i), 42, None, None, "fake")) for i in range(n)]
    for i, p in enumerate(keyed):
        os.utime(p, (1_000_000 + 1000 * i, 1_000_000 + 1000 * i))
    return keyed


def test_eviction_keeps_the_cap_and_removes_the_least_recently_used(grid_scenario, tmp_path):
    scn = grid_scenario
    paths = _fill(tmp_path, scn, 6)
    size = paths[0].stat().st_size
    # a read touches: day 0, the oldest written, becomes the most recently used
    reader = MemoExecutor(FakeExecutor(simulator="fake"), store_dir=tmp_path)
    reader.run_days(scn, _choices(scn, 0)[None], [42])
    assert reader.inner.batches == [] and paths[0].stat().st_mtime > paths[5].stat().st_mtime
    cap = int(size * 4.5)
    left = evict(tmp_path, cap)
    kept = [p.exists() for p in paths]
    assert left <= cap and left == sum(p.stat().st_size for p in paths if p.exists())
    assert kept == [True, False, False, True, True, True]  # 1 and 2: the least recently used
    # a writer keeps the cap too: each day it stores beyond it evicts the oldest
    writer = MemoExecutor(FakeExecutor(simulator="fake"), store_dir=tmp_path, max_bytes=cap)
    writer.run_days(scn, np.stack([_choices(scn, 10 + i) for i in range(3)]), [42] * 3)
    assert sum(p.stat().st_size for p in tmp_path.rglob("*.npz")) <= cap
    # each went in least-recently-used order (3, 4, 5); day 0, read last, stays
    assert [p.exists() for p in paths] == [True, False, False, False, False, False]
    assert len(writer.inner.batches) == 1


def test_a_day_evicted_under_a_reader_is_run_again(grid_scenario, tmp_path, monkeypatch, caplog):
    scn = grid_scenario
    (path,) = _fill(tmp_path, scn, 1)
    real_load = memo.load_day

    def evicted_first(p, *key):  # another process removes the file between the lookup and the read
        os.unlink(p)
        return real_load(p, *key)

    monkeypatch.setattr(memo, "load_day", evicted_first)
    inner = FakeExecutor(simulator="fake")
    ex = MemoExecutor(inner, store_dir=tmp_path)
    with caplog.at_level(logging.WARNING, logger="urb_jax"):
        (day,) = ex.run_days(scn, _choices(scn, 0)[None], [42])
    assert len(inner.batches) == 1 and (ex.simulated, ex.reused) == (1, 0)  # a miss, run again
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]  # no "unreadable" warning
    assert path.exists()  # and stored again

    def evicted_after(p, *key):  # removed right after the read: the day in hand is served
        d = real_load(p, *key)
        os.unlink(p)
        return d

    monkeypatch.setattr(memo, "load_day", evicted_after)
    again = MemoExecutor(FakeExecutor(simulator="fake"), store_dir=tmp_path)
    (same,) = again.run_days(scn, _choices(scn, 0)[None], [42])
    assert again.inner.batches == [] and same.same_as(day)


def test_the_store_is_off_when_asked_or_when_days_are_not_sumos(store, monkeypatch):
    fake = FakeExecutor(simulator="fake")
    assert is_stored(day_store(fake)) and day_store(fake).store_dir == store
    assert day_store(fake, enabled=False) is fake  # --no-day-store
    plain = FakeExecutor()  # no simulator: stand-in days never enter the store
    assert day_store(plain) is plain
    for off in ("0", "off"):
        monkeypatch.setenv(DAY_STORE_ENV, off)
        assert day_store(fake) is fake
    monkeypatch.setenv(DAY_STORE_ENV, "0.5")
    assert day_store_bytes() == 500_000_000 and day_store(fake).max_bytes == 500_000_000
    for bad in ("lots", "-1", "inf", "nan"):
        monkeypatch.setenv(DAY_STORE_ENV, bad)
        with pytest.raises(UrbJaxError, match=f"{DAY_STORE_ENV}=.*Fix: set {DAY_STORE_ENV}"):
            day_store(fake)


def test_a_bad_cap_stops_train_with_exit_code_2(monkeypatch, capsys):
    from urb_jax.commands.cli import main

    monkeypatch.setenv(DAY_STORE_ENV, "two gigabytes")
    assert main(["train", "--no-progress", "--results-dir", "unused"]) == 2
    assert f"{DAY_STORE_ENV}='two gigabytes'" in capsys.readouterr().err


def test_a_stored_sumo_day_is_the_day_sumo_runs(grid_scenario, store):
    scn = grid_scenario
    choices = np.stack([np.asarray(scn.fft).argmin(axis=1)])
    fresh_ex = InProcessExecutor()
    try:
        fresh = fresh_ex.run_days(scn, choices, [42])[0]
        first = day_store(fresh_ex)
        assert is_stored(first)
        first.run_days(scn, choices, [42])
        assert (first.simulated, first.reused) == (1, 0)
        second = day_store(fresh_ex)
        (back,) = second.run_days(scn, choices, [42])
        assert (second.simulated, second.reused) == (0, 1) and back.same_as(fresh)
        assert day_store(fresh_ex, enabled=False) is fresh_ex  # --no-day-store: SUMO runs it
    finally:
        fresh_ex.close()


def test_train_runs_behind_the_store_unless_told_not_to(store):
    from urb_jax.runs.train import _executor
    from urb_jax.training.hybrid.plan import HybridConfig

    fake = FakeExecutor(simulator="fake")
    with _executor(fake, HybridConfig(), store, "pool", None, True) as ex:
        assert is_stored(ex) and ex.inner is fake
    with _executor(fake, HybridConfig(), store, "pool", None, False) as ex:  # --no-day-store
        assert ex is fake


def test_sumo_starts_only_for_a_day_not_in_the_store(grid_scenario, store):
    """Behind the store a train run's executor is made on its first missing day: a run whose days
    are all stored starts no SUMO process."""
    scn, made = grid_scenario, []

    def make():
        made.append(FakeExecutor(simulator=keys.sumo_version()))
        made[-1].config = SumoConfig()
        return made[-1]

    seed_store = FakeExecutor(simulator=keys.sumo_version())
    MemoExecutor(seed_store, store_dir=store, config=SumoConfig()).run_days(scn, _choices(scn, 0)[None], [42])
    lazy = memo.LazyExecutor(make, SumoConfig())
    stored = day_store(lazy)
    stored.run_days(scn, _choices(scn, 0)[None], [42])
    assert made == []  # all in the store: nothing started
    stored.run_days(scn, _choices(scn, 1)[None], [42])
    assert len(made) == 1 and len(made[0].batches) == 1
    other = memo.LazyExecutor(make, SumoConfig(stuck_rule="routerl"))  # keys must be the made one's
    with pytest.raises(ValueError, match="LazyExecutor"):
        other.run_days(scn, _choices(scn, 2)[None], [42])


@pytest.mark.slow  # three tiny runs: ~30 s on a loaded 2-core machine
def test_a_run_is_the_same_bytes_with_the_store_off_cold_and_warm(confs, tmp_path, store, tiny_iql_reference):
    """The reference ran without the store (a FakeExecutor without `simulator`); the same run with the
    store cold, then warm, gives the same records and metrics, and the warm run runs no day at all
    (human phase, calibration, SUMO training and test days all read back)."""
    ref, ref_ex = tiny_iql_reference
    cold_ex = FakeExecutor(simulator="fake-tiny-run")
    (cold,) = train_iql(confs, tmp_path, "cold", executor=cold_ex)
    warm_ex = FakeExecutor(simulator="fake-tiny-run")
    (warm,) = train_iql(confs, tmp_path, "warm", executor=warm_ex)
    off_ex = FakeExecutor(simulator="fake-tiny-run")
    (off,) = train_iql(confs, tmp_path, "off", executor=off_ex, day_store=False)
    digest = result_digests(ref.folder)
    assert digest is not None
    assert result_digests(cold.folder) == result_digests(warm.folder) == result_digests(off.folder) == digest
    assert warm_ex.batches == []  # no human day, no day at all
    ran = sum(len(b) for b, _ in cold_ex.batches)
    assert 0 < ran <= sum(len(b) for b, _ in ref_ex.batches)
    # the opt-out runs every day SUMO would have run without a store
    assert [b.tolist() for b, _ in off_ex.batches] == [b.tolist() for b, _ in ref_ex.batches]


def test_a_second_baseline_reads_every_day_from_the_store(tmp_path, store):
    import json

    from urb_jax.runs.baseline import run_baseline
    from urb_jax.runs.request import BaselineRequest

    overrides = {"human_learning_episodes": 6, "training_eps": 8, "test_eps": 4}
    outs, executors = [], []
    for exp_id, stored in (("first", True), ("second", True)):
        executors.append(FakeExecutor(simulator="fake-baseline"))
        outs.append(run_baseline(BaselineRequest(model="aon", exp_id=exp_id, results_dir=str(tmp_path),
                                                 progress=False, day_store=stored),
                                 executor=executors[-1], task_overrides=overrides))
    cfgs = [json.loads((o.folder / "exp_config.json").read_text()) for o in outs]
    ran = [sum(len(b) for b, _ in ex.batches) for ex in executors]
    assert cfgs[0]["sumo_days_run"] == ran[0] > 0 and cfgs[0]["sumo_days_from_store"] == 0
    assert ran[1] == 0 and cfgs[1]["sumo_days_run"] == 0 and cfgs[1]["sumo_days_from_store"] == ran[0]
    assert len({result_digests(o.folder) for o in outs}) == 1
