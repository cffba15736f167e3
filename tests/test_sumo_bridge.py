"""run_day against SUMO's own command-line run, and the stuck-vehicle rules.

The CLI reference: `urb-jax export-day`'s plain .rou.xml (every vehicle written out with RouteRL's
`vehicle.add` defaults, in its insertion order) run by the `sumo` binary of the eclipse-sumo wheel,
so libsumo's runtime insertion, stepping and arrival bookkeeping are checked against SUMO's own
one-shot run.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.blocker import make_blocker

from urb_jax.reporting.day_export import day_routes_xml
from urb_jax.sumo_bridge import ARRIVED, REMOVED_CAP, REMOVED_STUCK, SumoConfig, run_day
from urb_jax.sumo_bridge.sim import Simulator

pytestmark = pytest.mark.sumo


def _sumo_binary() -> str:
    import sumo

    return os.path.join(sumo.SUMO_HOME, "bin", "sumo")


def _cli_day(scn, choices, is_cav, seed, tmp: Path) -> tuple[dict, dict]:
    """SUMO's one-shot run of the same day; returns (tripinfo by id, statistic attributes)."""
    rou = tmp / "day.rou.xml"
    rou.write_text(day_routes_xml(scn, choices, is_cav))
    subprocess.run(
        [_sumo_binary(), "-n", scn.net_file, "-r", str(rou), "--seed", str(seed), "--time-to-teleport", "-1",
         "--no-step-log", "true", "--no-warnings", "true", "--tripinfo-output", str(tmp / "trip.xml"),
         "--statistic-output", str(tmp / "stats.xml")],
        check=True, timeout=300,
    )
    trips = {}
    for m in re.finditer(r"<tripinfo ([^>]*)>", (tmp / "trip.xml").read_text()):
        a = dict(re.findall(r'(\w+)="([^"]*)"', m.group(1)))
        trips[a["id"]] = a
    stat_el = re.search(r"<vehicleTripStatistics ([^>]*)>", (tmp / "stats.xml").read_text())
    stats = dict(re.findall(r'(\w+)="([^"]*)"', stat_el[1]))
    return trips, stats


def _check_against_cli(scn, choices, is_cav, seed, tmp_path):
    res = run_day(scn, choices, seed=seed, is_cav=is_cav)
    trips, stats = _cli_day(scn, choices, is_cav, seed, tmp_path)
    ids = [str(a) for a in scn.agent_id]
    assert set(trips) == set(ids)
    assert (res.status == ARRIVED).all() and res.n_removed == 0
    arrival = np.array([float(trips[v]["arrival"]) for v in ids])
    np.testing.assert_array_equal(res.leave_time, arrival)
    np.testing.assert_array_equal(res.duration, [float(trips[v]["duration"]) for v in ids])
    np.testing.assert_array_equal(res.depart_delay, [float(trips[v]["departDelay"]) for v in ids])
    np.testing.assert_allclose(res.route_length, [float(trips[v]["routeLength"]) for v in ids], atol=0.005)
    np.testing.assert_allclose(res.time_loss, [float(trips[v]["timeLoss"]) for v in ids], atol=0.005)
    # URB's travel time: RouteRL records an arrival 2 s after SUMO's arrival stamp.
    np.testing.assert_array_equal(res.travel_time, (arrival + 2 - scn.agent_depart) / 60.0)
    assert res.stat_mean_route_length == pytest.approx(float(stats["routeLength"]), abs=0.01)
    assert res.stat_mean_duration == pytest.approx(float(stats["duration"]), abs=0.01)
    assert res.stat_mean_speed == pytest.approx(float(stats["speed"]), abs=0.01)
    return res


def test_run_day_matches_sumo_cli_on_grid(grid_scenario, tmp_path):
    scn = grid_scenario
    rng = np.random.default_rng(3)
    choices = rng.integers(0, scn.k, size=scn.n_agents)
    is_cav = rng.random(scn.n_agents) < 0.4
    res = _check_against_cli(scn, choices, is_cav, 7, tmp_path)
    # a different seed changes SUMO's draws (speed factors), so the seed really reaches SUMO
    other = run_day(scn, choices, seed=8, is_cav=is_cav)
    assert not np.array_equal(other.leave_time, res.leave_time)


