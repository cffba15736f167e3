"""Departures that vary day to day (task key day_departure_jitter_s): each day's departures are a
reproducible draw around the scheduled ones; SUMO inserts each vehicle at its day's second and
URB's travel time counts from it; the surrogate's day of the same index moves by the same draw; the
runs' post-mutation SUMO days get their day's departures (and are refitted on with them) and the
human phase keeps the scheduled ones; runs that cannot honour the option refuse it."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from support.fakeday import FakeExecutor
from support.tiny_runs import train_iql

from urb_jax.city.demand import ABSENT
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import TaskConfig
from urb_jax.game.demand import DepartureJitter, jittered_departures
from urb_jax.game.env import RoutingEnv
from urb_jax.game.mutation import draw_cavs
from urb_jax.runs.setup import check_departure_jitter
from urb_jax.sumo_bridge import day_key, run_day
from urb_jax.sumo_bridge.keys import routes_key, scenario_key
from urb_jax.sumo_bridge.scheduler import KEPT_SCENARIOS, KeptScenarios
from urb_jax.surrogate import SumoSample, SurrogateConfig, build_static, init_params
from urb_jax.surrogate.calibrate import FitConfig, loss_fn
from urb_jax.surrogate.model import predict_days


def test_a_days_departures_are_a_reproducible_bounded_draw():
    sched = np.arange(0, 4000, 10)  # [400]
    a = jittered_departures(42, 60, 7, sched)
    np.testing.assert_array_equal(a, jittered_departures(42, 60, 7, sched))  # reproducible
    off = a - sched
    assert a.dtype == np.int64 and off[sched >= 60].min() >= -60 and off.max() <= 60
    assert (a >= 0).all() and a[0] == max(0, off[0])  # never before second 0
    assert len(np.unique(off)) > 60 and abs(off[sched >= 60].mean()) < 10  # spread over [-60, 60]
    assert not np.array_equal(a, jittered_departures(42, 60, 8, sched))  # another day
    assert not np.array_equal(a, jittered_departures(43, 60, 7, sched))  # another env seed
    assert TaskConfig().departure_jitter(42) is None
    assert TaskConfig(day_departure_jitter_s=60).departure_jitter(42) == DepartureJitter(42, 60)
    with pytest.raises(ConfigError, match="day_departure_jitter_s"):
        TaskConfig(day_departure_jitter_s=-1)


def test_sumo_inserts_each_vehicle_at_its_days_second(grid_scenario):
    """A lone vehicle: free flow either way, so its travel time is the same and it leaves the network
    exactly its departure offset later."""
    lone = grid_scenario.with_agents(np.array([5]))
    jitter = DepartureJitter(seed=3, jitter_s=90)
    sched = lone.agent_depart[0]
    day = next(d for d in range(64) if jitter.departures(d, lone.agent_depart)[0] - sched >= 30)
    moved = jitter.scenario_on(lone, day)
    offset = int(moved.agent_depart[0] - lone.agent_depart[0])
    choice = np.zeros(1, np.int64)
    base, shifted = run_day(lone, choice, seed=42), run_day(moved, choice, seed=42)
    assert shifted.leave_time[0] - base.leave_time[0] == pytest.approx(offset)
    assert shifted.travel_time[0] == pytest.approx(base.travel_time[0])  # counted from its own departure
    # the same network and routes (one route file), another day for the store
    assert routes_key(moved) == routes_key(lone) and scenario_key(moved) != scenario_key(lone)
    assert day_key(moved, choice, 42, None, None) != day_key(lone, choice, 42, None, None)


def test_the_model_day_gets_its_days_shifts_in_the_program(grid_scenario):
    """A model day on day index d is given exactly SUMO day d's departures minus the schedule, drawn
    inside the jitted step from the traced day counter."""
    scn = grid_scenario
    jitter = DepartureJitter(seed=7, jitter_s=120)

    def shift_as_time(params, choices, shift):  # minutes = 1 + the shift in seconds
        return 1.0 + params["scale"] * shift

    env = RoutingEnv(scn, draw_cavs(0, scn.n_agents, 0.4), shift_as_time, depart_jitter=jitter,
                     default_params={"scale": jnp.asarray(1.0)})
    _, state = env.reset(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    actions = jnp.zeros((env.n_cavs,), jnp.int32)
    for day in (0, 5, 6):
        state = state._replace(day=jnp.asarray(day, jnp.int32))
        times = np.asarray(step(jax.random.PRNGKey(1), state, actions)[1].times)
        expected = jittered_departures(7, 120, day, scn.agent_depart) - scn.agent_depart
        np.testing.assert_array_equal(times, 1.0 + expected)
    with pytest.raises(ValueError, match="day index"):
        env.travel_times(None, env.joint_actions(state, actions))


def test_a_moved_drivers_speed_factor_is_its_insertion_slots(grid_scenario, monkeypatch):
    """SUMO draws a vehicle's speedFactor as it is added, in insertion order: on any day driver n
    drives at the factor of the slot it holds, which the model reads from the driver that held the
    slot in the human phase (scheduled, no CAV; `slot_agents`): after mutation (CAVs added after
    the humans of their second), on a moved day, and on a day some drivers stay home."""
    import libsumo

    from urb_jax.sumo_bridge.sim import Simulator
    from urb_jax.surrogate.departures import slot_agents

    factors: dict[str, float] = {}
    add = libsumo.vehicle.add

    def add_and_read(vid, *args, **kwargs):
        add(vid, *args, **kwargs)
        factors[vid] = libsumo.vehicle.getSpeedFactor(vid)

    monkeypatch.setattr(libsumo.vehicle, "add", add_and_read)
    scn = grid_scenario
    is_cav = draw_cavs(0, scn.n_agents, 0.4)
    moved = DepartureJitter(seed=7, jitter_s=120).scenario_on(scn, 3)
    choice = np.zeros(scn.n_agents, np.int64)
    home = np.random.default_rng(0).random(scn.n_agents) < 0.2
    days = [(scn, choice, None), (scn, choice, is_cav), (moved, choice, is_cav),
            (scn, np.where(home, ABSENT, choice), is_cav)]
    sim = Simulator()
    try:
        factor = []
        for s, c, cav in days:
            factors.clear()
            sim.run_day(s, c, seed=42, is_cav=cav)
            factor.append(np.array([factors.get(str(int(a)), np.nan) for a in scn.agent_id]))
    finally:
        sim.close()
    human_phase, mutated, on_moved, on_fewer = factor
    static = build_static(scn, SurrogateConfig(), max_shift_s=120.0, is_cav=is_cav)
    zero = jnp.zeros(scn.n_agents)
    holder = np.asarray(slot_agents(static.departs, zero))
    assert (holder != np.arange(scn.n_agents)).sum() > 10  # CAVs moved behind humans of their second
    np.testing.assert_allclose(mutated, human_phase[holder])
    shift = jnp.asarray(moved.agent_depart - scn.agent_depart, jnp.float32)
    assert np.mean(np.isclose(on_moved, human_phase)) < 0.5  # the factors did not stay with the drivers
    np.testing.assert_allclose(on_moved, human_phase[np.asarray(slot_agents(static.departs, shift))])
    holder = np.asarray(slot_agents(static.departs, zero, jnp.asarray(~home)))
    assert np.isnan(on_fewer[home]).all() and np.mean(np.isclose(on_fewer[~home], human_phase[~home])) < 0.5
    np.testing.assert_allclose(on_fewer[~home], human_phase[holder[~home]])
    no_cav = build_static(scn, SurrogateConfig(), max_shift_s=120.0)
    np.testing.assert_array_equal(np.asarray(slot_agents(no_cav.departs, zero)), np.arange(scn.n_agents))


def test_a_sample_of_moved_days_is_fitted_with_its_shifts(grid_scenario):
    """SUMO days whose departures moved carry their shifts (scheduled days: zeros when mixed); the
    calibration loss predicts each day with its own shifts: days made by the model under their
    shifts have no error at the model's parameters, and read as scheduled they would."""
    scn = grid_scenario
    static = build_static(scn, SurrogateConfig(chunk=32), max_shift_s=300.0)
    params = init_params(static)
    params = {**params, "log_a_c": params["log_a_c"] + 2.5}
    rng = np.random.default_rng(2)
    choices = rng.integers(0, scn.k, (3, scn.n_agents)).astype(np.int32)
    shift = np.stack([jittered_departures(7, 300, d, scn.agent_depart) - scn.agent_depart
                      for d in range(3)]).astype(np.float32)
    times = np.asarray(predict_days(params, static, jnp.asarray(choices), jnp.asarray(shift)))
    moved = SumoSample(choices, times, np.ones_like(choices, bool), shift)
    sched = SumoSample(choices[:1], times[:1], np.ones_like(choices[:1], bool))
    both = sched + moved
    np.testing.assert_array_equal(both.shifts(), np.concatenate([np.zeros_like(shift[:1]), shift]))
    np.testing.assert_array_equal(both.days([2]).shift, shift[1:2])
    assert (sched + sched).shift is None

    def loss(sample: SumoSample) -> float:
        data = {"choices": jnp.asarray(sample.choices), "travel_time": jnp.asarray(sample.travel_time),
                "arrived": jnp.asarray(sample.arrived)}
        if sample.shift is not None:
            data["shift"] = jnp.asarray(sample.shift)
        return float(loss_fn(params, static, data, params, FitConfig(edge_prior=0.0, agent_prior=0.0)))

    assert loss(moved) < 1e-10
    assert loss(SumoSample(choices, times, moved.arrived)) > 1e-6


