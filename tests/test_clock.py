"""The surrogate leg's clock (urb_jax.training.hybrid.clock): a long round says early what the
training will cost, timed from the host between equal chunks of one compiled scan."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.fakeday import FakeExecutor

from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.training.hybrid.clock import (
    LINE_EVERY_S,
    IterationClock,
    chunk_len,
    fmt_duration,
    leg_chunk_len,
    run_chunks,
)


class FakeTime:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_one_iteration_gives_the_estimate_and_the_hint_when_slow():
    t, notes = FakeTime(), []
    clock = IterationClock(n_iters=10, n_rounds=4, hint="use --alg-conf hybrid", note=notes.append, clock=t)
    clock.start_round(0)
    clock(0)
    t.now = 500.0
    clock(1)
    clock(1)  # a repeated index counts once
    assert len(notes) == 1
    # 500 s an iteration: 5,000 s a round, 20,000 s for 4 rounds: slow, so the hint follows
    assert "takes 8.3 min" in notes[0] and "about 83.3 min" in notes[0] and "about 5.6 h" in notes[0]
    assert notes[0].endswith("use --alg-conf hybrid")
    t.now += LINE_EVERY_S  # later iterations: a line at most every LINE_EVERY_S
    clock(2)
    clock(3)
    assert len(notes) == 2 and "iteration 2/10" in notes[1]
    clock.start_round(1)  # the estimate is said once per run
    clock(0)
    t.now += 1
    clock(1)
    assert len(notes) == 2


def test_the_estimate_counts_the_short_last_round():
    """A budget that is not whole rounds: the last round's 3 iterations, not 10, in what is left."""
    t, notes = FakeTime(), []
    clock = IterationClock(n_iters=10, n_rounds=4, note=notes.append, clock=t, last_iters=3)
    assert [clock.iters_of(r) for r in range(4)] == [10, 10, 10, 3]
    clock.start_round(2)
    clock(0)
    t.now = 100.0
    clock(1)  # 100 s an iteration; rounds 3 and 4 left: 13 iterations, 1,300 s
    assert "the 2 round(s) left about 21.7 min" in notes[0]
    clock.start_round(3)
    clock(0)
    t.now += LINE_EVERY_S
    clock(1)
    assert "surrogate iteration 1/3" in notes[1]


