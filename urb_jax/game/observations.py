"""CAV observations (URB_REFERENCE §7) as masked prefix counts over the departure-sorted axis.

`previous_agents_plus_start_time`: [own start_time (s), count_k for k < K], where count_k is the
number of agents with the same OD and a strictly earlier departure whose action today is k.
`previous_agents`: the counts only. `global_previous_agents`: counts over every agent with a
strictly earlier departure (any OD), plus start time: the sensitivity-study variant.

URB observes humans who depart between two CAV turns with yesterday's choice (a timing artefact,
§12.8); we use today's choices of everyone who departed earlier, which is what the observation
means. Counts come from one cumulative sum over agents sorted by (group, departure): no loop over
agents, O(N*K) per day, and it runs inside jit.

Earlier CAVs' actions enter later CAVs' observations, so the day is sequential in principle; the
group ids kept in the spec say which CAVs depend on which (`urb_jax.game.rollout` acts level by
level on them).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.core.errors import ConfigError

OBSERVATION_TYPES = ("previous_agents_plus_start_time", "previous_agents", "global_previous_agents")


@dataclass(frozen=True)
class PrefixIndex:
    """Static index arrays for 'earlier agents of my group' counts (numpy, built once)."""

    order: np.ndarray  # [N] agents sorted by (group, depart, position)
    inverse: np.ndarray  # [N] position of agent i in `order`
    group_start: np.ndarray  # [N] (sorted positions) first position of my group
    tie_start: np.ndarray  # [N] (sorted positions) first position of my (group, depart)


def prefix_index(group: np.ndarray, depart: np.ndarray) -> PrefixIndex:
    group = np.asarray(group)
    depart = np.asarray(depart)
    n = group.shape[0]
    order = np.lexsort((np.arange(n), depart, group))
    g, t = group[order], depart[order]
    new_group = np.ones(n, dtype=bool)
    new_group[1:] = g[1:] != g[:-1]
    new_tie = new_group.copy()
    new_tie[1:] |= t[1:] != t[:-1]
    pos = np.arange(n)
    group_start = np.maximum.accumulate(np.where(new_group, pos, 0))
    tie_start = np.maximum.accumulate(np.where(new_tie, pos, 0))
    inverse = np.empty(n, dtype=np.int64)
    inverse[order] = pos
    return PrefixIndex(order, inverse, group_start, tie_start)


def earlier_counts(index: PrefixIndex, actions: jnp.ndarray, k: int) -> jnp.ndarray:
    """[N, K]: per agent, how many agents of its group departed strictly earlier with action k."""
    onehot = jax.nn.one_hot(actions, k, dtype=jnp.float32)
    sorted_onehot = onehot[index.order]
    before = jnp.concatenate([jnp.zeros((1, k)), jnp.cumsum(sorted_onehot, axis=0)[:-1]], axis=0)
    counts_sorted = before[index.tie_start] - before[index.group_start]
    return counts_sorted[index.inverse]


@dataclass(frozen=True)
class ObservationSpec:
    kind: str
    index: PrefixIndex
    group: np.ndarray  # [N] observation group: the OD pair, or 0 for everyone (global variant)
    depart: np.ndarray  # [N] seconds
    k: int

    @property
    def size(self) -> int:
        return self.k if self.kind == "previous_agents" else self.k + 1


def make_observation_spec(kind: str, od: np.ndarray, depart: np.ndarray, k: int) -> ObservationSpec:
    if kind not in OBSERVATION_TYPES:
        raise ConfigError(f"unknown observations '{kind}'. Fix: use one of {', '.join(OBSERVATION_TYPES)}.")
    group = np.zeros_like(od) if kind == "global_previous_agents" else od
    return ObservationSpec(kind, prefix_index(group, depart), np.asarray(group), np.asarray(depart), k)


def observe(spec: ObservationSpec, actions: jnp.ndarray) -> jnp.ndarray:
    """[N, obs_size] observation of every agent given today's actions of everyone."""
    counts = earlier_counts(spec.index, actions, spec.k)
    if spec.kind == "previous_agents":
        return counts
    start = jnp.asarray(spec.depart, dtype=jnp.float32)[:, None]
    return jnp.concatenate([start, counts], axis=-1)