def test_kept_scenarios_drop_the_oldest_as_both_sides_do():
    kept: KeptScenarios[int] = KeptScenarios()
    dropped = [kept.add(f"k{i}", i) for i in range(KEPT_SCENARIOS + 2)]
    assert dropped[:KEPT_SCENARIOS] == [[]] * KEPT_SCENARIOS and dropped[-2:] == [["k0"], ["k1"]]
    assert "k0" not in kept and "k2" in kept and kept[f"k{KEPT_SCENARIOS + 1}"] == KEPT_SCENARIOS + 1


class _Recording(FakeExecutor):
    """FakeExecutor that also remembers each batch's departures."""

    def __init__(self) -> None:
        super().__init__()
        self.departs: list[np.ndarray] = []

    def run_days(self, scenario, choices, seeds, is_cav=None):
        self.departs += [np.asarray(scenario.agent_depart).copy()] * len(choices)
        return super().run_days(scenario, choices, seeds, is_cav)


@pytest.mark.slow  # a whole tiny hybrid run
def test_a_runs_days_after_mutation_leave_at_their_days_seconds(tiny_iql_confs, tmp_path, grid_scenario):
    ex = _Recording()
    train_iql(tiny_iql_confs, tmp_path, "jitter", executor=ex, env_seed=7,
              overrides=("task.day_departure_jitter_s=120",))
    sched = grid_scenario.agent_depart
    moved = [d for d in ex.departs if not np.array_equal(d, sched)]
    assert moved and len(moved) < len(ex.departs)  # the human phase and calibration keep the schedule
    draws = [jittered_departures(7, 120, d, sched) for d in range(64)]
    for d in moved:  # each is one day's draw of the env seed
        assert any(np.array_equal(d, v) for v in draws)
    assert len({d.tobytes() for d in moved}) > 1  # the days differ
    # the surrogate refits on each SUMO day with that day's departures (the checkpoint keeps them)
    newest = max(tmp_path.rglob("sumo_days.npz"), key=lambda p: p.parent.name)  # checkpoints/round_N
    shifts = np.load(newest)["shift_0"]  # [D, N]: the calibration days, then the SUMO training days
    later = shifts[~(shifts == 0).all(axis=1)]
    assert len(later) >= 2 and len(later) < len(shifts)
    for row in later:
        assert any(np.array_equal(row, v - sched) for v in draws)