def test_chunks_cut_a_round_into_equal_parts():
    assert [chunk_len(n) for n in (1, 2, 8, 16, 40, 37, 19, 64, 100)] == [1, 1, 1, 2, 5, 1, 1, 8, 10]
    for n in range(1, 200):
        L = chunk_len(n)
        assert n % L == 0 and (n // L >= 8 or L == 1)


def test_a_short_last_round_shares_the_full_rounds_chunk_where_it_can():
    # St. Arnoult at 6,000 days: rounds of 40 iterations (chunks of 5) and a last round of 12
    assert leg_chunk_len(40, 40, 12) == leg_chunk_len(12, 40, 12) == 4
    assert leg_chunk_len(40, 40, 40) == chunk_len(40) == 5  # no short round: unchanged
    # sharing would cut 64 into 64 chunks of 1 instead of 8 of 8: each leg keeps its own
    assert (leg_chunk_len(64, 64, 7), leg_chunk_len(7, 64, 7)) == (8, 1)
    for full in range(1, 60):
        for last in range(0, full + 1):
            L = leg_chunk_len(full, full, last)
            assert full % L == 0 and chunk_len(full) <= 2 * L, (full, last)  # at most 2x the chunks
            if last:
                assert last % leg_chunk_len(last, full, last) == 0


def test_one_program_serves_a_full_round_and_a_short_last_round():
    import jax
    import jax.numpy as jnp

    def step(c, k):
        return c + jax.random.normal(k), {"l": c}

    fn = jax.jit(jax.vmap(lambda c, ks: jax.lax.scan(step, c, ks)))
    keys = jax.vmap(lambda k: jax.random.split(k, 40))(jax.random.split(jax.random.PRNGKey(1), 2))
    programs: dict = {}
    clock = IterationClock(40, 2, note=lambda _: None)
    (full,), _ = run_chunks(fn, (jnp.zeros(2),), keys, clock, programs, leg_chunk_len(40, 40, 12))
    (last,), _ = run_chunks(fn, (full,), keys[:, :12], clock, programs, leg_chunk_len(12, 40, 12))
    assert len(programs) == 1
    whole, _ = fn(fn(jnp.zeros(2), keys)[0], keys[:, :12])
    np.testing.assert_array_equal(np.asarray(last), np.asarray(whole))
    with pytest.raises(ValueError, match="does not divide"):
        run_chunks(fn, (full,), keys[:, :12], clock, programs, 5)


def test_run_chunks_equals_one_scan_and_tells_the_clock_each_chunk():
    """The chunked round carries and reports exactly what one scan over the same keys gives; the
    clock hears each chunk's first iteration and the end; one program serves every chunk."""
    import jax
    import jax.numpy as jnp

    def step(c, k):
        x = c["x"] * 1.01 + jax.random.normal(k, (3,))
        return {"x": x}, {"loss": x.sum(), "time_cav": x.mean()}

    fn = jax.jit(jax.vmap(lambda c, ks: jax.lax.scan(step, c, ks)))
    carry = {"x": jnp.ones((2, 3))}  # [S=2, 3]
    keys = jax.vmap(lambda k: jax.random.split(k, 24))(jax.random.split(jax.random.PRNGKey(0), 2))
    whole, m_whole = fn(carry, keys)
    calls, programs = [], {}
    class Spy(IterationClock):
        def __call__(self, i: int) -> None:
            calls.append(i)
            super().__call__(i)

    spy = Spy(24, 1, note=lambda _: None)
    (chunked,), m = run_chunks(fn, (carry,), keys, spy, programs)
    assert calls == [0, 3, 6, 9, 12, 15, 18, 21, 24] and len(programs) == 1
    np.testing.assert_array_equal(np.asarray(chunked["x"]), np.asarray(whole["x"]))
    assert m["loss"].shape == (2, 24)
    np.testing.assert_array_equal(m["loss"], np.asarray(m_whole["loss"]))
    (again,), _ = run_chunks(fn, (chunked,), keys, spy, programs)  # a later round: no new program
    assert len(programs) == 1 and not np.array_equal(np.asarray(again["x"]), np.asarray(chunked["x"]))


def test_a_fast_training_gets_no_hint():
    t, notes = FakeTime(), []
    clock = IterationClock(n_iters=4, n_rounds=2, hint="HINT", note=notes.append, clock=t)
    clock(0)
    t.now = 2.0
    clock(1)
    assert notes and "HINT" not in notes[0] and "16 s" in notes[0]
    assert fmt_duration(42) == "42 s" and fmt_duration(600) == "10.0 min" and fmt_duration(9000) == "2.5 h"


@pytest.mark.slow
def test_a_training_run_prints_its_estimate(tmp_path, capsys):
    from urb_jax.runs.train import run_train

    hyb = {"train_days": 20, "num_envs": 2, "surrogate_days_per_round": 8, "sumo_days_per_round": 2,
           "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2, "calib_steps": 20,
           "refit_days": 4, "refit_steps": 5}
    alg = {"agent_frames_per_batch": 2, "n_iters": 10, "num_epochs": 1, "minibatch_size": 64,
           "mlp_depth": 1, "mlp_cells": 16, "memory_size": 400}
    (tmp_path / "hyb.json").write_text(json.dumps(hyb))
    (tmp_path / "iql.json").write_text(json.dumps(alg))
    run_train(TrainRequest(alg="iql", task_conf="test", hybrid_conf=str(tmp_path / "hyb.json"),
                           alg_conf=str(tmp_path / "iql.json"), results_dir=str(tmp_path / "r"),
                           progress=False), executor=FakeExecutor())
    err = capsys.readouterr().err
    # 8 surrogate env-days a round over 2 envs of 2 days: 2 iterations a round, two chunks of one
    lines = [line for line in err.splitlines() if line.startswith("estimate: one surrogate iteration")]
    assert len(lines) == 1 and "a round's 2 iterations" in lines[0]


def test_the_hybrid_hint_goes_to_urbs_own_config_only():
    """A slow round with URB's config1 points to `--alg-conf hybrid`; with the hybrid config itself
    (or any other), the hint says what else would shorten it."""
    from urb_jax.algorithms.registry import load_algo_config
    from urb_jax.training.hybrid.trainer import _slow_hint

    assert "--alg-conf hybrid" in _slow_hint("mappo", load_algo_config("mappo", "config1"))
    for conf in ("hybrid", "fast"):
        hint = _slow_hint("mappo", load_algo_config("mappo", conf))
        assert "--alg-conf hybrid" not in hint and "--train-days" in hint
    assert "--alg-conf hybrid" not in _slow_hint("iql_star", load_algo_config("iql_star", "config1"))


@pytest.mark.slow
def test_a_run_with_urbs_config1_gets_the_hybrid_hint(tmp_path, capsys, monkeypatch):
    """The hint is chosen from the config as given: fitted to the budget (n_iters), URB's config1
    no longer equals the file, and a slow QMIX config1 run on nemours was told only 'fewer
    --train-days'."""
    from urb_jax.runs.train import run_train
    from urb_jax.training.hybrid import clock

    monkeypatch.setattr(clock, "SLOW_S", 0.0)  # every training counts as slow
    # a round of one whole iteration of URB's config1 (320 days): a budget exactly as asked trains
    # no surrogate iteration in a shorter round, and says no estimate
    hyb = {"train_days": 644, "num_envs": 2, "surrogate_days_per_round": 320, "sumo_days_per_round": 2,
           "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2, "calib_steps": 20,
           "refit_days": 4, "refit_steps": 5}
    (tmp_path / "hyb.json").write_text(json.dumps(hyb))
    run_train(TrainRequest(alg="mappo", task_conf="test", hybrid_conf=str(tmp_path / "hyb.json"),
                           alg_conf="config1", results_dir=str(tmp_path / "r"),
                           progress=False), executor=FakeExecutor(), stop_after_round=1)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("estimate:")]
    assert len(lines) == 1 and "`--alg-conf hybrid` trains mappo" in lines[0]


