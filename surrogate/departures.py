"""The model's day when departures move day to day (the task's `day_departure_jitter_s`).

The BPR model places each (agent, route, edge) entry in its time bins once, in numpy, from the
scheduled departures (`build_static`). When a driver leaves `shift_n` seconds off its schedule, every
entry of its routes moves by the same amount:

    u_nkj = depart_n + shift_n + gamma * sum_{i<j} t0_{e_i}

so the bins an entry falls in, and the insertion load (same-origin departures in (d - w, d]), are
functions of the day's shifts. This index keeps the entries without their bins; `day_cells` bins
them in the program for one day's shifts [N]: fixed shapes (every edge has a cell in every bin that
the largest shift can reach), so one compiled day serves every day of a run, and the model stays
jittable, vmappable and differentiable in the choices. With zero shifts it is the scheduled model:
the same entries, weights and cells (up to float32 rounding of the bin positions).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario


@partial(
    jax.tree_util.register_dataclass,
    data_fields=["row", "agent", "edge", "lead", "depart", "edge_cap", "pair_agent", "pair_other"],
    meta_fields=["n_bins", "n_edges", "bin_s", "interpolate", "origin_window_s"],
)
@dataclass(frozen=True)
class DepartIndex:
    """One scenario's route entries without their bins (built once in numpy; a pytree)."""

    row: jax.Array  # [M] row n*K+k of each (agent, route, edge) entry, sorted
    agent: jax.Array  # [M] its agent n
    edge: jax.Array  # [M] its edge
    lead: jax.Array  # [M] gamma x free-flow seconds before the entry (from the departure)
    depart: jax.Array  # [N] scheduled departures, s
    edge_cap: jax.Array  # [E] capacity, vehicles per bin
    pair_agent: jax.Array  # [Q] same-origin pairs (n, m), n's own pair included: n's insertion
    pair_other: jax.Array  # [Q]     load counts m when m leaves in (d_n - w, d_n]
    n_bins: int  # bins per edge: every entry of a day with shifts <= the index's bound falls in them
    n_edges: int
    bin_s: float
    interpolate: bool
    origin_window_s: float

    @property
    def n_cells(self) -> int:
        return self.n_edges * self.n_bins


def build_depart_index(scn: Scenario, entry_scale: float, bin_s: float, interpolate: bool,
                       origin_window_s: float, max_shift_s: float) -> DepartIndex:
    """The entries of `scn`'s routes, for days whose departures move by at most `max_shift_s` later
    than scheduled (an entry beyond the last bin is counted in it)."""
    routes = scn.routes  # [N, K, L]
    _, K, _ = routes.shape
    t0 = (scn.edge_length / scn.edge_speed).astype(np.float64)
    valid = routes >= 0
    t_edge = np.where(valid, t0[np.maximum(routes, 0)], 0.0)
    before = np.cumsum(t_edge, axis=2) - t_edge  # [N, K, L] free-flow time before entering edge j
    n_i, k_i, j_i = np.nonzero(valid)  # row-major: sorted by n*K+k
    lead = entry_scale * before[n_i, k_i, j_i]
    latest = float(scn.agent_depart.max()) + max_shift_s + float(lead.max(initial=0.0))
    n_bins = int(np.floor(latest / bin_s + 0.5)) + 3  # the static model's b0 + 2, plus one spare
    origin = scn.od_routes[scn.agent_od, 0, 0]
    groups = [np.flatnonzero(origin == o) for o in np.unique(origin)]
    pair = np.concatenate([np.stack([np.repeat(g, g.size), np.tile(g, g.size)], axis=1) for g in groups])
    i32 = partial(jnp.asarray, dtype=jnp.int32)
    return DepartIndex(
        row=i32(n_i * K + k_i), agent=i32(n_i), edge=i32(routes[n_i, k_i, j_i]),
        lead=jnp.asarray(lead, jnp.float32), depart=jnp.asarray(scn.agent_depart, jnp.float32),
        edge_cap=jnp.asarray(scn.edge_capacity.astype(np.float64) * bin_s / 3600.0, jnp.float32),
        pair_agent=i32(pair[:, 0]), pair_other=i32(pair[:, 1]),
        n_bins=n_bins, n_edges=scn.n_edges, bin_s=float(bin_s), interpolate=bool(interpolate),
        origin_window_s=float(origin_window_s),
    )


def day_cells(index: DepartIndex, shift: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """For a day whose drivers leave `shift` [N] seconds off their schedule: (row [2M], cell [2M],
    weight [2M], origin load [N]); cell c is edge c // n_bins. Each entry is split between the two
    nearest bin centres (or put whole in its bin), as the scheduled model splits it; rows stay sorted."""
    depart = index.depart + shift  # [N]
    enter = depart[index.agent] + index.lead  # [M]
    if index.interpolate:
        u = enter / index.bin_s - 0.5
        b0 = jnp.floor(u)
        f = u - b0
        b0 = b0.astype(jnp.int32) + 1
    else:
        b0 = jnp.floor(enter / index.bin_s).astype(jnp.int32) + 1
        f = jnp.zeros_like(enter)
    bins = jnp.clip(jnp.stack([b0, b0 + 1], axis=1), 0, index.n_bins - 1)  # [M, 2]
    cell = (index.edge[:, None] * index.n_bins + bins).reshape(-1)
    weight = jnp.stack([1.0 - f, f], axis=1).reshape(-1)
    row = jnp.repeat(index.row, 2)
    d_n, d_m = depart[index.pair_agent], depart[index.pair_other]
    within = (d_m > d_n - index.origin_window_s) & (d_m <= d_n)
    load = jax.ops.segment_sum(within.astype(jnp.float32), index.pair_agent, depart.shape[0])
    return row, cell, weight, load
