"""A time-dependent BPR link-performance model of one URB day, jitted and differentiable.

An agent's travel time is the sum, over the edges of its route, of the time each edge takes at the
moment the agent enters it, plus an insertion delay and an intercept:

    enter time     u_nkj = depart_n + gamma * sum_{i<j} t0_{e_i}           (static, free-flow based)
    flow           x_{e,b} = sum_{n,k,j: e_nkj=e} P_nk * w_b(u_nkj)          (triangular kernel in bins)
    edge time      tau_{e,b} = (t0_e s_e + j_e) * (1 + a_e (x_{e,b} / cap_e)^p)
    route time     R_nk = sum_j sum_b w_b(u_nkj) tau_{e_nkj,b}
    agent time     T_n = g_n sum_k P_nk R_nk + ins * q_n + c0                 (seconds; returned /60)

`g_n` is a per-agent speed factor: SUMO draws each vehicle's speedFactor (N(1, 0.1)) from the
seeded RNG in insertion order, so under URB's fixed seed an agent drives 10% faster or slower
than the limit on every day and every route; the fit recovers it (prior toward 1).

`w_b` splits an entry between the two nearest bin centres (linear interpolation), so flows and
times move continuously with departure time. The jitted day is two sorted segment sums laid out
batch-last ([rows, B]: every gather moves a contiguous batch vector) and a map over batch chunks
that keeps the working set in cache. See docs/surrogate.md for what each term buys, measured.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.surrogate.departures import (
    DepartIndex,
    build_depart_index,
    day_weights,
    reachable_bins,
    slot_agents,
)
from urb_jax.surrogate.queue import QueueIndex, build_queue_index, init_queue_params, queue_route_delays

# Junction classes for the junction/signal delay term (the edge's downstream junction).
JUNCTION_CLASSES = ("traffic_light", "priority", "right_before_left", "other")


@dataclass(frozen=True)
class SurrogateConfig:
    """Static structure of the model: changing it changes the index arrays, not the parameters."""

    bin_s: float = 300.0  # width of a time bin, s
    bpr_power: int = 4  # p in (x/c)^p; an integer so the power is two multiplies
    entry_scale: float = 1.2  # gamma: edge entry times use free-flow times scaled by this
    origin_window_s: float = 60.0  # insertion-load window: same-origin departures in (d - w, d]
    chunk: int = 128  # batch chunk per map step (cache-sized working set)
    interpolate: bool = True  # split each edge entry between the two nearest bins (else: hard bins)
    model: str = "bpr"  # "bpr" (this module alone) or "queue" (plus surrogate/queue.py's point queues)
    queue_passes: int = 2  # queue model: passes that move entry times by the queues met upstream
    queue_spill: bool = True  # queue model: spill-back of queues beyond an edge's storage
    queue_cap_start: float = 0.5  # queue model: service rates start at this share of marouter's capacity


MODELS = ("bpr", "queue")


@partial(
    jax.tree_util.register_dataclass,
    data_fields=[
        "flow_row", "flow_cell", "flow_w", "time_row", "time_cell", "time_w",
        "cell_edge", "cell_cap", "edge_t0", "edge_class", "edge_jclass", "origin_load", "queue", "departs",
    ],
    meta_fields=["n", "k", "n_cells", "n_edges", "n_classes", "power", "chunk"],
)
@dataclass(frozen=True)
class Static:
    """Index arrays of one scenario (built once in numpy); a pytree, so `predict` can be jitted."""

    flow_row: jax.Array  # [M] row n*K+k of each (agent, route, edge, bin) entry, sorted by cell
    flow_cell: jax.Array  # [M]
    flow_w: jax.Array  # [M] interpolation weight
    time_row: jax.Array  # [M] the same entries sorted by row
    time_cell: jax.Array
    time_w: jax.Array
    cell_edge: jax.Array  # [C] edge of each (edge, bin) cell
    cell_cap: jax.Array  # [C] capacity of the cell's edge, vehicles per bin
    edge_t0: jax.Array  # [E] length / speed limit, s
    edge_class: jax.Array  # [E] road class (edge type) index
    edge_jclass: jax.Array  # [E] downstream junction class index
    origin_load: jax.Array  # [N] same-origin-edge departures within the insertion window
    n: int
    k: int
    n_cells: int
    n_edges: int
    n_classes: int
    power: int
    chunk: int
    queue: QueueIndex | None = None  # the queue model's entries (None: the BPR model)
    departs: DepartIndex | None = None  # the entries again for days whose departures move (None: never)


class DayWeights(NamedTuple):
    """A day's entry weights in cell order [M] and in row order [M], and each agent's insertion
    load [N]: the scheduled ones, or those of a day whose departures move (the rest is static)."""

    flow_w: jax.Array
    time_w: jax.Array
    origin_load: jax.Array


def weights_on(static: Static, shift: jax.Array | None) -> DayWeights:
    """The scheduled day's weights (`shift` None), or those of a day whose drivers leave `shift` [N]
    seconds off their schedule (surrogate/departures.py)."""
    if shift is None:
        return DayWeights(static.flow_w, static.time_w, static.origin_load)
    if static.departs is None:
        raise ValueError("this surrogate was built for scheduled departures only: build it with "
                         "build_static(..., max_shift_s=J) to predict days whose departures move")
    if static.queue is not None:
        raise ValueError("the queue model places its entries from the scheduled departures: days whose "
                         "departures move need surrogate_model 'bpr'")
    if not static.departs.moves:  # only the insertion slots vary (demand): the built weights hold
        return DayWeights(static.flow_w, static.time_w, static.origin_load)
    return DayWeights(*day_weights(static.departs, shift))


def junction_types(net_file: str, edge_ids: tuple[str, ...]) -> list[str]:
    """Type of each edge's downstream junction (traffic_light, priority, ...) read from the net.xml."""
    to_node: dict[str, str] = {}
    jtype: dict[str, str] = {}
    for _, elem in ET.iterparse(net_file, events=("end",)):
        if elem.tag == "edge":
            eid = elem.get("id", "")
            if not eid.startswith(":"):
                to_node[eid] = elem.get("to", "")
            elem.clear()
        elif elem.tag == "junction":
            jtype[elem.get("id", "")] = elem.get("type", "")
            elem.clear()
    out = []
    for e in edge_ids:
        t = jtype.get(to_node.get(e, ""), "")
        if t.startswith("traffic_light"):
            t = "traffic_light"
        out.append(t if t in JUNCTION_CLASSES else "other")
    return out