def test_the_probe_scales_one_environment_to_the_iteration():
    notes: list[str] = []
    clock = IterationClock(n_iters=2, n_rounds=10, hint="HINT", note=notes.append, clock=FakeTime())
    clock.start_round(0)
    clock.before_training(48.0 * 80, 80)  # 48 s for one env, 5 seeds x 16 envs an iteration
    # 3,840 s an iteration, 2 a round, 10 rounds: 21.3 h, slow, so the hint follows
    assert notes[0].startswith("estimate before training (one environment's iteration timed here, "
                               "times the 80 of an iteration): one surrogate iteration takes 64.0 min")
    assert "about 2.1 h" in notes[0] and "about 21.3 h" in notes[0] and notes[0].endswith("HINT")
    assert not clock.estimated  # the first real iteration still gives its own estimate


@pytest.mark.slow
def test_a_big_learner_is_timed_before_training(tmp_path, capsys, monkeypatch):
    """Above PROBE_PARAMS a run says its memory and cost before the first round; the probe has its
    own runner and key, so the records are byte-identical to the same run without it. A resume
    probes again, before restoring the state, for the rounds it has left."""
    from urb_jax.runs.train import resume_train, run_train
    from urb_jax.training.hybrid import clock

    hyb = {"train_days": 20, "num_envs": 2, "surrogate_days_per_round": 8, "sumo_days_per_round": 2,
           "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2, "calib_steps": 20,
           "refit_days": 4, "refit_steps": 5}
    alg = {"agent_frames_per_batch": 2, "n_iters": 10, "num_epochs": 1, "minibatch_size": 64,
           "mlp_depth": 1, "mlp_cells": 16, "memory_size": 400, "mixing_embed_dim": 8}
    (tmp_path / "hyb.json").write_text(json.dumps(hyb))
    (tmp_path / "qmix.json").write_text(json.dumps(alg))

    probe_line = ("estimate before training (one environment's iteration timed here, times the 4 of an "
                  "iteration)")

    def said() -> list[str]:
        err = capsys.readouterr().err
        return [line for line in err.splitlines() if line.startswith(("estimate", "memory"))]

    def run(name: str) -> list[str]:
        req = TrainRequest(alg="qmix", task_conf="test", hybrid_conf=str(tmp_path / "hyb.json"), seeds=[0, 1],
                           alg_conf=str(tmp_path / "qmix.json"), results_dir=str(tmp_path / name),
                           progress=False)
        run_train(req, executor=FakeExecutor(), stop_after_round=1)
        return said()

    plain = run("plain")
    monkeypatch.setattr(clock, "PROBE_PARAMS", 0)
    probed = run("probed")
    assert [line.split(":")[0] for line in plain] == ["estimate"]
    assert [line.split(":")[0] for line in probed] == ["memory", probe_line, "estimate"]
    assert "GB for 2 seed(s)" in probed[0] and "the 2 round(s) left" in probed[1]
    for seed in ("s0", "s1"):  # round 1's SUMO days (records) were chosen by the trained policy
        (a,), (b,) = ((tmp_path / name).glob(f"qmix_*_{seed}") for name in ("plain", "probed"))
        files = sorted(p.relative_to(a) for p in a.glob("records.parts/*"))
        parts = [f for f in files if f.suffix == ".parquet"]  # each with its .sha256 digest
        assert len(parts) == 2 and files == sorted(p.relative_to(b) for p in b.glob("records.parts/*"))
        assert all((a / f).read_bytes() == (b / f).read_bytes() for f in files)
    resume_train(ResumeRequest("qmix_hybrid_urb_grid_test_s0", results_dir=str(tmp_path / "probed"),
                               progress=False), executor=FakeExecutor())
    resumed = said()
    assert [line.split(":")[0] for line in resumed[:2]] == ["memory", probe_line]
    assert "the 1 round(s) left" in resumed[1]