def test_run_day_matches_sumo_cli_on_saint_arnoult(real_networks_dir, tmp_path):
    from urb_jax.city.scenario import load_scenario

    scn = load_scenario("saint_arnoult", networks_dir=real_networks_dir)
    _check_against_cli(scn, scn.fft.argmin(1), np.zeros(scn.n_agents, bool), 42, tmp_path)


_PYARROW_FIRST = """
import sys
import numpy as np
import pyarrow as pa, pyarrow.parquet as pq
pq.write_table(pa.table({"x": [1, 2]}), sys.argv[1] + "/t.parquet")  # pyarrow's own libarrow in use
assert pq.read_table(sys.argv[1] + "/t.parquet").column("x").to_pylist() == [1, 2]
from urb_jax.city.scenario import load_scenario
from urb_jax.sumo_bridge import run_day
scn = load_scenario("urb_grid")
rng = np.random.default_rng(3)
choices, is_cav = rng.integers(0, scn.k, size=scn.n_agents), rng.random(scn.n_agents) < 0.4
np.save(sys.argv[1] + "/leave.npy", run_day(scn, choices, seed=7, is_cav=is_cav).leave_time)
"""


def test_sumo_day_start_prints_no_pyarrow_notice_and_matches_cli(grid_scenario, tmp_path):
    """libsumo/__init__.py prints a pyarrow-version notice on import (pyarrow 26 vs its libarrow
    2300); urb-jax drops exactly that notice (sim.import_libsumo). Its claim of harm is checked:
    with pyarrow's libarrow loaded and used first, the libsumo day still equals SUMO's CLI run."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    out = subprocess.run([sys.executable, "-c", _PYARROW_FIRST, str(tmp_path)], capture_output=True,
                         text=True, timeout=300, env=env, check=True)
    assert "pyarrow" not in out.stdout + out.stderr, out.stdout + out.stderr
    assert "libarrow" not in out.stdout + out.stderr
    rng = np.random.default_rng(3)
    scn = grid_scenario
    choices, is_cav = rng.integers(0, scn.k, size=scn.n_agents), rng.random(scn.n_agents) < 0.4
    trips, _ = _cli_day(scn, choices, is_cav, 7, tmp_path)
    arrival = [float(trips[str(a)]["arrival"]) for a in scn.agent_id]
    np.testing.assert_array_equal(np.load(tmp_path / "leave.npy"), arrival)


def test_import_libsumo_keeps_its_other_output(monkeypatch, capsys):
    """Only the notice's two lines are dropped: anything else libsumo prints on import stays."""
    import builtins
    import types

    from urb_jax.sumo_bridge import sim

    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name == "libsumo":
            print("Warning! pyarrow is installed with version 26.0.1 which might be incompatible ...")
            print(" Try to uninstall pyarrow or install a matching pyarrow version, if you encounter "
                  "problems.")
            print("SUMO says something else")
            return types.ModuleType("libsumo")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "libsumo", raising=False)
    monkeypatch.setattr("builtins.__import__", fake_import)
    module = sim.import_libsumo()
    monkeypatch.undo()
    assert module.__name__ == "libsumo"
    assert capsys.readouterr().out == "SUMO says something else\n"


def test_repeated_days_are_identical(grid_scenario):
    choices = grid_scenario.fft.argmin(1)
    a = run_day(grid_scenario, choices, seed=42)
    run_day(grid_scenario, np.zeros_like(choices), seed=5)  # something else in between
    b = run_day(grid_scenario, choices, seed=42)
    assert a.same_as(b)


