"""The `Learner` seam the trainers drive, and day collection: CAVs act in departure order,
the env simulates, `collect` scans days over vmapped environments."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.policy import Policy
from urb_jax.game.env import EnvState, RoutingEnv


class Day(NamedTuple):
    """One day of one environment, arrays over CAVs [C] (leading [T, B] after collect)."""

    obs: jnp.ndarray  # [C, D] observation each CAV acted on (departure order)
    action: jnp.ndarray  # [C]
    reward: jnp.ndarray  # [C] the day's reward (arrives at the end of the day)
    done: jnp.ndarray  # [C] True: every day ends the CAVs' episode (URB)
    next_obs: jnp.ndarray  # [C, D] provisional observation of the next day
    time_cav: jnp.ndarray  # [] mean CAV travel time, minutes
    time_human: jnp.ndarray  # []


def dependency_levels(env: RoutingEnv) -> tuple[np.ndarray, ...]:
    """CAV-axis indices by level: a CAV's level is the number of distinct earlier departure times
    among CAVs of its observation group, so its observation depends only on lower levels."""
    scn = env.scenario
    group = scn.agent_od if env.obs_spec.kind != "global_previous_agents" else np.zeros(scn.n_agents, int)
    g, t = group[env.cav_index], scn.agent_depart[env.cav_index]
    level = np.zeros(env.n_cavs, dtype=np.int64)
    for grp in np.unique(g):
        members = np.flatnonzero(g == grp)
        level[members] = np.searchsorted(np.unique(t[members]), t[members])
    return tuple(np.flatnonzero(level == lv) for lv in range(int(level.max(initial=-1)) + 1))


def act_by_levels(env: RoutingEnv, key: jax.Array, state: EnvState, policy: Policy,
                  levels: tuple[np.ndarray, ...] | None = None) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Exact departure-order choices like env.act_in_order, but each CAV's network runs once:
    level by level (static index sets, unrolled), observing the lower levels' choices. Costs C
    policy evaluations per day instead of depth x C."""
    levels = dependency_levels(env) if levels is None else levels
    actions = state.cav_actions
    for lv, idx in enumerate(levels):
        obs = env.observe(state, actions)
        chosen = policy(jax.random.fold_in(key, lv), obs[idx], jnp.asarray(idx))
        actions = actions.at[idx].set(chosen.astype(jnp.int32))
    return env.observe(state, actions), actions


def env_day(env: RoutingEnv, policy: Policy, key: jax.Array, state: EnvState,
            levels: tuple[np.ndarray, ...] | None = None) -> tuple[EnvState, Day]:
    """One day of one env: CAVs act in departure order (act_by_levels), then simulate."""
    k_act, k_step = jax.random.split(key)
    obs, actions = act_by_levels(env, k_act, state, policy, levels)
    next_obs, state, rewards, dones, info = env.step(k_step, state, actions)
    return state, Day(obs, actions, rewards, dones, next_obs, info["mean_time_cav"], info["mean_time_human"])


def collect(env: RoutingEnv, policy: Policy, key: jax.Array, states: EnvState, n_days: int
            ) -> tuple[EnvState, Day]:
    """n_days days in each of B envs (states batched [B]); returns Day arrays [n_days, B, ...]."""
    n_envs = jax.tree_util.tree_leaves(states)[0].shape[0]
    levels = dependency_levels(env)

    def body(states: EnvState, k: jax.Array) -> tuple[EnvState, Day]:
        keys = jax.random.split(k, n_envs)
        return jax.vmap(lambda kk, s: env_day(env, policy, kk, s, levels))(keys, states)

    return jax.lax.scan(body, states, jax.random.split(key, n_days))


class Learner(NamedTuple):
    """An algorithm as pieces the trainers drive (`make_train` scans `iteration`; the hybrid trainer
    mixes surrogate iterations with updates on SUMO days).

    init(key) -> runner; iteration(runner, key) -> (runner, metrics): collect on the runner's envs,
    then update; update_from_days(runner, days[T, B, ...], key) -> (runner, metrics): one update on
    given days (e.g. SUMO days), env states untouched; policy(runner, explore) -> Policy (explore
    False: the frozen test policy); n_iters: iterations `make_train` runs; days_per_iter: days
    collected per env per iteration."""

    init: Callable[[jax.Array], Any]
    iteration: Callable[[Any, jax.Array], tuple[Any, dict[str, jnp.ndarray]]]
    update_from_days: Callable[[Any, Day, jax.Array], tuple[Any, dict[str, jnp.ndarray]]]
    policy: Callable[[Any, bool], Policy]
    n_iters: int
    days_per_iter: int


def scan_train(learner: Learner, n_keys: int) -> Callable[[jax.Array], dict[str, Any]]:
    """train(key): init, then `n_iters` iterations in one lax.scan on the last of `n_keys` splits
    of the key (the split `init` also makes, so init and loop keys never overlap)."""
    def train(key: jax.Array) -> dict[str, Any]:
        runner = learner.init(key)
        k_loop = jax.random.split(key, n_keys)[-1]
        runner, metrics = jax.lax.scan(learner.iteration, runner, jax.random.split(k_loop, learner.n_iters))
        return {"runner_state": runner, "metrics": metrics}

    return train


def reset_envs(env: RoutingEnv, key: jax.Array, n_envs: int) -> EnvState:
    _, states = jax.vmap(env.reset)(jax.random.split(key, n_envs))
    return states


def day_metrics(days: Day) -> dict[str, jnp.ndarray]:
    return {
        "reward": days.reward.mean(),
        "time_cav": days.time_cav.mean(),
        "time_human": days.time_human.mean(),
    }


def evaluate(env: RoutingEnv, policy: Policy, key: jax.Array, n_days: int, n_envs: int = 1,
             states: EnvState | None = None) -> dict[str, jnp.ndarray]:
    """Mean CAV / human travel time (minutes) and reward of a fixed policy over n_days x n_envs."""
    k_reset, k_run = jax.random.split(key)
    if states is None:
        states = reset_envs(env, k_reset, n_envs)
    _, days = collect(env, policy, k_run, states, n_days)
    return day_metrics(days)
