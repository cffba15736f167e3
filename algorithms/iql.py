"""IQL (URB's `iql_torchrl.py`): independent DQN learners, shared parameters + OD embedding.

Per iteration: collect `agent_frames_per_batch` days in each of `num_envs` envs with an
epsilon-greedy policy (epsilon linear eps_init -> eps_end over exploration_fraction of the
training days), append the days to a ring replay buffer, then `num_epochs` epochs of
`max(1, frames // minibatch_size)` Adam steps each on TD(0) targets
y = r + gamma * (1 - done) * max_a' Q_target(s', a') with the CAV's own reward; the target is
mixed `target <- eps * target + (1 - eps) * online` once per epoch (URB key `eps`, `tau` unused).
URB's episodes are one day (done every day), so y = r: a contextual bandit per day.
`num_minibatches > 0` replaces URB's step count by a fixed one (updates.update_plan).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from urb_jax.algorithms.buffer import Buffer, buffer_add, buffer_init
from urb_jax.algorithms.configs import IQLConfig
from urb_jax.algorithms.frames import make_replay
from urb_jax.algorithms.learner import (
    Day,
    Learner,
    active_mean,
    collect_then_update,
    day_metrics,
    reset_envs,
    scan_train,
)
from urb_jax.algorithms.networks import hidden_layers, make_agent_net
from urb_jax.algorithms.policy import eps_greedy_policy, linear_schedule, masked
from urb_jax.algorithms.updates import (
    adam_step,
    clipped_adam,
    days_shape,
    flatten_days,
    polyak,
    select_tree,
    update_plan,
)
from urb_jax.game.env import EnvParams, EnvState, RoutingEnv


class RunnerState(NamedTuple):
    params: Any
    target: Any
    opt_state: Any
    buffer: Buffer
    env_states: EnvState
    env_params: EnvParams  # travel-time parameters the envs simulate with
    day: jnp.ndarray  # training days so far (per env)


def td_loss(q_apply, params: Any, target: Any, batch: Day, mask: jnp.ndarray, gamma: float) -> jnp.ndarray:
    """Mean squared TD(0) error over every CAV of every day in the batch (that travelled that day:
    `Day.active`)."""
    q = q_apply(params, batch.obs)  # [M, C, K]
    q_a = jnp.take_along_axis(q, batch.action[..., None], axis=-1)[..., 0]
    q_next = masked(q_apply(target, batch.next_obs), mask).max(-1)
    y = batch.reward + gamma * (1.0 - batch.done.astype(jnp.float32)) * q_next
    return active_mean((q_a - jax.lax.stop_gradient(y)) ** 2, batch.active)


def make_network(config: IQLConfig, env: RoutingEnv):
    return make_agent_net(env, hidden_layers(config.mlp_depth, config.mlp_cells), env.n_actions, "relu",
                          shared=config.shared_parameters, embed_dim=config.od_embedding_dim,
                          normalize=config.normalize_obs)


def make_policy(config: IQLConfig, env: RoutingEnv):
    """(params, eps) -> policy(key, obs[C, D]) -> actions[C]; eps=0 is the greedy test policy."""
    net = make_network(config, env)
    mask = jnp.asarray(env.action_mask)

    return eps_greedy_policy(net.apply, mask)


def make_learner(config: IQLConfig, env: RoutingEnv) -> Learner:
    net = make_network(config, env)
    policy_for = make_policy(config, env)
    mask = jnp.asarray(env.action_mask)
    n_cav, n_envs, n_days = env.n_cavs, config.num_envs, config.agent_frames_per_batch
    _, mb_iter = update_plan(config.num_minibatches, config.minibatch_size, n_days * n_envs, n_cav)
    capacity = max(config.memory_size // max(n_cav, 1), mb_iter)  # memory_size frames, stored as days
    replay = make_replay(config.frames, env, config.num_minibatches, config.minibatch_size, capacity)
    total_days = n_days * config.n_iters
    eps_at = linear_schedule(config.eps_init, config.eps_end, config.exploration_fraction * total_days)
    tx = clipped_adam(config.max_grad_norm, config.lr)

    def loss_fn(params: Any, target: Any, batch: Day) -> jnp.ndarray:
        return td_loss(net.apply, params, target, batch, mask, config.gamma)

    def init(key: jax.Array) -> RunnerState:
        k_init, k_env, _ = jax.random.split(key, 3)
        params = net.init(k_init)
        env_states = reset_envs(env, k_env, n_envs)
        template = Day.zeros(n_cav, env.obs_size, active=env.day_demand is not None)
        return RunnerState(params, params, tx.init(params), buffer_init(replay.example(template), capacity),
                           env_states, env.default_params, jnp.zeros((), jnp.int32))

    def policy(runner: RunnerState, explore: bool = True):
        return policy_for(runner.params, eps_at(runner.day) if explore else 0.0)

    def update_from_days(runner: RunnerState, days: Day, key: jax.Array):
        t, b = days_shape(days)
        steps_per_epoch, mb = replay.plan(t * b)
        q_fn = functools.partial(net.apply, runner.params)  # the policy that emitted the days
        buffer = buffer_add(runner.buffer, replay.store(key, q_fn, eps_at(runner.day), flatten_days(days)))

        def epoch(carry, k):
            params, target, opt_state = carry

            def sgd_step(carry, k):
                params, opt_state = carry
                batch = replay.sample(buffer, k, mb)
                return adam_step(tx, loss_fn, params, opt_state, target, batch)

            (params, opt_state), losses = jax.lax.scan(
                sgd_step, (params, opt_state), jax.random.split(k, steps_per_epoch))
            return (params, polyak(target, params, config.target_eps), opt_state), losses.mean()

        (params, target, opt_state), losses = jax.lax.scan(
            epoch, (runner.params, runner.target, runner.opt_state), jax.random.split(key, config.num_epochs))
        ready = replay.ready(buffer, mb)
        params, target, opt_state = select_tree(
            ready, (params, target, opt_state), (runner.params, runner.target, runner.opt_state))
        metrics = day_metrics(days) | {"loss": losses.mean()}
        return runner._replace(params=params, target=target, opt_state=opt_state, buffer=buffer,
                               day=runner.day + t), metrics

    iteration = collect_then_update(env, policy, update_from_days, n_days,
                                    exploration=lambda runner: {"eps": eps_at(runner.day)})
    return Learner(init, iteration, update_from_days, policy, config.n_iters, n_days)


def make_train(config: IQLConfig, env: RoutingEnv):
    return scan_train(make_learner(config, env), 3)
