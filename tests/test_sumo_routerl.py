"""run_day against a literal re-run of RouteRL 2.0.0's simulation loop (traci + the sumo binary).

The reference follows `SumoSimulator.step` / `TrafficEnvironment._help_step`: vehicles are added
with `vehicle.add` at their departure second (humans before CAVs), arrivals are read before each
`simulationStep` and charged `(timestep after the step - start_time) / 60`, and a vehicle whose
speed is exactly 0 for more than 600 consecutive steps is removed and charged
`simulation_timesteps / 60`. Speeds come from traci subscriptions (same values as getSpeed).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from support.blocker import make_blocker

from urb_jax.sumo_bridge import REMOVED_STUCK, SumoConfig, run_day
from urb_jax.sumo_bridge.tripinfo import write_routes_file

pytestmark = pytest.mark.sumo


def routerl_day(scn, choices, is_cav, seed, tmp, extra_additional=(), stuck_time=600):
    import sumo
    import traci

    routes = tmp / "routes.add.xml"
    write_routes_file(routes, scn)
    adds = ",".join([str(routes), *map(str, extra_additional)])
    traci.start([os.path.join(sumo.SUMO_HOME, "bin", "sumo"), "--seed", str(seed), "--net-file", scn.net_file,
                 "--additional-files", adds, "--no-step-log", "true", "--time-to-teleport", "-1",
                 "--no-warnings", "true"], label="routerl-ref")
    conn = traci.getConnection("routerl-ref")
    try:
        by_second: dict[int, list[int]] = {}
        for i in range(scn.n_agents):
            by_second.setdefault(int(scn.agent_depart[i]), []).append(i)
        sim_len = scn.simulation_timesteps
        tt: dict[str, float] = {}
        waiting: dict[str, int] = {}
        speed: dict[str, float] = {}
        start = {str(a): int(d) for a, d in zip(scn.agent_id, scn.agent_depart, strict=True)}
        timestep = 0
        while timestep < sim_len or len(tt) < scn.n_agents:
            todo = sorted(by_second.get(timestep, []), key=lambda i: bool(is_cav[i]))  # humans first
            for i in todo:
                vid = str(scn.agent_id[i])
                conn.vehicle.add(vid, f"{scn.agent_od[i]}_{choices[i]}",
                                 typeID="AV" if is_cav[i] else "Human", depart=str(int(scn.agent_depart[i])))
                waiting[vid] = 0
            arrivals = list(conn.simulation.getArrivedIDList())
            for a in arrivals:
                waiting.pop(a, None)
            teleported = []
            for vid in list(waiting):
                if speed.get(vid, -1.0) == 0:  # not yet inserted: getSpeed is invalid, never 0
                    waiting[vid] += 1
                    if waiting[vid] > stuck_time:
                        conn.vehicle.remove(vid)
                        teleported.append(vid)
                        waiting.pop(vid)
                else:
                    waiting[vid] = 0
            conn.simulationStep()
            timestep += 1
            for vid in conn.simulation.getDepartedIDList():
                conn.vehicle.subscribe(vid, [traci.constants.VAR_SPEED])
            subs = conn.vehicle.getAllSubscriptionResults()
            speed = {k: v[traci.constants.VAR_SPEED] for k, v in subs.items()}
            for a in arrivals:
                if a in start and a not in teleported and a not in tt:  # skip a test's blocker
                    tt[a] = (timestep - start[a]) / 60
            for a in teleported:
                tt[a] = sim_len / 60.0
    finally:
        conn.close()
    return np.array([tt[str(a)] for a in scn.agent_id])


def test_travel_times_equal_routerl_loop(grid_scenario, tmp_path):
    scn = grid_scenario
    rng = np.random.default_rng(5)
    choices = rng.integers(0, scn.k, size=scn.n_agents)
    is_cav = rng.random(scn.n_agents) < 0.4
    ref = routerl_day(scn, choices, is_cav, 11, tmp_path)
    res = run_day(scn, choices, seed=11, is_cav=is_cav)
    np.testing.assert_array_equal(res.travel_time, ref)


def test_stuck_removals_equal_routerl_loop(grid_scenario, tmp_path):
    scn = grid_scenario
    choices = scn.fft.argmin(1)
    blocker, _ = make_blocker(scn, choices, tmp_path)
    ref = routerl_day(scn, choices, np.zeros(scn.n_agents, bool), 42, tmp_path, [blocker])
    exact = run_day(scn, choices, seed=42, config=SumoConfig(
        additional_files=(str(blocker),), stuck_rule="routerl", stuck_penalty="urb"))
    assert (exact.status == REMOVED_STUCK).sum() >= 2
    np.testing.assert_array_equal(exact.travel_time, ref)
    # the cheap default clock (SUMO's waiting time) removes the same first vehicles a little earlier
    fast = run_day(scn, choices, seed=42, config=SumoConfig(additional_files=(str(blocker),)))
    first = np.argmin(np.where(exact.status == REMOVED_STUCK, exact.leave_time, np.inf))
    assert fast.status[first] == REMOVED_STUCK
    assert 0 <= exact.leave_time[first] - fast.leave_time[first] <= 20
