"""The `Learner` seam the trainers drive, and day collection: CAVs act in departure order
(`urb_jax.game.rollout`), the env simulates under the runner's env params, `collect` scans days
over vmapped environments."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.game.env import EnvParams, EnvState, RoutingEnv
from urb_jax.game.rollout import Policy, act_by_levels, dependency_levels


class Day(NamedTuple):
    """One day of one environment, arrays over CAVs [C] (leading [T, B] after collect)."""

    obs: jnp.ndarray  # [C, D] observation each CAV acted on (departure order)
    action: jnp.ndarray  # [C]
    reward: jnp.ndarray  # [C] the day's reward (arrives at the end of the day)
    done: jnp.ndarray  # [C] True: every day ends the CAVs' episode (URB)
    next_obs: jnp.ndarray  # [C, D] provisional observation of the next day
    time_cav: jnp.ndarray  # [] mean CAV travel time, minutes
    time_human: jnp.ndarray  # []
    # [C] bool, the CAVs that travelled (the task's day_participation); None (no leaf, so fixed
    # demand keeps its pytrees, buffers and checkpoints): every CAV. A CAV that stayed home took no
    # action: the losses leave its row out (`active_mean`).
    active: jnp.ndarray | None = None

    @classmethod
    def zeros(cls, n_cavs: int, obs_size: int, active: bool = False) -> Day:
        """One day of zeros: the template a replay memory of days is shaped on (`active`: with
        the per-CAV travelled mask, for an env with day_demand)."""
        c, d = n_cavs, obs_size
        return cls(jnp.zeros((c, d)), jnp.zeros((c,), jnp.int32), jnp.zeros((c,)), jnp.zeros((c,), bool),
                   jnp.zeros((c, d)), jnp.zeros(()), jnp.zeros(()), jnp.zeros((c,), bool) if active else None)


def active_mean(x: jnp.ndarray, active: jnp.ndarray | None) -> jnp.ndarray:
    """Mean of per-CAV terms x [..., C] over the rows of CAVs that travelled (`active`, same shape;
    None: every row, the plain mean)."""
    if active is None:
        return jnp.mean(x)
    return jnp.where(active, x, 0.0).sum() / jnp.maximum(active.sum(), 1)


def env_day(env: RoutingEnv, policy: Policy, key: jax.Array, state: EnvState, params: EnvParams = None,
            levels: tuple[np.ndarray, ...] | None = None) -> tuple[EnvState, Day]:
    """One day of one env: CAVs act in departure order (act_by_levels), then simulate under
    `params` (the env's default_params when None)."""
    k_act, k_step = jax.random.split(key)
    obs, actions = act_by_levels(env, k_act, state, policy, levels)
    next_obs, state, rewards, dones, info = env.step(k_step, state, actions, params)
    return state, Day(obs, actions, rewards, dones, next_obs, info["mean_time_cav"], info["mean_time_human"],
                      info.get("active"))


def collect(env: RoutingEnv, policy: Policy, key: jax.Array, states: EnvState, n_days: int,
            params: EnvParams = None) -> tuple[EnvState, Day]:
    """n_days days in each of B envs (states batched [B]), all under the same env `params`
    (env.default_params when None); returns Day arrays [n_days, B, ...]."""
    n_envs = jax.tree_util.tree_leaves(states)[0].shape[0]
    levels = dependency_levels(env)
    # One copy of the params per env ([B, ...], vmapped like the states): with the params unbatched
    # XLA fuses the surrogate differently and its times move by ~1e-6 min.
    params = env.default_params if params is None else params
    params_b = jax.tree_util.tree_map(lambda p: jnp.broadcast_to(p, (n_envs, *jnp.shape(p))), params)

    def body(states: EnvState, k: jax.Array) -> tuple[EnvState, Day]:
        keys = jax.random.split(k, n_envs)
        return jax.vmap(lambda kk, s, p: env_day(env, policy, kk, s, p, levels))(keys, states, params_b)

    return jax.lax.scan(body, states, jax.random.split(key, n_days))


class Learner(NamedTuple):
    """An algorithm as pieces the trainers drive (`make_train` scans `iteration`; the hybrid trainer
    mixes surrogate iterations with updates on SUMO days).

    init(key) -> runner, its env params starting at env.default_params (a trainer may swap them,
    e.g. after a surrogate refit: runner._replace(env_params=...)); iteration(runner, key) ->
    (runner, metrics): collect on the runner's envs, then update; update_from_days(runner,
    days[T, B, ...], key) -> (runner, metrics): one update on given days (e.g. SUMO days), env
    states untouched; policy(runner, explore) -> Policy (explore False: the frozen test policy);
    n_iters: iterations `make_train` runs; days_per_iter: days collected per env per iteration."""

    init: Callable[[jax.Array], Any]
    iteration: Callable[[Any, jax.Array], tuple[Any, dict[str, jnp.ndarray]]]
    update_from_days: Callable[[Any, Day, jax.Array], tuple[Any, dict[str, jnp.ndarray]]]
    policy: Callable[[Any, bool], Policy]
    n_iters: int
    days_per_iter: int


Metrics = dict[str, jnp.ndarray]  # a learner's per-iteration scalars (loss, eps, mean times, ...)


def collect_then_update(env: RoutingEnv, policy: Callable[[Any, bool], Policy],
                        update_from_days: Callable[[Any, Day, jax.Array], tuple[Any, Metrics]], n_days: int,
                        exploration: Callable[[Any], Metrics] | None = None
                        ) -> Callable[[Any, jax.Array], tuple[Any, Metrics]]:
    """Every learner's `iteration`: `n_days` days in each of the runner's envs under its exploring
    policy, then one `update_from_days` on them. `exploration(runner)`: how that policy explored
    (e.g. epsilon), logged beside the update's metrics."""
    def iteration(runner: Any, key: jax.Array) -> tuple[Any, Metrics]:
        k_col, k_upd = jax.random.split(key)
        env_states, days = collect(env, policy(runner, True), k_col, runner.env_states, n_days,
                                   runner.env_params)
        updated, metrics = update_from_days(runner._replace(env_states=env_states), days, k_upd)
        return updated, metrics | (exploration(runner) if exploration else {})

    return iteration


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
        "reward": active_mean(days.reward, days.active),
        "time_cav": days.time_cav.mean(),
        "time_human": days.time_human.mean(),
    }


def evaluate(env: RoutingEnv, policy: Policy, key: jax.Array, n_days: int, n_envs: int = 1,
             states: EnvState | None = None, params: EnvParams = None) -> dict[str, jnp.ndarray]:
    """Mean CAV / human travel time (minutes) and reward of a fixed policy over n_days x n_envs."""
    k_reset, k_run = jax.random.split(key)
    if states is None:
        states = reset_envs(env, k_reset, n_envs)
    _, days = collect(env, policy, k_run, states, n_days, params)
    return day_metrics(days)