def test_runs_that_cannot_honour_jitter_refuse_it():
    task, path = TaskConfig(day_departure_jitter_s=60), Path("task.json")
    check_departure_jitter(task, path, train=True)
    with pytest.raises(ConfigError, match=r"queue surrogate.*surrogate_model"):
        check_departure_jitter(task, path, train=True, surrogate_model="queue")
    check_departure_jitter(task, path, train=False, baseline="aon")
    with pytest.raises(ConfigError, match=r"task.json: key 'day_departure_jitter_s' = 60.*the 'human'"):
        check_departure_jitter(task, path, train=False, baseline="human")
    check_departure_jitter(TaskConfig(), path, train=False, baseline="human")  # off: nothing to refuse


def test_tools_that_resimulate_a_runs_days_refuse_a_jittered_run(tmp_path):
    from urb_jax.analysis.optimum import run_references
    from urb_jax.core.errors import UrbJaxError
    from urb_jax.reporting.day_export import export_day
    from urb_jax.reporting.headroom import headroom

    run = tmp_path / "run"
    run.mkdir()
    (run / "exp_config.json").write_text(json.dumps({"day_departure_jitter_s": 60, "env_seed": 7}))
    for tool in (lambda: export_day(run, tmp_path / "day.rou.xml"), lambda: headroom(run),
                 lambda: run_references(run)):
        with pytest.raises(UrbJaxError, match=r"exp_config.json: key 'day_departure_jitter_s' = 60.*Fix"):
            tool()


@pytest.mark.slow  # two tiny hybrid runs
def test_a_stopped_jittered_run_resumes_to_the_uninterrupted_runs_results(tmp_path):
    """The SUMO days' shifts are in the round checkpoint: a jittered run stopped after its first round
    and resumed refits on the same days and ends with the records and metric files of the same run
    never stopped."""
    from support.tiny_runs import stopped_and_whole, tiny_reward_run

    resumed, whole = stopped_and_whole(tiny_reward_run(tmp_path, day_departure_jitter_s=120), tmp_path)
    assert whole is not None and resumed == whole
