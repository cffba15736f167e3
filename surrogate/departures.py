"""The model's day when departures move day to day (the task's `day_departure_jitter_s`).

The BPR model places each (agent, route, edge) entry in its time bins once, in numpy, from the
scheduled departures (`build_static`). When a driver leaves `shift_n` seconds off its schedule, every
entry of its routes moves by the same amount:

    u_nkj = depart_n + shift_n + gamma * sum_{i<j} t0_{e_i}

so the bins an entry falls in, their weights and the insertion load (same-origin departures in
(d - w, d]) are functions of the day's shifts. An entry moved by at most `max_shift_s` can only
reach a few bins (4 at +-300 s in 300-s bins, against 2 when scheduled): this index lists every
(entry, reachable bin) pair once, sorted by cell and by row as the scheduled index is, and only
their weights are computed in the program (`day_weights`), the triangular kernel of the shifted
position. The layout stays batch-last with static, sorted indices, so a batch of days whose shifts
differ (the training envs, vmapped) costs about twice a scheduled batch, not a scatter per day.

SUMO draws each vehicle's speedFactor from the seeded RNG as the vehicle is added, in insertion
order (departure second, humans before CAVs, then agent order; sumo_bridge.tripinfo), so a factor
belongs to an insertion slot, not to a driver: measured on St. Arnoult, a day with departures moved
by up to 300 s gives 2% of the drivers their scheduled day's factor and 100% of the slots theirs.
The model's per-agent factor g_n is first fitted on the human phase's days (scheduled, no CAV),
where driver n holds slot s0(n); on any later day it takes the factor of the slot it holds, g_{a(n)},
a(n) the driver whose slot that was in the human phase (`slot_agents`); mutation alone moves a CAV
behind the humans leaving in its second (6 of St. Arnoult's 222 drivers change slot, 121 of
Ingolstadt's 1,035). With zero shifts and no CAV it is the scheduled model: the same non-zero
weights on the same cells, every driver in its own slot.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario

if TYPE_CHECKING:  # model.py imports this module
    from urb_jax.surrogate.model import SurrogateConfig


@partial(
    jax.tree_util.register_dataclass,
    data_fields=["flow_agent", "flow_pos", "time_agent", "time_pos", "depart", "pair_agent", "pair_other",
                 "slot_tiebreak", "slot_agent"],
    meta_fields=["bin_s", "interpolate", "origin_window_s", "moves"],
)
@dataclass(frozen=True)
class DepartIndex:
    """One scenario's (entry, reachable bin) pairs: what moves with the shifts (a pytree). Their rows
    and cells are the Static's flow_/time_ arrays; these are each pair's agent and position."""

    flow_agent: jax.Array  # [M] agent of each pair, in the Static's cell order
    flow_pos: jax.Array  # [M] scheduled entry time / bin_s - the pair's bin index
    time_agent: jax.Array  # [M] the same pairs in row order
    time_pos: jax.Array
    depart: jax.Array  # [N] scheduled departures, s
    pair_agent: jax.Array  # [Q] same-origin pairs (n, m), n's own pair included: n's insertion
    pair_other: jax.Array  # [Q]     load counts m when m leaves in (d_n - w, d_n]
    slot_tiebreak: jax.Array  # [N] is_cav_n * N + n: insertion order within a second
    slot_agent: jax.Array  # [N] the driver in each insertion slot in the human phase (no CAV)
    bin_s: float
    interpolate: bool
    origin_window_s: float
    moves: bool  # the entries can move (max_shift_s > 0); else only the insertion slots vary


def reachable_bins(enter: np.ndarray, bin_s: float, interpolate: bool, max_shift_s: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(entry index, bin) of every bin an entry entering at `enter` [M] s +- max_shift_s can weigh on.
    Bin b (>= 0) has centre (b - 0.5) bin_s: interpolated, an entry at t weighs 1 - |t / bin_s + 0.5 - b|
    on the bins within one width; hard, it sits whole in bin floor(t / bin_s) + 1."""
    lo_t, hi_t = np.maximum(enter - max_shift_s, 0.0) / bin_s, (enter + max_shift_s) / bin_s
    if interpolate:
        lo, hi = np.floor(lo_t + 0.5).astype(np.int64), np.ceil(hi_t + 0.5).astype(np.int64)
    else:
        lo, hi = np.floor(lo_t).astype(np.int64) + 1, np.floor(hi_t).astype(np.int64) + 1
    count = hi - lo + 1
    entry = np.repeat(np.arange(enter.size), count)
    first = np.repeat(np.cumsum(count) - count, count)
    return entry, np.repeat(lo, count) + (np.arange(entry.size) - first)


