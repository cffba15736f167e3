"""The queue model (SurrogateConfig(model="queue")): hand-computed bottleneck delays, tandem queues,
spill-back, probabilities, vmap and gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from urb_jax.city.routes import RouteParams
from urb_jax.city.scenario import Scenario
from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict, predict_jit

OFF = -40.0  # log of a term switched off


def _scenario(tmp_path, routes, depart, length, capacity_vph) -> Scenario:
    """One OD pair, every agent on it; `routes` [K, L] edge indices (-1 padded)."""
    n_e = len(length)
    net = tmp_path / "q.net.xml"
    edges = "".join(f'<edge id="e{i}" from="a{i}" to="b{i}"/>' for i in range(n_e))
    net.write_text(f"<net>{edges}</net>")
    routes = np.asarray(routes, np.int32)[None]
    k = routes.shape[1]
    n = len(depart)
    return Scenario(
        name="q", net_file=str(net), env_seed=0, route_params=RouteParams(),
        edge_ids=tuple(f"e{i}" for i in range(n_e)), edge_length=np.asarray(length, float),
        edge_speed=np.full(n_e, 10.0), edge_lanes=np.ones(n_e, int), edge_priority=np.ones(n_e, int),
        edge_type=("t",) * n_e, edge_capacity=np.asarray(capacity_vph, float),
        od_origin=np.array([0]), od_destination=np.array([0]), od_origin_edge=("e0",),
        od_destination_edge=("e1",), od_routes=routes, od_route_len=(routes >= 0).sum(-1),
        od_route_valid=np.ones((1, k), bool), od_fft=np.zeros((1, k)), od_fft_full=np.zeros((1, k)),
        od_route_length=np.zeros((1, k)), agent_id=np.arange(n), agent_od=np.zeros(n, int),
        agent_origin=np.zeros(n, int), agent_destination=np.zeros(n, int),
        agent_depart=np.asarray(depart), agent_kind=("Human",) * n,
    )


def _free_flow_params(static, spill=0.5, storage=1.0):
    """BPR part = free-flow time exactly: no BPR term, junction delay, insertion or intercept."""
    p = init_params(static)
    return {**p, "log_a_c": jnp.full_like(p["log_a_c"], OFF), "log_junc_j": jnp.full(4, OFF),
            "log_ins": jnp.array(OFF), "intercept": jnp.array(0.0), "log_cap_j": jnp.zeros(4),
            "log_spill": jnp.log(jnp.array(spill)), "log_storage": jnp.log(jnp.array(storage))}


def test_single_bottleneck_kth_vehicle_delay(tmp_path):
    """One edge, 10 s free flow, capacity 360 veh/h = one vehicle per 10 s; departures 0, 1, 2, 3, 30.
    Served at 0, 10, 20, 30, 40: delays 0, 9, 18, 27 and 10 (the fifth meets the rest of the queue)."""
    scn = _scenario(tmp_path, [[0], [0]], [0, 1, 2, 3, 30], [100.0], [360.0])
    static = build_static(scn, SurrogateConfig(model="queue", entry_scale=1.0, queue_passes=1,
                                               queue_spill=False))
    params = _free_flow_params(static)
    out = np.asarray(predict_jit(params, static, jnp.zeros((1, 5), jnp.int32)))[0] * 60
    np.testing.assert_allclose(out, 10.0 + np.array([0, 9, 18, 27, 10]), atol=1e-3)
    # an unchosen route's delay is what the agent would meet: the same edge here, so the same
    alone = np.asarray(predict_jit(params, static, jnp.array([[1, 1, 1, 1, 1]], jnp.int32)))[0] * 60
    np.testing.assert_allclose(alone, out, atol=1e-3)
    # half the capacity doubles every delay
    slow = {**params, "log_cap_j": params["log_cap_j"] + jnp.log(0.5)}
    out2 = np.asarray(predict_jit(slow, static, jnp.zeros((1, 5), jnp.int32)))[0] * 60
    np.testing.assert_allclose(out2, 10.0 + np.array([0, 19, 38, 57, 50]), atol=1e-3)


def test_tandem_queues_second_pass_is_exact(tmp_path):
    """e0 (10 s, one per 10 s) then e1 (10 s, one per 20 s). One pass uses free-flow entry times
    into e1 (10, 11, 12, 13, 40); the second moves them by e0's queue (10, 20, 30, 40, 50), and
    e1 then serves at 10, 30, 50, 70, 90: delays 0, 10, 20, 30, 40, as a tandem point queue."""
    scn = _scenario(tmp_path, [[0, 1]], [0, 1, 2, 3, 30], [100.0, 100.0], [360.0, 180.0])
    q0 = np.array([0, 9, 18, 27, 10])
    for passes, q1 in ((1, [0, 19, 38, 57, 50]), (2, [0, 10, 20, 30, 40])):
        static = build_static(scn, SurrogateConfig(model="queue", entry_scale=1.0, queue_passes=passes,
                                                   queue_spill=False))
        out = np.asarray(predict_jit(_free_flow_params(static), static, jnp.zeros((1, 5), jnp.int32)))
        np.testing.assert_allclose(out[0] * 60, 20.0 + q0 + np.array(q1), atol=1e-3)


def test_spill_back_blocks_the_upstream_edge(tmp_path):
    """e0 (10 s, 1 veh/s) feeds e1 (1.5 s, one per 10 s, stores 2 vehicles) and e2 (10 s).
    Departures 0..3 to e1, 4 to e2: e1's queue delays 0, 9, 18, 27 s; storage covers 2 / 0.1 = 20 s,
    so the excess is 7 s and every vehicle entering e0 in that bin waits spill x 7 = 3.5 s more,
    the one bound for e2 included."""
    scn = _scenario(tmp_path, [[0, 1], [0, 2]], [0, 1, 2, 3, 4], [100.0, 15.0, 100.0],
                    [3600.0, 360.0, 3600.0])
    static = build_static(scn, SurrogateConfig(model="queue", entry_scale=1.0, queue_passes=1))
    params = _free_flow_params(static, spill=0.5)
    out = np.asarray(predict_jit(params, static, jnp.array([[0, 0, 0, 0, 1]], jnp.int32)))[0] * 60
    np.testing.assert_allclose(out, [11.5 + 3.5, 20.5 + 3.5, 29.5 + 3.5, 38.5 + 3.5, 20.0 + 3.5],
                               atol=1e-3)
    # twice the storage covers the queue: no spill-back
    roomy = {**params, "log_storage": jnp.log(jnp.array(2.0))}
    out = np.asarray(predict_jit(roomy, static, jnp.array([[0, 0, 0, 0, 1]], jnp.int32)))[0] * 60
    np.testing.assert_allclose(out, [11.5, 20.5, 29.5, 38.5, 20.0], atol=1e-3)


@pytest.fixture(scope="module")
def grid_queue(grid_scenario):
    static = build_static(grid_scenario, SurrogateConfig(model="queue", chunk=32))
    params = init_params(static)
    params = {**params, "log_cap_j": params["log_cap_j"] - 2.0}  # queues on the grid
    return grid_scenario, static, params


def test_queue_model_batches_vmaps_and_matches_probabilities(grid_queue):
    scn, static, params = grid_queue
    ch = np.random.default_rng(0).integers(0, scn.k, (40, scn.n_agents)).astype(np.int32)
    batch = np.asarray(predict_jit(params, static, jnp.asarray(ch)))  # 40 > chunk: mapped chunks
    assert np.isfinite(batch).all() and (batch > 0).all()
    vm = np.asarray(jax.jit(jax.vmap(lambda c: predict(params, static, c)))(jnp.asarray(ch[:3])))
    np.testing.assert_allclose(vm, batch[:3], rtol=1e-5)
    probs = np.eye(scn.k, dtype=np.float32)[ch[:3]]
    np.testing.assert_allclose(np.asarray(predict_jit(params, static, jnp.asarray(probs))), batch[:3],
                               rtol=1e-5)
    # the queues matter here: the queue model is slower than its BPR part alone
    bpr = np.asarray(predict_jit({**params, "log_cap_j": params["log_cap_j"] + 20.0}, static,
                                 jnp.asarray(ch[:3])))
    assert (batch[:3] >= bpr - 1e-4).all() and batch[:3].mean() > bpr.mean() * 1.01


def test_queue_model_gradients_are_finite_and_match_finite_differences(grid_queue):
    scn, static, params = grid_queue
    logits = jnp.asarray(np.random.default_rng(3).normal(size=(scn.n_agents, scn.k)).astype(np.float32))

    def total(lg, cap_shift):
        p = {**params, "log_cap_j": params["log_cap_j"] + cap_shift}
        return predict(p, static, jax.nn.softmax(lg, axis=-1)).sum()

    g_lg, g_cap = jax.grad(total, argnums=(0, 1))(logits, 0.0)
    assert np.isfinite(np.asarray(g_lg)).all() and float(g_cap) < 0  # more capacity, shorter days
    f = jax.jit(total)
    v = jnp.asarray(np.random.default_rng(4).normal(size=logits.shape).astype(np.float32))
    fd = (f(logits + 1e-2 * v, 0.0) - f(logits - 1e-2 * v, 0.0)) / 2e-2
    an = float((g_lg * v).sum())
    assert abs(float(fd) - an) <= 5e-2 * abs(an) + 1e-2, (float(fd), an)
    fd_cap = (f(logits, 1e-2) - f(logits, -1e-2)) / 2e-2
    assert abs(float(fd_cap) - float(g_cap)) <= 5e-2 * abs(float(g_cap)) + 1e-2


def test_unknown_model_is_refused(grid_scenario):
    with pytest.raises(ValueError, match="queue"):
        build_static(grid_scenario, SurrogateConfig(model="ctm"))


def test_hybrid_config_key_selects_the_model():
    from urb_jax.core.errors import ConfigError
    from urb_jax.training.hybrid.plan import HybridConfig

    assert HybridConfig().surrogate_config.model == "bpr"
    assert HybridConfig(surrogate_model="queue").surrogate_config.model == "queue"
    with pytest.raises(ConfigError, match="surrogate_model"):
        HybridConfig(surrogate_model="ctm")


def test_bpr_static_and_params_carry_no_queue(grid_scenario):
    static = build_static(grid_scenario)
    assert static.queue is None
    assert not {"log_cap_j", "log_cap_e", "log_spill", "log_storage"} & set(init_params(static))


def test_the_service_rates_start_at_the_configured_share_of_capacity(tmp_path):
    """Uncalibrated, the single bottleneck above serves at cap_start x 360 veh/h: at nominal capacity
    (1.0) the hand-computed delays; at half (the default start) a vehicle every 20 s."""
    from urb_jax.surrogate.queue import edge_capacity

    scn = _scenario(tmp_path, [[0], [0]], [0, 1, 2, 3, 30], [100.0], [360.0])
    for share, delays in ((1.0, [0, 9, 18, 27, 10]), (0.5, [0, 19, 38, 57, 50])):
        static = build_static(scn, SurrogateConfig(model="queue", entry_scale=1.0, queue_passes=1,
                                                   queue_spill=False, queue_cap_start=share))
        start = init_params(static)
        np.testing.assert_allclose(np.asarray(edge_capacity(start, static.queue)), [share * 0.1], rtol=1e-6)
        params = {**_free_flow_params(static), "log_cap_j": start["log_cap_j"]}
        out = np.asarray(predict_jit(params, static, jnp.zeros((1, 5), jnp.int32)))[0] * 60
        np.testing.assert_allclose(out, 10.0 + np.array(delays), atol=1e-3)