class IncrementalObservations:
    """Every agent's observation kept current while today's actions change a few at a time (numpy,
    outside jit: the PettingZoo envs). Equal to `observe(spec, actions)` after every change.

    Counts live per (group, departure)-sorted position. A changed action of the agent at sorted
    position p moves one count in the rows of its group that depart strictly later (one contiguous
    slice, at most the group's size), so a change costs O(group) <= O(N) and reading one agent's
    observation O(K); recomputing everyone after each of C changes cost O(C·N·K)."""

    def __init__(self, spec: ObservationSpec) -> None:
        self.spec = spec
        idx = spec.index
        n = idx.order.shape[0]
        g = spec.group[idx.order]
        t = spec.depart[idx.order]
        last_of_group = np.ones(n, dtype=bool)
        last_of_group[:-1] = g[1:] != g[:-1]
        last_of_tie = last_of_group.copy()
        last_of_tie[:-1] |= t[1:] != t[:-1]
        pos = np.arange(n)
        # [N] (sorted positions) one past the last position of my group / of my (group, depart) tie
        self._group_end = np.minimum.accumulate(np.where(last_of_group, pos + 1, n)[::-1])[::-1]
        self._tie_end = np.minimum.accumulate(np.where(last_of_tie, pos + 1, n)[::-1])[::-1]
        self._start = np.asarray(spec.depart, dtype=np.float32)[:, None]  # [N, 1]
        self._full = jax.jit(lambda actions: earlier_counts(idx, actions, spec.k)[idx.order])  # [N, K]
        self.actions = np.zeros(n, dtype=np.int64)
        self._counts = np.zeros((n, spec.k), dtype=np.int64)  # [N, K] by sorted position

    def reset(self, actions: np.ndarray) -> None:
        """Start from `actions` [N] (one full computation)."""
        self.actions = np.asarray(actions, dtype=np.int64).copy()
        self._counts = np.rint(np.asarray(self._full(self.actions))).astype(np.int64)

    def set(self, agents: np.ndarray | int, actions: np.ndarray | int) -> None:
        """Agents `agents` (rows of the agent axis) now take `actions`."""
        for i, a in zip(np.atleast_1d(agents).tolist(), np.atleast_1d(actions).tolist(), strict=True):
            if not 0 <= a < self.spec.k:
                raise ValueError(f"action {a} of agent row {i} is not a route index in [0, {self.spec.k}).")
            old = int(self.actions[i])
            if old == a:
                continue
            p = int(self.spec.index.inverse[i])
            rows = slice(int(self._tie_end[p]), int(self._group_end[p]))  # same group, departing later
            self._counts[rows, old] -= 1
            self._counts[rows, a] += 1
            self.actions[i] = a

    def observe_one(self, agent: int) -> np.ndarray:
        """[obs_size] float32 observation of one agent (row of the agent axis): `observe`'s row
        without its array indexing, for the AEC env's one read per step."""
        counts = self._counts[self.spec.index.inverse[agent]]
        if self.spec.kind == "previous_agents":
            return counts.astype(np.float32)
        out = np.empty(self.spec.k + 1, dtype=np.float32)
        out[0] = self._start[agent, 0]
        out[1:] = counts
        return out

    def observe(self, agents: np.ndarray) -> np.ndarray:
        """[len(agents), obs_size] float32 observations of `agents` (rows of the agent axis)."""
        agents = np.asarray(agents)
        counts = self._counts[self.spec.index.inverse[agents]].astype(np.float32)
        if self.spec.kind == "previous_agents":
            return counts
        return np.concatenate([self._start[agents], counts], axis=-1)