def build_depart_index(scn: Scenario, flow_agent: np.ndarray, flow_pos: np.ndarray, time_agent: np.ndarray,
                       time_pos: np.ndarray, config: SurrogateConfig, is_cav: np.ndarray | None,
                       moves: bool) -> DepartIndex:
    """The index of the pairs `build_static` laid out: their agents and positions in cell order and
    in row order, the same-origin pairs of `scn`'s drivers and their insertion slots (`is_cav` [N]:
    CAVs are added after the humans of their second; None: no CAV)."""
    origin = scn.od_routes[scn.agent_od, 0, 0]
    groups = [np.flatnonzero(origin == o) for o in np.unique(origin)]
    pair = np.concatenate([np.stack([np.repeat(g, g.size), np.tile(g, g.size)], axis=1) for g in groups])
    n = scn.n_agents
    cav = np.zeros(n, bool) if is_cav is None else np.asarray(is_cav, bool)
    tiebreak = cav.astype(np.int64) * n + np.arange(n)
    i32, f32 = partial(jnp.asarray, dtype=jnp.int32), partial(jnp.asarray, dtype=jnp.float32)
    return DepartIndex(
        flow_agent=i32(flow_agent), flow_pos=f32(flow_pos),
        time_agent=i32(time_agent), time_pos=f32(time_pos),
        depart=f32(scn.agent_depart), pair_agent=i32(pair[:, 0]), pair_other=i32(pair[:, 1]),
        slot_tiebreak=i32(tiebreak), slot_agent=i32(np.argsort(scn.agent_depart * 2 * n + np.arange(n))),
        bin_s=float(config.bin_s), interpolate=bool(config.interpolate),
        origin_window_s=float(config.origin_window_s), moves=moves,
    )


def day_weights(index: DepartIndex, shift: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """For a day whose drivers leave `shift` [N] seconds off their schedule: each pair's weight in
    cell order [M] and in row order [M], and each agent's insertion load [N]."""
    step = shift / index.bin_s  # [N] in bins

    def weight(agent: jax.Array, pos: jax.Array) -> jax.Array:
        p = pos + step[agent]
        if index.interpolate:
            return jnp.maximum(1.0 - jnp.abs(p + 0.5), 0.0)
        return ((p >= -1.0) & (p < 0.0)).astype(jnp.float32)

    depart = index.depart + shift  # [N]
    d_n, d_m = depart[index.pair_agent], depart[index.pair_other]
    within = (d_m > d_n - index.origin_window_s) & (d_m <= d_n)
    load = jax.ops.segment_sum(within.astype(jnp.float32), index.pair_agent, depart.shape[0])
    return weight(index.flow_agent, index.flow_pos), weight(index.time_agent, index.time_pos), load


def slot_agents(index: DepartIndex, shift: jax.Array, present: jax.Array | None = None) -> jax.Array:
    """[N] (or [N, B] for `present` [N, B]) for each driver on a day moved by `shift` [N] on which
    only `present` drivers travel (None: all): the driver that held its insertion slot in the human
    phase (scheduled, everyone, no CAV: whose fitted speed factor is the slot's). Absent drivers are
    added after everyone (no vehicle: their entry is unused). The identity when nothing moves and no
    CAV shares a departure second with a human after it."""
    n = index.depart.shape[0]
    depart = jnp.round(index.depart + shift).astype(jnp.int32)  # whole seconds
    key = depart * (2 * n) + index.slot_tiebreak  # [N] SUMO's insertion order
    if present is None:
        return index.slot_agent[jnp.argsort(jnp.argsort(key))]
    late = jnp.int32(2**30) + index.slot_tiebreak  # after every present driver
    tail = (1,) * (present.ndim - 1)  # the batch axis of `present`, if any
    keys = jnp.where(present, key.reshape(n, *tail), late.reshape(n, *tail))
    return index.slot_agent[jnp.argsort(jnp.argsort(keys, axis=0), axis=0)]
