"""The surrogate model: shapes, batching, one-hot vs probabilities, a hand-computed day, gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from urb_jax.city.routes import RouteParams
from urb_jax.city.scenario import Scenario
from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict, predict_jit


@pytest.fixture(scope="module")
def grid(grid_scenario):
    static = build_static(grid_scenario, SurrogateConfig(chunk=32))
    params = init_params(static)
    # congest the grid so the BPR term matters
    params = {**params, "log_a_c": params["log_a_c"] + 2.0}
    return grid_scenario, static, params


def _choices(scn, b, seed=0):
    return np.random.default_rng(seed).integers(0, scn.k, (b, scn.n_agents)).astype(np.int32)


def test_shapes_and_batch_equals_per_day_loop(grid):
    scn, static, params = grid
    ch = _choices(scn, 70)  # > chunk: padded and mapped over chunks
    batch = np.asarray(predict_jit(params, static, jnp.asarray(ch)))
    assert batch.shape == (70, scn.n_agents)
    assert np.isfinite(batch).all() and (batch > 0).all()
    loop = np.stack([np.asarray(predict_jit(params, static, jnp.asarray(c))) for c in ch[:: 7]])
    np.testing.assert_allclose(batch[:: 7], loop, rtol=1e-5)
    # vmap over days of the unbatched function agrees too
    vm = np.asarray(jax.jit(jax.vmap(lambda c: predict(params, static, c)))(jnp.asarray(ch[:5])))
    np.testing.assert_allclose(vm, batch[:5], rtol=1e-5)


def test_congestion_is_local_in_time(grid):
    """Moving other agents changes only the times of agents that travel near them in time."""
    scn, static, params = grid
    base = _choices(scn, 1)[0]
    late = scn.agent_depart >= scn.agent_depart.max() - 120
    moved = np.where(late, (base + 1) % scn.k, base)
    t0, t1 = np.asarray(predict_jit(params, static, jnp.asarray(np.stack([base, moved]))))
    # late agents enter edges at >= 1080 s: bins centred at 1050 s and later (300 s bins). An agent
    # whose every edge entry is before 750 s only touches bins centred at <= 750 s.
    assert scn.agent_depart.max() - 120 == 1080
    early = scn.agent_depart + 1.2 * 60 * scn.fft_full.max(axis=1) < 745
    assert early.sum() > 10
    np.testing.assert_allclose(t0[early], t1[early], rtol=1e-6)
    assert not np.allclose(t0[late], t1[late])


def test_one_hot_probabilities_match_indices(grid):
    scn, static, params = grid
    ch = _choices(scn, 4, seed=1)
    probs = np.eye(scn.k, dtype=np.float32)[ch]
    a = np.asarray(predict_jit(params, static, jnp.asarray(ch)))
    b = np.asarray(predict_jit(params, static, jnp.asarray(probs)))
    np.testing.assert_allclose(a, b, rtol=1e-5)


def _tiny_scenario(tmp_path, capacity_vph=12.0) -> Scenario:
    """3 edges, 2 agents from e0: route 0 = e0 e1, route 1 = e0 e2; both leave at 150 s."""
    net = tmp_path / "tiny.net.xml"
    net.write_text(
        '<net><edge id="e0" from="a" to="b"/><edge id="e1" from="b" to="c"/><edge id="e2" from="b" to="d"/>'
        '<junction id="b" type="priority"/><junction id="c" type="dead_end"/>'
        '<junction id="d" type="dead_end"/></net>'
    )
    routes = np.array([[[0, 1], [0, 2], [0, 2], [0, 2]]], dtype=np.int32)
    return Scenario(
        name="tiny", net_file=str(net), env_seed=0, route_params=RouteParams(),
        edge_ids=("e0", "e1", "e2"), edge_length=np.array([3000.0, 1000.0, 1000.0]),
        edge_speed=np.array([10.0, 10.0, 10.0]), edge_lanes=np.array([1, 1, 1]),
        edge_priority=np.array([1, 1, 1]), edge_type=("t", "t", "t"),
        edge_capacity=np.full(3, capacity_vph),
        od_origin=np.array([0]), od_destination=np.array([0]), od_origin_edge=("e0",),
        od_destination_edge=("e1",), od_routes=routes, od_route_len=np.array([[2, 2, 2, 2]]),
        od_route_valid=np.array([[True, True, False, False]]),
        od_fft=np.zeros((1, 4)), od_fft_full=np.zeros((1, 4)), od_route_length=np.zeros((1, 4)),
        agent_id=np.array([0, 1]), agent_od=np.array([0, 0]), agent_origin=np.array([0, 0]),
        agent_destination=np.array([0, 0]), agent_depart=np.array([150, 150]),
        agent_kind=("Human", "Human"),
    )


def test_hand_computed_two_agents_sharing_an_edge(tmp_path):
    """Bins of 300 s, entries at bin centres: e0 at 150 s (bin 0), e1/e2 at 150+300 s (bin 1).

    Capacity 12 veh/h = 1 vehicle per bin, a = 0.15, p = 4, no junction delay, insertion 2 s per
    same-origin departure (load 2), intercept 1 s.
      both on route 0: each edge x=2: (300 + 100) * (1 + 0.15*16) + 4 + 1 = 1365 s = 22.75 min
      agent 1 on route 1: e0 x=2 (1020 s), e1/e2 x=1 (115 s): 1020 + 115 + 5 = 1140 s = 19 min
    """
    scn = _tiny_scenario(tmp_path)
    static = build_static(scn, SurrogateConfig(bin_s=300.0, entry_scale=1.0))
    params = init_params(static)
    params = {**params, "log_a_c": jnp.log(jnp.array([0.15])), "log_junc_j": jnp.full(4, -40.0),
              "log_ins": jnp.log(jnp.array(2.0)), "intercept": jnp.array(1.0)}
    out = np.asarray(predict_jit(params, static, jnp.array([[0, 0], [0, 1]])))
    np.testing.assert_allclose(out, [[22.75, 22.75], [19.0, 19.0]], rtol=1e-5)
    # probabilities 50/50 for agent 1: e1 and e2 each carry 1.5 resp. 0.5 vehicles
    probs = jnp.array([[[1.0, 0, 0, 0], [0.5, 0.5, 0, 0]]])
    e0 = 300 * (1 + 0.15 * 2.0**4)
    t_a0 = e0 + 100 * (1 + 0.15 * 1.5**4) + 5
    t_a1 = 0.5 * (e0 + 100 * (1 + 0.15 * 1.5**4)) + 0.5 * (e0 + 100 * (1 + 0.15 * 0.5**4)) + 5
    np.testing.assert_allclose(np.asarray(predict_jit(params, static, probs))[0],
                               np.array([t_a0, t_a1]) / 60, rtol=1e-5)


def test_grad_wrt_logits_matches_finite_differences(grid):
    scn, static, params = grid
    rng = np.random.default_rng(3)
    logits = jnp.asarray(rng.normal(size=(scn.n_agents, scn.k)).astype(np.float32))
    group = jnp.asarray(rng.random(scn.n_agents) < 0.3)

    def group_time(lg):
        t = predict(params, static, jax.nn.softmax(lg, axis=-1))
        return jnp.where(group, t, 0.0).sum()

    g = jax.grad(group_time)(logits)
    f = jax.jit(group_time)
    for s in range(3):
        v = jnp.asarray(np.random.default_rng(10 + s).normal(size=logits.shape).astype(np.float32))
        eps = 1e-2
        fd = (f(logits + eps * v) - f(logits - eps * v)) / (2 * eps)
        an = float((g * v).sum())
        assert abs(float(fd) - an) <= 2e-2 * abs(an) + 1e-3, (float(fd), an)
    # a single coordinate (one agent's logit) as well
    e = jnp.zeros_like(logits).at[5, 1].set(1.0)
    fd = (f(logits + 1e-2 * e) - f(logits - 1e-2 * e)) / 2e-2
    assert abs(float(fd) - float(g[5, 1])) <= 3e-2 * abs(float(g[5, 1])) + 1e-3


def test_hand_computed_day_whose_departures_move(tmp_path):
    """The two agents of the hand-computed day above, both on route 0; agent 1 leaves 300 s late.
    Its entries move one bin: every (edge, bin) then carries one vehicle,
      each: (300 + 100) * (1 + 0.15 * 1) + 2 * 1 (load 1) + 1 = 463 s;
    40 s late, agent 1 counts agent 0 in its 60-s insertion window and agent 0 does not count it."""
    from urb_jax.surrogate.departures import day_weights

    scn = _tiny_scenario(tmp_path)
    static = build_static(scn, SurrogateConfig(bin_s=300.0, entry_scale=1.0), max_shift_s=300.0)
    params = init_params(static)
    params = {**params, "log_a_c": jnp.log(jnp.array([0.15])), "log_junc_j": jnp.full(4, -40.0),
              "log_ins": jnp.log(jnp.array(2.0)), "intercept": jnp.array(1.0)}
    both = jnp.array([[0, 0]])
    scheduled = np.asarray(predict_jit(params, static, both))
    unmoved = np.asarray(predict_jit(params, static, both, jnp.zeros(2)))
    np.testing.assert_allclose(unmoved, scheduled, rtol=1e-6)
    np.testing.assert_allclose(scheduled, [[22.75, 22.75]], rtol=1e-5)
    late = np.asarray(predict_jit(params, static, both, jnp.array([0.0, 300.0])))
    np.testing.assert_allclose(late, [[463 / 60, 463 / 60]], rtol=1e-5)
    load = np.asarray(day_weights(static.departs, jnp.array([0.0, 40.0]))[2])
    np.testing.assert_array_equal(load, [1.0, 2.0])
    with pytest.raises(ValueError, match="max_shift_s"):
        predict(params, build_static(scn, SurrogateConfig(bin_s=300.0)), both, jnp.zeros(2))


def test_moving_departures_keep_the_scheduled_model_and_its_gradients(grid_scenario):
    """Zero shifts are the scheduled model; moving everyone by one bin width moves every entry by
    exactly one bin (same times); shifts reach the times of those who move and stay differentiable."""
    scn = grid_scenario
    static = build_static(scn, SurrogateConfig(chunk=32), max_shift_s=300.0)
    params = init_params(static)
    params = {**params, "log_a_c": params["log_a_c"] + 2.0}
    ch = jnp.asarray(_choices(scn, 40, seed=4))  # > chunk: mapped over chunks
    base = np.asarray(predict_jit(params, static, ch))
    n = scn.n_agents
    np.testing.assert_allclose(np.asarray(predict_jit(params, static, ch, jnp.zeros(n))), base, rtol=2e-5)
    one_bin_later = np.asarray(predict_jit(params, static, ch, jnp.full(n, 300.0)))
    np.testing.assert_allclose(one_bin_later, base, rtol=2e-5)
    rng = np.random.default_rng(5)
    shift = jnp.asarray(rng.integers(0, 301, n), jnp.float32)
    moved = np.asarray(predict_jit(params, static, ch, shift))
    assert np.abs(moved - base).max() > 1e-3 * base.mean()
    logits = jnp.asarray(rng.normal(size=(n, scn.k)).astype(np.float32))
    g = jax.grad(lambda lg: predict(params, static, jax.nn.softmax(lg, -1), shift).sum())(logits)
    assert np.isfinite(np.asarray(g)).all() and np.abs(np.asarray(g)).max() > 0


def test_a_day_with_drivers_at_home_gives_the_others_their_slots_factors(grid_scenario):
    """On a day some drivers stay home (ABSENT), the others move up in SUMO's insertion order: each
    present driver's time is the per-driver model's with the factor of the driver whose scheduled
    slot it now holds; with everyone present it is the per-driver model itself."""
    from urb_jax.city.demand import ABSENT
    from urb_jax.surrogate.departures import slot_agents

    scn = grid_scenario
    static = build_static(scn, SurrogateConfig(chunk=32), max_shift_s=0.0)
    rng = np.random.default_rng(6)
    params = init_params(static)
    params = {**params, "log_agent": jnp.asarray(rng.normal(0, 0.1, scn.n_agents), jnp.float32)}
    n = scn.n_agents
    ch = _choices(scn, 3, seed=7)
    home = rng.random((3, n)) < 0.2
    days = jnp.asarray(np.where(home, ABSENT, ch))
    zero = jnp.zeros(n)
    np.testing.assert_allclose(np.asarray(predict_jit(params, static, jnp.asarray(ch), zero)),
                               np.asarray(predict_jit(params, static, jnp.asarray(ch))), rtol=1e-6)
    got = np.asarray(predict_jit(params, static, days, zero))
    for d in range(3):
        holder = np.asarray(slot_agents(static.departs, zero, jnp.asarray(~home[d])))
        assert (holder[~home[d]] != np.flatnonzero(~home[d])).any()  # someone moved up
        by_driver = {**params, "log_agent": params["log_agent"][holder]}
        want = np.asarray(predict_jit(by_driver, static, days[d]))
        np.testing.assert_allclose(got[d][~home[d]], want[~home[d]], rtol=1e-5)