def edge_classes(scn: Scenario) -> tuple[np.ndarray, tuple[str, ...]]:
    """Road class index per edge (by SUMO edge type) and the class names."""
    names = tuple(sorted(set(scn.edge_type)))
    lookup = {t: i for i, t in enumerate(names)}
    return np.array([lookup[t] for t in scn.edge_type], dtype=np.int32), names


def _origin_load(scn: Scenario, window: float) -> np.ndarray:
    """For each agent: agents leaving the same origin edge in (depart - window, depart], itself included."""
    load = np.zeros(scn.n_agents, dtype=np.float32)
    dep = scn.agent_depart.astype(np.float64)
    origin = scn.od_routes[scn.agent_od, 0, 0]
    for o in np.unique(origin):
        idx = np.flatnonzero(origin == o)
        d = np.sort(dep[idx])
        lo = np.searchsorted(d, dep[idx] - window, side="right")
        hi = np.searchsorted(d, dep[idx], side="right")
        load[idx] = hi - lo
    return load


def _scheduled_entries(row: np.ndarray, edge: np.ndarray, enter: np.ndarray, config: SurrogateConfig
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(row, edge, bin, weight) of the (route entry, bin) pairs with a weight, entering at `enter` s:
    split between the two nearest bin centres, or whole in its bin (`config.interpolate`)."""
    u = enter / config.bin_s - 0.5  # position relative to bin centres
    b0 = np.floor(u).astype(np.int64)
    f = u - b0
    if not config.interpolate:
        b0, f = np.floor(enter / config.bin_s).astype(np.int64), np.zeros_like(u)
    rows, edges = np.concatenate([row, row]), np.concatenate([edge, edge])
    b = np.concatenate([b0, b0 + 1]) + 1  # >= 0
    w = np.concatenate([1.0 - f, f])
    keep = w > 0
    return rows[keep], edges[keep], b[keep], w[keep]


def build_static(scn: Scenario, config: SurrogateConfig = SurrogateConfig(),
                 max_shift_s: float | None = None, is_cav: np.ndarray | None = None) -> Static:
    """Precompute the (agent, route, edge, bin) entries, the compact cells and the edge features;
    `max_shift_s` set: an entry in every bin it reaches when its driver leaves up to that many
    seconds off schedule (zero-weighted when scheduled), for `predict(..., shift=)`; `is_cav` [N]
    (None: none) orders their insertion slots as SUMO's (surrogate/departures.py)."""
    if config.model not in MODELS:
        raise ValueError(f"surrogate model {config.model!r} is not one of {', '.join(MODELS)}")
    routes = scn.routes  # [N, K, L]
    N, K, _ = routes.shape
    t0 = (scn.edge_length / scn.edge_speed).astype(np.float64)
    valid = routes >= 0
    t_edge = np.where(valid, t0[np.maximum(routes, 0)], 0.0)
    before = np.cumsum(t_edge, axis=2) - t_edge  # free-flow time before entering edge j
    n_i, k_i, j_i = np.nonzero(valid)
    e_i = routes[n_i, k_i, j_i]
    enter = scn.agent_depart[n_i] + config.entry_scale * before[n_i, k_i, j_i]
    if max_shift_s is None:
        row, edge, b, w = _scheduled_entries(n_i * K + k_i, e_i, enter, config)
    else:  # departures that move: every bin an entry can reach
        entry, b = reachable_bins(enter, config.bin_s, config.interpolate, max_shift_s)
        row, edge, agent = (n_i * K + k_i)[entry], e_i[entry], n_i[entry]
        pos = enter[entry] / config.bin_s - b  # scheduled position relative to the bin (departures.py)
        w = (np.maximum(1.0 - np.abs(pos + 0.5), 0.0) if config.interpolate
             else ((pos >= -1.0) & (pos < 0.0)).astype(np.float64))
    n_bins = int(b.max()) + 1
    uniq, cell = np.unique(edge * n_bins + b, return_inverse=True)
    cell_edge = (uniq // n_bins).astype(np.int32)
    by_cell = np.lexsort((row, cell))
    by_row = np.lexsort((cell, row))
    cls, _ = edge_classes(scn)
    jnames = junction_types(scn.net_file, scn.edge_ids)
    jcls = np.array([JUNCTION_CLASSES.index(t) for t in jnames], dtype=np.int32)
    cap = scn.edge_capacity.astype(np.float64) * config.bin_s / 3600.0
    f32 = partial(jnp.asarray, dtype=jnp.float32)
    i32 = partial(jnp.asarray, dtype=jnp.int32)
    return Static(
        flow_row=i32(row[by_cell]), flow_cell=i32(cell[by_cell]), flow_w=f32(w[by_cell]),
        time_row=i32(row[by_row]), time_cell=i32(cell[by_row]), time_w=f32(w[by_row]),
        cell_edge=i32(cell_edge), cell_cap=f32(cap[cell_edge]), edge_t0=f32(t0),
        edge_class=i32(cls), edge_jclass=i32(jcls),
        origin_load=f32(_origin_load(scn, config.origin_window_s)),
        n=N, k=K, n_cells=len(uniq), n_edges=scn.n_edges, n_classes=int(cls.max()) + 1,
        power=config.bpr_power, chunk=config.chunk,
        queue=(build_queue_index(scn, config.entry_scale, config.bin_s, config.queue_passes,
                                 config.queue_spill, jcls, config.queue_cap_start)
               if config.model == "queue" else None),
        departs=(None if max_shift_s is None else build_depart_index(
            scn, agent[by_cell], pos[by_cell], agent[by_row], pos[by_row], config, is_cav, max_shift_s > 0)),
    )


def init_params(static: Static) -> dict[str, jax.Array]:
    """Uncalibrated parameters: textbook BPR (a=0.15) with a small junction delay per junction class.

    Positive quantities are stored as logs; `*_e` are per-edge deviations from the class value
    (regularised toward 0 during calibration).
    """
    nc, ne, nj = static.n_classes, static.n_edges, len(JUNCTION_CLASSES)
    if static.queue is not None:
        return {**init_params(replace(static, queue=None)), **init_queue_params(static.queue, nj)}
    return {
        "log_speed_c": jnp.zeros(nc),  # multiplier on free-flow time
        "log_speed_e": jnp.zeros(ne),
        "log_a_c": jnp.full(nc, jnp.log(0.15)),
        "log_a_e": jnp.zeros(ne),
        "log_junc_j": jnp.log(jnp.array([8.0, 2.0, 4.0, 2.0])[:nj]),  # s per traversal
        "log_junc_e": jnp.zeros(ne),
        "log_agent": jnp.zeros(static.n),  # per-agent speed factor g_n (seeded SUMO speedFactor)
        "log_ins": jnp.log(jnp.array(1.0)),  # s per same-origin departure in the window
        "intercept": jnp.array(1.0),  # s (URB's +1 s step offset, start-up acceleration)
    }


def edge_terms(params: dict[str, jax.Array], static: Static) -> tuple[jax.Array, jax.Array]:
    """Per-edge base time t0*s + j (s) and BPR coefficient a."""
    cls, jc = static.edge_class, static.edge_jclass
    speed = jnp.exp(params["log_speed_c"][cls] + params["log_speed_e"])
    junc = jnp.exp(params["log_junc_j"][jc] + params["log_junc_e"])
    a = jnp.exp(params["log_a_c"][cls] + params["log_a_e"])
    return static.edge_t0 * speed + junc, a


def _route_times(X: jax.Array, base_c: jax.Array, a_c: jax.Array, w: DayWeights, static: Static) -> jax.Array:
    """[N*K, b] route weights -> [N*K, b] route times (s), both batch-last."""
    F = jax.ops.segment_sum(
        w.flow_w[:, None] * X[static.flow_row], static.flow_cell, static.n_cells,
        indices_are_sorted=True,
    )
    r = F / static.cell_cap[:, None]
    tau = base_c[:, None] * (1.0 + a_c[:, None] * jax.lax.integer_pow(r, static.power))
    return jax.ops.segment_sum(
        w.time_w[:, None] * tau[static.time_cell], static.time_row, static.n * static.k,
        indices_are_sorted=True,
    )


def _day_chunk(chunk_in: jax.Array, base_c, a_c, w: DayWeights, static: Static) -> jax.Array:
    """One batch chunk, batch-last: int [N, b] choices or [N, K, b] probabilities -> [N, b] seconds."""
    N, K = static.n, static.k
    if chunk_in.ndim == 2:  # route indices
        X = (chunk_in[:, None, :] == jnp.arange(K, dtype=chunk_in.dtype)[None, :, None])
        X = X.astype(jnp.float32).reshape(N * K, -1)
        R = _route_times(X, base_c, a_c, w, static).reshape(N, K, -1)
        return jnp.take_along_axis(R, chunk_in[:, None, :], axis=1)[:, 0]
    X = chunk_in.reshape(N * K, -1)
    R = _route_times(X, base_c, a_c, w, static).reshape(N, K, -1)
    return (chunk_in * R).sum(axis=1)


def _queue_day_chunk(chunk_in: jax.Array, base_c, a_c, g: jax.Array, params, static: Static) -> jax.Array:
    """`_day_chunk` of the queue model: g_n R^BPR + the route's queue delay, [N, b] seconds."""
    assert static.queue is not None
    N, K = static.n, static.k
    if chunk_in.ndim == 2:
        X = (chunk_in[:, None, :] == jnp.arange(K, dtype=chunk_in.dtype)[None, :, None])
        X = X.astype(jnp.float32).reshape(N * K, -1)
    else:
        X = chunk_in.reshape(N * K, -1)
    R = _route_times(X, base_c, a_c, weights_on(static, None), static) * jnp.repeat(g, K)[:, None]
    R = (R + queue_route_delays(params, static.queue, X)).reshape(N, K, -1)
    if chunk_in.ndim == 2:
        return jnp.take_along_axis(R, chunk_in[:, None, :], axis=1)[:, 0]
    return (chunk_in * R).sum(axis=1)


def route_times_seconds(params, static: Static, probs: jax.Array) -> jax.Array:
    """[B, N, K] probabilities -> [B, N, K] time of every route given the flows (s, no insertion)."""
    base, a = edge_terms(params, static)
    X = jnp.moveaxis(probs, 0, -1).reshape(static.n * static.k, -1)
    R = _route_times(X, base[static.cell_edge], a[static.cell_edge], weights_on(static, None), static)
    if static.queue is not None:
        R = R * jnp.exp(params["log_agent"])[:, None] + queue_route_delays(params, static.queue, X)
        return jnp.moveaxis(R.reshape(static.n, static.k, -1), -1, 0)
    R = R.reshape(static.n, static.k, -1) * jnp.exp(params["log_agent"])[:, None, None]
    return jnp.moveaxis(R, -1, 0)


def predict(params: dict[str, jax.Array], static: Static, choices: jax.Array,
            shift: jax.Array | None = None) -> jax.Array:
    """Travel times in minutes, [B, N], for choices [B, N] (route index) or [B, N, K] (probabilities).

    A leading batch axis is optional ([N] or [N, K] give [N]). Probabilities give each agent's
    expected time under flows weighted by everyone's probabilities (differentiable). `shift` [N]:
    the days' drivers leave that many seconds off their schedule (the same for the whole batch;
    needs `build_static(..., max_shift_s=)`).
    """
    is_prob = jnp.issubdtype(choices.dtype, jnp.floating)
    single = choices.ndim == (2 if is_prob else 1)
    if single:
        choices = choices[None]
    given = choices
    B = choices.shape[0]
    base, a = edge_terms(params, static)
    w = weights_on(static, shift)
    base_c, a_c = base[static.cell_edge], a[static.cell_edge]
    x = jnp.moveaxis(choices, 0, -1)  # batch last
    if not is_prob:
        x = x.astype(jnp.int32)
    size = static.chunk

    def day_chunk(c: jax.Array) -> jax.Array:
        if static.queue is None:
            return _day_chunk(c, base_c, a_c, w, static)
        return _queue_day_chunk(c, base_c, a_c, jnp.exp(params["log_agent"]), params, static)

    if size >= B:
        sec = day_chunk(x)
    else:
        n_chunks = -(-B // size)
        pad = n_chunks * size - B
        if pad:
            x = jnp.concatenate([x, jnp.zeros((*x.shape[:-1], pad), x.dtype)], axis=-1)
        xs = jnp.moveaxis(x.reshape((*x.shape[:-1], n_chunks, size)), -2, 0)
        out = jax.lax.map(day_chunk, xs)  # [n_chunks, N, size]
        sec = jnp.moveaxis(out, 0, 1).reshape(static.n, -1)[:, :B]
    ins = jnp.exp(params["log_ins"]) * w.origin_load[:, None]
    if static.queue is None:
        g = jnp.exp(params["log_agent"])  # [N]
        if shift is not None:  # a moved day: each driver drives at its insertion slot's factor
            assert static.departs is not None  # weights_on refused otherwise
            present = None if is_prob else jnp.moveaxis(choices, 0, -1) >= 0  # [N, B] (ABSENT: -1)
            g = g[slot_agents(static.departs, shift, present)]  # [N] or [N, B]
        sec = sec * (g[:, None] if g.ndim == 1 else g) + ins + params["intercept"]
    else:  # the per-agent factor is already on the BPR part only
        sec = sec + ins + params["intercept"]
    out = sec.T / 60.0
    if "route_bias" in params:  # [N, K] minutes: SUMO's residual on routes it has seen (route_bias())
        bias = params["route_bias"]
        if is_prob:
            out = out + (given * bias[None]).sum(-1)
        else:
            out = out + jnp.take_along_axis(bias[None], given.astype(jnp.int32)[..., None], axis=-1)[..., 0]
    return out[0] if single else out


predict_jit = jax.jit(predict)


def predict_days(params: dict[str, jax.Array], static: Static, choices: jax.Array,
                 shift: jax.Array | None = None) -> jax.Array:
    """Minutes [D, N] of D days of choices [D, N] (or [D, N, K]); `shift` [D, N]: each day's own
    departure shifts (days whose departures move), None: every day as scheduled (one batch)."""
    if shift is None:
        return predict(params, static, choices)
    return jax.vmap(lambda c, s: predict(params, static, c, s))(choices, shift)


predict_days_jit = jax.jit(predict_days)

MIN_BUCKET = 8


def bucket_size(n: int) -> int:
    """The smallest power of two >= n (at least MIN_BUCKET): an array that grows by a few rows
    every round is fed to a jitted function at this size, so it compiles once per doubling."""
    return max(MIN_BUCKET, 1 << max(n - 1, 0).bit_length())


def predict_bucketed(params: dict[str, jax.Array], static: Static, choices: np.ndarray,
                     shift: np.ndarray | None = None) -> np.ndarray:
    """`predict_days_jit` of D days of route indices [D, N] (each day's departure shifts [D, N], or
    None) -> minutes [D, N], run at D padded to `bucket_size(D)` (route-0 days, dropped): the
    trainer's growing set of SUMO days does not recompile it every round. Days are independent; the
    padded width changes XLA's vectorised loops, so a day's times can differ from an unpadded call's
    in the last bit (~1e-7 min)."""
    d = choices.shape[0]
    padded = np.zeros((bucket_size(d), static.n), np.int32)  # [B, N]
    padded[:d] = choices
    if shift is None:
        return np.asarray(predict_jit(params, static, jnp.asarray(padded)))[:d]
    shifts = np.zeros(padded.shape, np.float32)
    shifts[:d] = shift
    return np.asarray(predict_days_jit(params, static, jnp.asarray(padded), jnp.asarray(shifts)))[:d]
