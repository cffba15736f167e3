"""A departure-ordered point-queue term on top of the BPR model: `SurrogateConfig(model="queue")`.

Every edge is a bottleneck with a service rate c_e (vehicles per second). The route-level entries
(n, k, j) of edge e are sorted once by their entry time u (the BPR model's static entry time);
the m-th entry of that order sees the weighted count of entries before it,
S_{m-1} = sum_{i<m} X_i (X = 1 for a chosen route, its probability for probabilities), and waits
Newell's exact point-queue delay (cumulative counts, first in first out):

    W_m = max_{i<=m} [ (S_{m-1} - S_{i-1}) / c_e - (u_m - u_i) ]
        = Z_m - min_{i<=m} Z_i,        Z_i = S_{i-1} / c_e - u_i          (>= 0; a segmented cummin)

so an early departure passes free and a later one waits for every vehicle that reached the
bottleneck before it, beyond what the capacity serves. A vehicle's own weight is not in its
S_{m-1}: the delay of an unchosen route is what the vehicle would meet if it switched.

Entry times then absorb the queues met upstream (`passes` > 1): u'_nkj = u_nkj + sum_{i<j} W_nki,
with the order kept from the static entry times, and the delays are recomputed.

Spill-back: an edge's queue in vehicles at m is W_m c_e; beyond the edge's storage (lanes x length
/ jam spacing) the excess blocks the edges that feed it. Each edge takes the largest excess
(seconds of queue beyond storage, W_m - storage_e / c_e, at the rate of the blocked edge) over
the entries of its successors in the same time bin, times a fitted share, as an extra delay for
every vehicle entering it in that bin:

    O_{e,b} = max_{m in e, bin b} X_m relu(W_m - kappa * storage_e / c_e)
    V_{u,b} = beta * max_{e in succ(u)} O_{e,b}
    route queue delay Q_nk = sum_j W_nkj + V_{e_nkj, bin(u_nkj)}

Agent time: T_n = g_n R^BPR_nk + Q_nk + ins q_n + c0 (docs/surrogate.md).
Service rate: c_e = lanes_e x marouter's per-lane capacity x exp(lambda_junction(e) + lambda'_e).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario

JAM_SPACING_M = 7.5  # metres of lane per stored vehicle (SUMO's 5 m car + 2.5 m minGap)


@partial(
    jax.tree_util.register_dataclass,
    data_fields=[
        "q_row", "q_edge", "q_u", "q_first", "q_bin", "q_succ_bin_cell",
        "r_perm", "e_perm", "r_first", "edge_cap_s", "edge_storage", "edge_jclass",
    ],
    meta_fields=["n_rows", "n_edges", "n_bins", "passes", "spill", "cap_start"],
)
@dataclass(frozen=True)
class QueueIndex:
    """The point-queue entries of one scenario, built once in numpy (a pytree)."""

    q_row: jax.Array  # [Q] row n*K+k of each (agent, route, edge) entry, sorted by (edge, u)
    q_edge: jax.Array  # [Q] its edge
    q_u: jax.Array  # [Q] static entry time, s
    q_first: jax.Array  # [Q] bool: first entry of its edge
    q_bin: jax.Array  # [Q] time bin of the entry (for spill-back)
    q_succ_bin_cell: jax.Array  # [S] (edge, bin) cell index of edge-successor pairs (see build)
    r_perm: jax.Array  # [Q] the entries in route order (row, j): position in the (edge, u) order
    e_perm: jax.Array  # [Q] its inverse: the route-order index of each (edge, u)-ordered entry
    r_first: jax.Array  # [Q] bool: first entry of its row, in route order
    edge_cap_s: jax.Array  # [E] marouter capacity, vehicles per second (all lanes)
    edge_storage: jax.Array  # [E] vehicles the edge holds at jam density
    edge_jclass: jax.Array  # [E] downstream junction class
    n_rows: int
    n_edges: int
    n_bins: int
    passes: int
    spill: bool
    cap_start: float  # the service rates' start, a share of marouter's capacity


def _succ_pairs(routes: np.ndarray) -> np.ndarray:
    """[P, 2] (upstream edge, downstream edge) pairs that follow each other on some route."""
    a, b = routes[..., :-1].ravel(), routes[..., 1:].ravel()
    keep = (a >= 0) & (b >= 0)
    return np.unique(np.stack([a[keep], b[keep]], 1), axis=0)


def build_queue_index(scn: Scenario, entry_scale: float, bin_s: float, passes: int,
                      spill: bool, jclass: np.ndarray, cap_start: float = 0.5) -> QueueIndex:
    routes = scn.routes  # [N, K, L]
    N, K, _ = routes.shape
    t0 = (scn.edge_length / scn.edge_speed).astype(np.float64)
    valid = routes >= 0
    t_edge = np.where(valid, t0[np.maximum(routes, 0)], 0.0)
    before = np.cumsum(t_edge, axis=2) - t_edge
    n_i, k_i, j_i = np.nonzero(valid)  # route order: (n, k, j) ascending
    e_i = routes[n_i, k_i, j_i]
    u = scn.agent_depart[n_i] + entry_scale * before[n_i, k_i, j_i]
    row = n_i * K + k_i
    order = np.lexsort((j_i, row, u, e_i))  # (edge, u, row, j)
    pos = np.empty_like(order)
    pos[order] = np.arange(len(order))  # route-order entry -> its position in the (edge, u) order
    e_s = e_i[order]
    first = np.ones(len(order), bool)
    first[1:] = e_s[1:] != e_s[:-1]
    r_first = np.ones(len(row), bool)
    r_first[1:] = row[1:] != row[:-1]
    n_bins = int(np.floor(u.max() / bin_s)) + 2
    q_bin = np.floor(u[order] / bin_s).astype(np.int64)
    pairs = _succ_pairs(routes) if spill else np.zeros((0, 2), np.int64)
    storage = scn.edge_lanes * scn.edge_length / JAM_SPACING_M
    f32 = partial(jnp.asarray, dtype=jnp.float32)
    i32 = partial(jnp.asarray, dtype=jnp.int32)
    return QueueIndex(
        q_row=i32(row[order]), q_edge=i32(e_s), q_u=f32(u[order]), q_first=jnp.asarray(first),
        q_bin=i32(q_bin), q_succ_bin_cell=i32(pairs.reshape(-1, 2)),
        r_perm=i32(pos), e_perm=i32(order), r_first=jnp.asarray(r_first),
        edge_cap_s=f32(np.maximum(scn.edge_capacity.astype(np.float64), 1.0) / 3600.0),
        edge_storage=f32(np.maximum(storage, 1.0)), edge_jclass=i32(jclass),
        n_rows=N * K, n_edges=scn.n_edges, n_bins=n_bins, passes=passes, spill=spill,
        cap_start=float(cap_start),
    )


def init_queue_params(index: QueueIndex, n_jclasses: int) -> dict[str, jax.Array]:
    """Capacity at `cap_start` of marouter's (default half: where no queue forms, capacity has no
    gradient, so start with some), storage scale 1, spill-back share 0.5."""
    return {
        "log_cap_j": jnp.full(n_jclasses, jnp.log(index.cap_start)),
        "log_cap_e": jnp.zeros(index.n_edges),
        "log_spill": jnp.log(jnp.array(0.5)),
        "log_storage": jnp.zeros(()),
    }


def _seg_scan(first: jax.Array, x: jax.Array, op) -> jax.Array:
    """Inclusive scan of `op` along axis 0 restarting where `first` is True (x: [Q, b])."""
    f = jnp.broadcast_to(first[:, None], x.shape)

    def comb(a, b):
        fa, va = a
        fb, vb = b
        return fa | fb, jnp.where(fb, vb, op(va, vb))

    return jax.lax.associative_scan(comb, (f, x), axis=0)[1]


def edge_capacity(params: dict[str, jax.Array], index: QueueIndex) -> jax.Array:
    """[E] service rate, vehicles per second."""
    return index.edge_cap_s * jnp.exp(params["log_cap_j"][index.edge_jclass] + params["log_cap_e"])


def queue_route_delays(params: dict[str, jax.Array], index: QueueIndex, X: jax.Array) -> jax.Array:
    """[rows, b] route weights (batch-last) -> [rows, b] queue delay of every route, s."""
    cap = edge_capacity(params, index)
    inv_c = (1.0 / cap)[index.q_edge][:, None]  # [Q, 1]
    x = X[index.q_row]  # [Q, b] weight of each entry
    S = _seg_scan(index.q_first, x, jnp.add) - x  # weight before each entry on its edge
    u = jnp.broadcast_to(index.q_u[:, None], x.shape)
    W = jnp.zeros_like(x)
    for p in range(index.passes):
        Z = S * inv_c - u
        W = Z - _seg_scan(index.q_first, Z, jnp.minimum)
        if p + 1 == index.passes:
            break
        # queues met upstream delay the entry into later edges (route order, exclusive cumsum)
        w_r = W[index.r_perm]
        up = _seg_scan(index.r_first, w_r, jnp.add) - w_r
        u = index.q_u[:, None] + up[index.e_perm]
    delay = W
    if index.spill:
        kappa = jnp.exp(params["log_storage"])
        # only vehicles there (weight x) fill the storage: an unchosen route's entry adds nothing
        excess = x * jax.nn.relu(W - kappa * (index.edge_storage[index.q_edge] * inv_c[:, 0])[:, None])
        cell = index.q_edge * index.n_bins + index.q_bin
        over = jax.ops.segment_max(excess, cell, index.n_edges * index.n_bins)  # [E*bins, b]
        over = jnp.where(jnp.isfinite(over), over, 0.0)
        up_e, dn_e = index.q_succ_bin_cell[:, 0], index.q_succ_bin_cell[:, 1]
        # every (upstream, downstream) pair, every bin: upstream cell takes the largest excess
        bins = jnp.arange(index.n_bins)
        src = (dn_e[:, None] * index.n_bins + bins[None, :]).ravel()
        dst = (up_e[:, None] * index.n_bins + bins[None, :]).ravel()
        block = jax.ops.segment_max(over[src], dst, index.n_edges * index.n_bins)
        block = jnp.where(jnp.isfinite(block), block, 0.0)
        delay = delay + jnp.exp(params["log_spill"]) * block[cell]
    return jax.ops.segment_sum(delay, index.q_row, index.n_rows)
