"""MemoExecutor, the one SUMO-day cache: each distinct day (scenario content, choices, CAV mask, seed,
SumoConfig) is simulated once, kept in memory and optionally on disk; damaged files are re-run."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
import pytest

from urb_jax.sumo_bridge import SumoConfig
from urb_jax.sumo_bridge.keys import day_key, scenario_key
from urb_jax.sumo_bridge.memo import MemoExecutor, load_day, save_day
from urb_jax.sumo_bridge.types import ARRIVED, DayResult


def _day(choices: np.ndarray, seed: int) -> DayResult:
    n = choices.shape[0]
    tt = 1.0 + choices.astype(float)
    return DayResult(travel_time=tt, duration=tt * 60, route_length=np.full(n, 100.0),
                     mean_speed=np.full(n, 5.0), time_loss=np.zeros(n), depart_delay=np.zeros(n),
                     status=np.full(n, ARRIVED, np.int8),
                     seed=seed, stat_mean_speed=5.0, stat_mean_route_length=100.0, stat_mean_duration=60.0,
                     teleports=0, n_removed=0, sim_end_time=100.0, wall_time=0.5, leave_time=tt * 60)


class CountingExecutor:
    """Stand-in DayExecutor: counts every day it is asked for (choices, seed, first agent a CAV)."""

    config = SumoConfig()

    def __init__(self) -> None:
        self.days: list[tuple[tuple[int, ...], int, bool]] = []

    def run_days(self, scenario, choices, seeds, is_cav=None):
        masks = is_cav if is_cav is not None else [None] * len(seeds)
        for c, s, m in zip(choices, seeds, masks, strict=True):
            self.days.append((tuple(int(x) for x in c), int(s), m is not None and bool(m[0])))
        return [_day(np.asarray(c), int(s)) for c, s in zip(choices, seeds, strict=True)]

    def close(self) -> None:
        pass


@pytest.fixture(scope="module")
def two_choices(grid_scenario):
    n, k = grid_scenario.n_agents, grid_scenario.k
    return np.zeros(n, np.int64), np.arange(n) % k


def test_duplicates_run_once_and_keep_batch_order(grid_scenario, two_choices):
    inner = CountingExecutor()
    memo = MemoExecutor(inner)
    a, b = two_choices
    res = memo.run_days(grid_scenario, np.stack([a, b, a, a]), [42, 42, 42, 7])
    assert len(inner.days) == 3  # (a, 42), (b, 42), (a, 7)
    assert res[0] is res[2] and res[0] is not res[3]
    res2 = memo.run_days(grid_scenario, np.stack([b, a]), [42, 42])  # all seen: nothing simulated
    assert len(inner.days) == 3 and res2[0] is res[1] and res2[1] is res[0]
    assert (memo.simulated, memo.reused) == (3, 3)


def test_cav_mask_is_part_of_the_key(grid_scenario, two_choices):
    inner = CountingExecutor()
    memo = MemoExecutor(inner)
    a, _ = two_choices
    m1, m0 = np.zeros(len(a), bool), np.zeros(len(a), bool)
    m1[0] = True
    memo.run_days(grid_scenario, np.stack([a, a]), [42, 42], is_cav=np.stack([m1, m0]))
    assert len(inner.days) == 2
    # no mask means the Scenario's own agent kinds: the same day as that mask spelled out
    kinds = np.array([k == "AV" for k in grid_scenario.agent_kind])
    assert day_key(grid_scenario, a, 42, None, None) == day_key(grid_scenario, a, 42, kinds, None)


def test_day_key_covers_seed_choices_and_config(grid_scenario, two_choices):
    a, b = two_choices
    base = day_key(grid_scenario, a, 42, None, SumoConfig())
    assert base != day_key(grid_scenario, a, 43, None, SumoConfig())
    assert base != day_key(grid_scenario, b, 42, None, SumoConfig())
    assert base != day_key(grid_scenario, a, 42, None, SumoConfig(stuck_rule="routerl"))
    assert base == day_key(grid_scenario, a, 42, None, SumoConfig(shm_dir="/tmp"))  # where, not what


def test_scenario_key_is_content_not_path(grid_scenario, tmp_path):
    same = tmp_path / "same.net.xml"
    same.write_bytes(Path(grid_scenario.net_file).read_bytes())
    other = tmp_path / "other.net.xml"
    other.write_bytes(same.read_bytes() + b"<!-- changed -->\n")
    key = scenario_key(grid_scenario)
    assert scenario_key(dataclasses.replace(grid_scenario, net_file=str(same))) == key
    assert scenario_key(dataclasses.replace(grid_scenario, net_file=str(other))) != key
    later = grid_scenario.agent_depart + 1
    assert scenario_key(dataclasses.replace(grid_scenario, agent_depart=later)) != key


def test_disk_store_serves_a_new_executor_and_reruns_damaged_entries(grid_scenario, two_choices, tmp_path,
                                                                    caplog):
    a, b = two_choices
    first = MemoExecutor(CountingExecutor(), store_dir=tmp_path)
    ran = first.run_days(grid_scenario, np.stack([a, b]), [42, 42])
    files = sorted(tmp_path.rglob("*.npz"))
    assert len(files) == 2 and files[0].parent.name.startswith("urb_grid-")
    inner = CountingExecutor()
    again = MemoExecutor(inner, store_dir=tmp_path).run_days(grid_scenario, np.stack([b, a]), [42, 42])
    assert inner.days == [] and again[0].same_as(ran[1]) and again[1].same_as(ran[0])
    files[0].write_bytes(b"not an npz")  # damaged: run that day again and rewrite it
    third = MemoExecutor(inner, store_dir=tmp_path)
    with caplog.at_level(logging.WARNING, logger="urb_jax"):
        third.run_days(grid_scenario, np.stack([a, b, a, b]), [42] * 4)  # the damaged day twice: one warning
    assert (third.simulated, third.reused) == (1, 3)
    (warning,) = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert str(files[0]) in warning and "re-running" in warning
    load_day(files[0])  # readable again


def test_save_and_load_keep_every_field(tmp_path):
    day = _day(np.array([0, 1, 2]), 5)
    save_day(tmp_path / "d.npz", day)
    back = load_day(tmp_path / "d.npz")
    assert back.same_as(day) and back.wall_time == day.wall_time
    no_leave = dataclasses.replace(day, leave_time=None)
    save_day(tmp_path / "e.npz", no_leave)
    assert load_day(tmp_path / "e.npz").same_as(no_leave)
