"""CAVs choose today's routes in departure order (AEC semantics), vectorised.

A CAV observes the choices of agents of its observation group that departed strictly earlier
(`urb_jax.game.observations`), so its choice depends on earlier CAVs' choices. Grouping CAVs into
dependency levels (a CAV's level: the number of distinct earlier departure times among CAVs of its
group) makes the day exact with one policy call per level: each level observes the lower levels'
choices and yesterday's choices of the CAVs still to come (which it cannot see: they depart later).
A policy that ignores observations (the baselines) needs no order: `act_at_once`.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.game.env import EnvState, RoutingEnv
from urb_jax.game.observations import ObservationSpec

# policy(key, obs[n, D], idx[n] | None) -> actions[n]: idx names the CAVs acting (rows of the CAV
# axis); None = all C at once.
Policy = Callable[..., jnp.ndarray]


def dependency_levels(env: RoutingEnv) -> tuple[np.ndarray, ...]:
    """CAV-axis indices by level: a CAV's observation depends only on lower levels' choices."""
    return cav_levels(env.obs_spec, env.cav_index)


def cav_levels(spec: ObservationSpec, cav_index: np.ndarray) -> tuple[np.ndarray, ...]:
    """`dependency_levels` from an observation spec and the CAVs' rows [C] of the agent axis."""
    g = spec.group[cav_index]
    t = spec.depart[cav_index]
    level = np.zeros(len(cav_index), dtype=np.int64)
    for grp in np.unique(g):
        members = np.flatnonzero(g == grp)
        level[members] = np.searchsorted(np.unique(t[members]), t[members])
    return tuple(np.flatnonzero(level == lv) for lv in range(int(level.max(initial=-1)) + 1))


MAX_BLOCKS = 4  # scan bodies per day at most: compile time does not grow with the number of levels


class LevelBlock(NamedTuple):
    """Consecutive levels first .. first+L-1 as one [L, M] table (M: the block's largest level),
    acted in one `lax.scan`. A padding slot repeats its level's first CAV and writes nowhere."""

    first: int
    idx: np.ndarray  # [L, M] CAV-axis indices the policy reads
    write: np.ndarray  # [L, M] where each slot's action goes: idx, or C (out of range: dropped)


def block_bounds(sizes: np.ndarray, max_blocks: int = MAX_BLOCKS, block_rows: float = 0.0) -> list[int]:
    """Split points 0 = b[0] < ... < b[k] = L (k <= max_blocks) of the levels minimising the padded
    rows, sum over blocks of (b[i+1] - b[i]) * max(sizes[b[i]:b[i+1]]) + block_rows (dynamic
    programming over (blocks, levels covered)).

    One block for every level wastes rows when level sizes differ (saint_arnoult, default
    observations: 86 and 2 CAVs); a few blocks keep the padded work near the real one."""
    n = len(sizes)
    best = np.full((max_blocks + 1, n + 1), np.inf)  # [blocks, levels covered]
    best[0, 0] = 0.0
    arg = np.zeros((max_blocks + 1, n + 1), np.int64)
    for j in range(1, n + 1):
        widest = np.maximum.accumulate(sizes[:j][::-1])[::-1]  # [j] max(sizes[i:j]) per start i
        cost = (j - np.arange(j)) * widest + block_rows  # [j]
        for k in range(1, max_blocks + 1):
            total = best[k - 1, :j] + cost
            arg[k, j] = int(np.argmin(total))
            best[k, j] = total[arg[k, j]]
    k = int(np.argmin(best[:, n]))
    bounds = [n]
    while k > 0:
        bounds.append(int(arg[k, bounds[-1]]))
        k -= 1
    return bounds[::-1]


def level_blocks(levels: tuple[np.ndarray, ...], n_cavs: int) -> tuple[LevelBlock, ...]:
    """The levels as at most MAX_BLOCKS padded blocks; a block must save a tenth of the CAVs'
    rows to be worth its own compiled body."""
    sizes = np.array([len(lv) for lv in levels], np.int64)
    bounds = block_bounds(sizes, block_rows=max(n_cavs / 10, 1.0))
    blocks = []
    for lo, hi in itertools.pairwise(bounds):
        width = int(sizes[lo:hi].max())
        idx = np.zeros((hi - lo, width), np.int32)
        write = np.full((hi - lo, width), n_cavs, np.int32)
        for row, members in enumerate(levels[lo:hi]):
            idx[row] = np.concatenate([members, np.full(width - len(members), members[0])])
            write[row, :len(members)] = members
        blocks.append(LevelBlock(lo, idx, write))
    return tuple(blocks)


def act_by_levels(env: RoutingEnv, key: jax.Array, state: EnvState, policy: Policy,
                  levels: tuple[np.ndarray, ...] | None = None) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(obs [C, D], actions [C]) in exact departure order: level by level, each CAV's policy
    evaluated once with the level's key fold_in(key, level), as a `lax.scan` per level block.

    A level of n CAVs acts as M >= n rows; the first n rows get the same random draws as an
    n-row call (JAX's partitionable threefry, on by default: element i of a draw depends on i,
    not on the shape), so the actions equal those of one call per level (tested)."""
    levels = dependency_levels(env) if levels is None else levels
    actions = state.cav_actions  # [C]
    for block in level_blocks(levels, env.n_cavs):
        actions = _act_block(env, key, state, policy, block, actions)
    return env.observe(state, actions), actions


def _act_block(env: RoutingEnv, key: jax.Array, state: EnvState, policy: Policy, block: LevelBlock,
               actions: jnp.ndarray) -> jnp.ndarray:
    if len(block.idx) == 1:  # a lone level is never padded: one plain call (the old loop's program)
        members = block.idx[0]
        chosen = policy(jax.random.fold_in(key, block.first), env.observe(state, actions)[members],
                        jnp.asarray(members))
        return actions.at[members].set(chosen.astype(jnp.int32))

    def level(acts: jnp.ndarray, xs: tuple[jnp.ndarray, ...]) -> tuple[jnp.ndarray, None]:
        lv, idx, write = xs  # [], [M], [M]
        obs = env.observe(state, acts)  # [C, D]
        chosen = policy(jax.random.fold_in(key, lv), obs[idx], idx)  # [M]
        return acts.at[write].set(chosen.astype(jnp.int32), mode="drop"), None

    xs = (block.first + jnp.arange(len(block.idx)), jnp.asarray(block.idx), jnp.asarray(block.write))
    return jax.lax.scan(level, actions, xs)[0]


def act_at_once(env: RoutingEnv, key: jax.Array, state: EnvState,
                policy: Policy) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(obs [C, D], actions [C]) for a policy that ignores its observations: one call for every CAV
    with `key` itself; obs are those of the final choices, as in `act_by_levels`."""
    actions = policy(key, env.observe(state, state.cav_actions)).astype(jnp.int32)
    return env.observe(state, actions), actions
