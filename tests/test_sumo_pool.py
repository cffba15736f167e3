"""SumoPool: order, determinism across workers, crash and timeout handling, logs."""

from __future__ import annotations

import itertools
import logging
from pathlib import Path

import numpy as np
import pytest
from support.kill_worker import run_killing_a_busy_worker

from urb_jax.sumo_bridge import InProcessExecutor, SumoDayError, SumoPool

pytestmark = pytest.mark.sumo


@pytest.fixture(scope="module")
def pool(tmp_path_factory):
    p = SumoPool(2, log_dir=tmp_path_factory.mktemp("sumo-logs"), day_timeout_s=120)
    yield p
    p.close()


@pytest.fixture(scope="module")
def days(grid_scenario):
    rng = np.random.default_rng(11)
    choices = rng.integers(0, grid_scenario.k, size=(4, grid_scenario.n_agents))
    choices[1] = choices[0]  # days 0 and 1 are the same day, run by different workers at once
    seeds = [5, 5, 6, 7]
    ref = InProcessExecutor().run_days(grid_scenario, choices, seeds)
    return choices, seeds, ref


def test_pool_preserves_order_and_matches_in_process_runs(pool, grid_scenario, days):
    choices, seeds, ref = days
    out = pool.run_days(grid_scenario, choices, seeds)
    assert [r.seed for r in out] == seeds
    assert all(a.same_as(b) for a, b in zip(out, ref, strict=True))
    assert out[0].same_as(out[1])  # same inputs on two workers give identical days
    assert not out[0].same_as(out[2])
    # reversed batch: results follow the batch order, not completion order
    back = pool.run_days(grid_scenario, choices[::-1], seeds[::-1])
    assert all(a.same_as(b) for a, b in zip(back, ref[::-1], strict=True))


def test_worker_killed_mid_day_is_restarted_and_day_repeated(pool, grid_scenario, days, caplog):
    choices, seeds, ref = days
    restarts = pool.restarts
    index = {w.proc.pid: w.index for w in pool.slots}
    with caplog.at_level(logging.WARNING, logger="urb_jax"):
        out, killed = run_killing_a_busy_worker(pool, lambda: pool.run_days(grid_scenario, choices, seeds))
    assert killed and pool.restarts == restarts + 1
    # one warning for the one restart, naming the worker, its day and its SUMO log
    (warning,) = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    i = index[killed[0]]
    assert f"SUMO worker {i} died" in warning and "restarting it" in warning and "retrying the day" in warning
    assert "day " in warning and str(pool.log_dir / f"sumo_worker{i}.log") in warning
    assert all(a.same_as(b) for a, b in zip(out, ref, strict=True))
    assert all(w.proc.is_alive() for w in pool.slots)
    assert not list(Path(pool.slots[0].shm_dir).glob(f"urbjax-sumo-{killed[0]}-*"))  # files cleaned


def test_second_failure_raises_with_network_day_and_log(grid_scenario, tmp_path):
    with SumoPool(1, log_dir=tmp_path, day_timeout_s=0.05) as p:  # no day fits in 50 ms
        with pytest.raises(SumoDayError) as err:
            p.run_days(grid_scenario, grid_scenario.fft.argmin(1)[None], [3])
        msg = str(err.value)
        assert "urb_grid" in msg and "day 0" in msg and "seed 3" in msg and "failed twice" in msg
        assert "SUMO log tail" in msg and "exceeded" in msg
        assert p.restarts == 2
        # the pool is still usable afterwards
        p.day_timeout_s = 120
        ok = p.run_days(grid_scenario, grid_scenario.fft.argmin(1)[None], [3])
        assert ok[0].n == grid_scenario.n_agents
    assert (tmp_path / "sumo_worker0.log").exists()


def test_bad_batch_is_rejected_before_dispatch(pool, grid_scenario):
    with pytest.raises(ValueError, match="route indices"):
        pool.run_days(grid_scenario, np.full((2, grid_scenario.n_agents), 99), [1, 2])


def test_sumo_error_is_reported_with_its_output(grid_scenario, tmp_path):
    from urb_jax.sumo_bridge import SumoConfig

    bad = SumoConfig(additional_files=(str(tmp_path / "missing.add.xml"),))
    with SumoPool(1, config=bad, log_dir=tmp_path) as p, pytest.raises(SumoDayError) as err:
        p.run_days(grid_scenario, grid_scenario.fft.argmin(1)[None], [1])
    msg = str(err.value)
    assert "raised" in msg and "missing.add.xml" in msg.split("SUMO log tail")[1]  # SUMO's own words


def test_sumo_warnings_go_to_the_worker_log_not_the_console(grid_scenario, tmp_path, capfd):
    from support.blocker import make_blocker

    from urb_jax.sumo_bridge import SumoConfig

    choices = grid_scenario.fft.argmin(1)
    add, _ = make_blocker(grid_scenario, choices, tmp_path)
    cfg = SumoConfig(additional_files=(str(add),), stuck_rule="sumo")  # SUMO warns on each teleport
    with SumoPool(1, config=cfg, log_dir=tmp_path / "logs") as p:
        res = p.run_days(grid_scenario, choices[None], [42])[0]
    assert res.n_removed > 0
    out, err = capfd.readouterr()
    assert "Teleporting" not in out + err
    assert "Teleporting" in (tmp_path / "logs" / "sumo_worker0.log").read_text()


def test_pool_takes_per_day_cav_masks(pool, grid_scenario):
    from urb_jax.sumo_bridge import run_day

    rng = np.random.default_rng(2)
    choices = rng.integers(0, grid_scenario.k, size=(2, grid_scenario.n_agents))
    cav = rng.random((2, grid_scenario.n_agents)) < 0.5
    out = pool.run_days(grid_scenario, choices, [9, 9], is_cav=cav)
    for b in range(2):
        assert out[b].same_as(run_day(grid_scenario, choices[b], seed=9, is_cav=cav[b]))
    with pytest.raises(ValueError, match="is_cav"):
        pool.run_days(grid_scenario, choices, [9, 9], is_cav=cav[:, :5])


def test_days_asked_one_at_a_time_alternate_workers_and_match(pool, grid_scenario, days, monkeypatch):
    """A worker loads its next day's network after sending a result; the longest-idle worker gets
    the next day, so single-day batches (the human phase) alternate and find the network loaded."""
    choices, seeds, ref = days
    sent = []
    submit = pool.submit
    monkeypatch.setattr(pool, "submit", lambda w, job: sent.append(w.index) or submit(w, job))
    out = [pool.run_days(grid_scenario, choices[i:i + 1], seeds[i:i + 1])[0] for i in range(len(seeds))]
    assert all(a.same_as(b) for a, b in zip(out, ref, strict=True))
    assert all(a != b for a, b in itertools.pairwise(sent)), sent