def test_preloaded_next_day_needs_no_load_and_is_the_same_day(grid_scenario):
    """`preload` loads the day `run_day` named next; that day then runs without a load of its own
    and equals a day run from a fresh start."""
    choices = grid_scenario.fft.argmin(1)
    sim = Simulator()
    try:
        first = sim.run_day(grid_scenario, choices, seed=42, next_seed=7)
        sim.preload()
        loads = sim._n_loads
        nxt = sim.run_day(grid_scenario, choices, seed=7)
        assert sim._n_loads == loads  # its network was pre-loaded
        assert sim.run_day(grid_scenario, choices, seed=42).same_as(first)  # no pre-load: loads itself
    finally:
        sim.close()
    assert nxt.same_as(run_day(grid_scenario, choices, seed=7))


def test_deadlocked_day_ends_with_stuck_vehicles_removed(grid_scenario, tmp_path):
    scn = grid_scenario
    choices = scn.fft.argmin(1)
    add, edge = make_blocker(scn, choices, tmp_path)
    cfg = SumoConfig(additional_files=(str(add),))
    res = run_day(scn, choices, seed=42, config=cfg)
    stuck = res.status == REMOVED_STUCK
    uses_edge = np.array([edge in scn.route_edge_ids(int(o), int(k))
                          for o, k in zip(scn.agent_od, choices, strict=True)])
    assert res.n_removed == stuck.sum() >= 2
    assert res.teleports == 0
    assert uses_edge[stuck].mean() > 0.5  # queued behind the blocker (or caught in its spillback)
    assert (res.status[scn.agent_depart > 1500] == ARRIVED).all()  # after the blocker left
    # stood still for more than 600 s before removal; charged the time until removal (+2 s)
    assert (res.leave_time[stuck] - scn.agent_depart[stuck] - res.depart_delay[stuck] > 600).all()
    assert (res.time_loss[stuck] > 600).all()
    np.testing.assert_array_equal(res.travel_time[stuck],
                                  (res.leave_time[stuck] + 2 - scn.agent_depart[stuck]) / 60.0)
    assert np.isnan(res.duration[stuck]).all() and np.isnan(res.mean_speed[stuck]).all()

    # URB's literal penalty: a flat simulation_timesteps / 60 for every removed vehicle
    urb = run_day(scn, choices, seed=42, config=SumoConfig(additional_files=(str(add),), stuck_penalty="urb"))
    np.testing.assert_array_equal(urb.status, res.status)
    assert (urb.travel_time[stuck] == scn.simulation_timesteps / 60.0).all()
    np.testing.assert_array_equal(urb.travel_time[~stuck], res.travel_time[~stuck])


def test_sumo_teleport_rule_and_hard_cap_also_end_the_day(grid_scenario, tmp_path):
    scn = grid_scenario
    choices = scn.fft.argmin(1)
    add, _ = make_blocker(scn, choices, tmp_path)
    res = run_day(scn, choices, seed=42, config=SumoConfig(additional_files=(str(add),), stuck_rule="sumo"))
    assert res.n_removed > 0 and (res.status != REMOVED_CAP).all()
    assert res.teleports == res.n_removed  # SUMO counts its removals as teleports
    forever, _ = make_blocker(scn, choices, tmp_path, duration=10**6)
    capped = run_day(scn, choices, seed=42,
                     config=SumoConfig(additional_files=(str(forever),), max_sim_time_s=1300))
    assert capped.sim_end_time == 1300
    cap = capped.status == REMOVED_CAP
    assert cap.any()
    np.testing.assert_array_equal(capped.leave_time[cap], 1300)
    np.testing.assert_array_equal(capped.travel_time[cap], (1300 + 2 - scn.agent_depart[cap]) / 60.0)


def test_bad_choices_are_rejected(grid_scenario):
    with pytest.raises(ValueError, match="route indices"):
        run_day(grid_scenario, np.full(grid_scenario.n_agents, grid_scenario.k), seed=1)
    with pytest.raises(ValueError, match="shape"):
        run_day(grid_scenario, np.zeros(3, int), seed=1)
