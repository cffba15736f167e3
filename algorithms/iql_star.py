"""IQL* (URB's adjusted `scripts/iql.py`): one Q network per CAV, a one-step contextual bandit.

Each CAV has its own ReLU MLP (`widths`), stacked on a leading [C] parameter axis with its own
Adam state (the update is vmapped over CAVs, so no CAV's gradient touches another's network).
Every day a CAV stores (observation at its turn, action, its day reward) in its FIFO buffer of
`buffer_size`; every `update_every` days, once the buffer holds `batch_size` samples, it takes
`num_epochs` minibatches of `batch_size` distinct samples and regresses Q(s, a) on the reward
(MSE, no bootstrapping, no target network); then epsilon <- max(eps_min, epsilon * eps_decay).
Acting is epsilon-greedy over valid routes. With `num_envs` B > 1, an update sees the B
parallel environments' days (B samples per CAV per day) and epsilon decays per update, as URB.

Demand varying day to day (the task's `day_participation`): each CAV's buffer is its own FIFO ring
of the days it travelled (`buffer_add_where`), and a CAV updates only after a day it travelled
(`Day.active`), once its own buffer holds `batch_size` samples; a CAV at home stores nothing and
its network and Adam state stay as they were. Epsilon, one for all CAVs, decays when any CAV updated.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from urb_jax.algorithms.buffer import Buffer, buffer_add, buffer_add_where, buffer_init, buffer_init_columns
from urb_jax.algorithms.configs import IQLStarConfig
from urb_jax.algorithms.learner import (
    Day,
    Learner,
    active_mean,
    collect_then_update,
    day_metrics,
    reset_envs,
    scan_train,
)
from urb_jax.algorithms.networks import make_per_cav_mlp
from urb_jax.algorithms.policy import eps_greedy_policy
from urb_jax.algorithms.updates import adam_step, flatten_days, select_tree
from urb_jax.game.env import EnvParams, EnvState, RoutingEnv


class Sample(NamedTuple):
    obs: jnp.ndarray  # [C, D]
    action: jnp.ndarray  # [C]
    reward: jnp.ndarray  # [C]


class RunnerState(NamedTuple):
    params: Any  # leaves [C, ...]
    opt_state: Any  # leaves [C, ...]
    # entries [capacity] of Sample (every CAV adds one per env-day); with day_demand one ring per CAV
    # (pos and size [C]) that holds the days it travelled
    buffer: Buffer
    env_states: EnvState
    env_params: EnvParams  # travel-time parameters the envs simulate with
    eps: jnp.ndarray


def bandit_loss(q: jnp.ndarray, action: jnp.ndarray, reward: jnp.ndarray) -> jnp.ndarray:
    """MSE between Q(s, a) and the day reward (one CAV's minibatch: q [M, K])."""
    q_a = jnp.take_along_axis(q, action[..., None], axis=-1)[..., 0]
    return jnp.mean((q_a - reward) ** 2)


def make_network(config: IQLStarConfig, env: RoutingEnv):
    """(init, apply, mlp, scale): one network per CAV (networks.make_per_cav_mlp)."""
    return make_per_cav_mlp(env, config.widths, config.normalize_obs)


def make_policy(config: IQLStarConfig, env: RoutingEnv):
    """(params, eps) -> policy(key, obs[C, D]) -> actions[C]; eps=0 is URB's greedy test."""
    _, apply, _, _ = make_network(config, env)
    mask = jnp.asarray(env.action_mask)

    return eps_greedy_policy(apply, mask)


def make_learner(config: IQLStarConfig, env: RoutingEnv) -> Learner:
    init_params, _, mlp, scale = make_network(config, env)
    policy_for = make_policy(config, env)
    n_cav, n_envs, n_days = env.n_cavs, config.num_envs, config.update_every
    n_iters = max(1, config.num_episodes // n_days)
    capacity = max(config.buffer_size, config.batch_size)
    tx = optax.adam(config.lr)
    varied = env.day_demand is not None  # demand varies day to day: per-CAV buffers, masked updates

    def agent_update(params: Any, opt_state: Any, obs: jnp.ndarray, action: jnp.ndarray, reward: jnp.ndarray,
                     key: jax.Array, size: jnp.ndarray):
        """One CAV: num_epochs minibatches of batch_size distinct samples from its buffer column."""
        def step(carry, k):
            params, opt_state = carry
            scores = jnp.where(jnp.arange(capacity) < size, jax.random.uniform(k, (capacity,)), -1.0)
            _, idx = jax.lax.top_k(scores, config.batch_size)

            def loss(p):
                return bandit_loss(mlp.apply(p, obs[idx] / scale), action[idx], reward[idx])

            return adam_step(tx, loss, params, opt_state)

        (params, opt_state), losses = jax.lax.scan(step, (params, opt_state),
                                                   jax.random.split(key, config.num_epochs))
        return params, opt_state, losses.mean()

    def init(key: jax.Array) -> RunnerState:
        k_init, k_env, _ = jax.random.split(key, 3)
        params = init_params(k_init)
        c, d = n_cav, env.obs_size
        example = Sample(jnp.zeros((c, d)), jnp.zeros((c,), jnp.int32), jnp.zeros((c,)))
        buffer = buffer_init_columns(example, capacity, c) if varied else buffer_init(example, capacity)
        return RunnerState(params, jax.vmap(tx.init)(params), buffer,
                           reset_envs(env, k_env, n_envs), env.default_params,
                           jnp.asarray(config.eps_init, jnp.float32))

    def policy(runner: RunnerState, explore: bool = True):
        return policy_for(runner.params, runner.eps if explore else 0.0)

    def update_from_days(runner: RunnerState, days: Day, key: jax.Array):
        if days.active is not None:
            return update_travelled(runner, days, key, days.active)
        buffer = buffer_add(runner.buffer, flatten_days(Sample(days.obs, days.action, days.reward)))
        data = buffer.data  # [cap, C, ...] -> per-CAV columns
        params, opt_state, loss = jax.vmap(agent_update, in_axes=(0, 0, 1, 1, 1, 0, None))(
            runner.params, runner.opt_state, data.obs, data.action, data.reward,
            jax.random.split(key, n_cav), buffer.size)
        ready = buffer.size >= config.batch_size
        params, opt_state = select_tree(ready, (params, opt_state), (runner.params, runner.opt_state))
        eps = jnp.where(ready, jnp.maximum(config.eps_min, runner.eps * config.eps_decay), runner.eps)
        metrics = day_metrics(days) | {"loss": loss.mean(), "eps": runner.eps}
        return runner._replace(params=params, opt_state=opt_state, buffer=buffer, eps=eps), metrics

    def update_travelled(runner: RunnerState, days: Day, key: jax.Array, active: jnp.ndarray):
        """The update under varying demand: each CAV stores and learns from the days it travelled
        (`active` [T, B, C]) only; a CAV at home on every one of `days` does not update."""
        went = flatten_days(active)  # [T*B, C]
        samples = flatten_days(Sample(days.obs, days.action, days.reward))
        buffer = buffer_add_where(runner.buffer, samples, went)
        data = buffer.data
        params, opt_state, loss = jax.vmap(agent_update, in_axes=(0, 0, 1, 1, 1, 0, 0))(
            runner.params, runner.opt_state, data.obs, data.action, data.reward,
            jax.random.split(key, n_cav), buffer.size)
        updated = went.any(axis=0) & (buffer.size >= config.batch_size)  # [C]

        def pick(new: jnp.ndarray, old: jnp.ndarray) -> jnp.ndarray:
            return jnp.where(updated.reshape(-1, *(1,) * (new.ndim - 1)), new, old)

        params, opt_state = jax.tree_util.tree_map(pick, (params, opt_state),
                                                   (runner.params, runner.opt_state))
        eps = jnp.where(updated.any(), jnp.maximum(config.eps_min, runner.eps * config.eps_decay), runner.eps)
        metrics = day_metrics(days) | {"loss": active_mean(loss, updated), "eps": runner.eps}
        return runner._replace(params=params, opt_state=opt_state, buffer=buffer, eps=eps), metrics

    iteration = collect_then_update(env, policy, update_from_days, n_days)
    return Learner(init, iteration, update_from_days, policy, n_iters, n_days)


def make_train(config: IQLStarConfig, env: RoutingEnv):
    return scan_train(make_learner(config, env), 3)
