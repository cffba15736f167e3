"""CAVs choose today's routes in departure order (AEC semantics), vectorised.

A CAV observes the choices of agents of its observation group that departed strictly earlier
(`urb_jax.game.observations`), so its choice depends on earlier CAVs' choices. Grouping CAVs into
dependency levels (a CAV's level: the number of distinct earlier departure times among CAVs of its
group) makes the day exact with one policy call per level: each level observes the lower levels'
choices and yesterday's choices of the CAVs still to come (which it cannot see: they depart later).
A policy that ignores observations (the baselines) needs no order: `act_at_once`.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.game.env import EnvState, RoutingEnv

# policy(key, obs[n, D], idx[n] | None) -> actions[n]: idx names the CAVs acting (rows of the CAV
# axis); None = all C at once.
Policy = Callable[..., jnp.ndarray]


def dependency_levels(env: RoutingEnv) -> tuple[np.ndarray, ...]:
    """CAV-axis indices by level: a CAV's observation depends only on lower levels' choices."""
    g = env.obs_spec.group[env.cav_index]
    t = env.obs_spec.depart[env.cav_index]
    level = np.zeros(env.n_cavs, dtype=np.int64)
    for grp in np.unique(g):
        members = np.flatnonzero(g == grp)
        level[members] = np.searchsorted(np.unique(t[members]), t[members])
    return tuple(np.flatnonzero(level == lv) for lv in range(int(level.max(initial=-1)) + 1))


def act_by_levels(env: RoutingEnv, key: jax.Array, state: EnvState, policy: Policy,
                  levels: tuple[np.ndarray, ...] | None = None) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(obs [C, D], actions [C]) in exact departure order: level by level (static index sets,
    unrolled), each CAV's policy evaluated once with the level's key fold_in(key, level)."""
    levels = dependency_levels(env) if levels is None else levels
    actions = state.cav_actions
    for lv, idx in enumerate(levels):
        obs = env.observe(state, actions)
        chosen = policy(jax.random.fold_in(key, lv), obs[idx], jnp.asarray(idx))
        actions = actions.at[idx].set(chosen.astype(jnp.int32))
    return env.observe(state, actions), actions


def act_at_once(env: RoutingEnv, key: jax.Array, state: EnvState,
                policy: Policy) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(obs [C, D], actions [C]) for a policy that ignores its observations: one call for every CAV
    with `key` itself; obs are those of the final choices, as in `act_by_levels`."""
    actions = policy(key, env.observe(state, state.cav_actions)).astype(jnp.int32)
    return env.observe(state, actions), actions
