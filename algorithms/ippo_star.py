"""IPPO* (URB's adjusted `scripts/ippo.py`): one policy network per CAV, PPO-clip as a bandit.

Each CAV has its own ReLU MLP (`widths`) -> masked logits, stacked on a leading [C] parameter axis
with its own Adam state and grad-norm clip (the update is vmapped over CAVs). CAVs sample from
softmax(logits) and store (observation, action, log-prob, day reward), one sample per CAV per day.
URB updates on the first day with `day % update_every == 0` and at least `batch_size` samples,
then clears the buffer: here one iteration collects exactly that many days
(`update_every * ceil(batch_size / (update_every * num_envs))` per env), then runs `num_epochs`
epochs, each on a random `batch_size` subset: ratio = exp(logp - logp_old), advantage = the
reward standardised over the minibatch (`normalize_advantage`) or the raw reward, loss =
-mean(min(ratio A, clip(ratio, 1 +- clip_eps) A)) - entropy_coef * entropy. No critic.

Demand varying day to day (the task's `day_participation`): a CAV's samples are the days it
travelled (`Day.active`). Its minibatch takes its travelled samples first (a random `batch_size`
of them; all of them when fewer), its loss and advantage standardisation average over those only,
and a CAV at home on every day of the update does not update.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from urb_jax.algorithms.configs import IPPOStarConfig
from urb_jax.algorithms.learner import (
    Day,
    Learner,
    active_mean,
    collect_then_update,
    day_metrics,
    reset_envs,
    scan_train,
)
from urb_jax.algorithms.networks import make_per_cav_mlp, take_agents
from urb_jax.algorithms.policy import entropy, masked
from urb_jax.algorithms.updates import adam_step, clipped_adam, days_shape, select_tree
from urb_jax.game.env import EnvParams, EnvState, RoutingEnv


class RunnerState(NamedTuple):
    params: Any  # leaves [C, ...]
    opt_state: Any
    env_states: EnvState
    env_params: EnvParams  # travel-time parameters the envs simulate with


def bandit_ppo_loss(logits: jnp.ndarray, action: jnp.ndarray, old_log_prob: jnp.ndarray, reward: jnp.ndarray,
                    clip_eps: float, entropy_coef: float, normalize: bool) -> jnp.ndarray:
    """One CAV's minibatch: logits [M, K] (masked), action/old_log_prob/reward [M]."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    logp_a = jnp.take_along_axis(logp, action[..., None], axis=-1)[..., 0]
    ratio = jnp.exp(logp_a - old_log_prob)
    adv = (reward - reward.mean()) / (reward.std() + 1e-8) if normalize else reward
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * adv)
    return -surrogate.mean() - entropy_coef * entropy(logits).mean()


def weighted_ppo_loss(logits: jnp.ndarray, action: jnp.ndarray, old_log_prob: jnp.ndarray,
                      reward: jnp.ndarray, weight: jnp.ndarray, clip_eps: float, entropy_coef: float,
                      normalize: bool) -> jnp.ndarray:
    """`bandit_ppo_loss` over the rows with `weight` [M] 1 (travelled) only: the means, and the
    advantage's mean and standard deviation, are over those rows (all rows 1: the same value)."""
    n = jnp.maximum(weight.sum(), 1.0)

    def mean(x: jnp.ndarray) -> jnp.ndarray:
        return (weight * x).sum() / n

    logp = jax.nn.log_softmax(logits, axis=-1)
    logp_a = jnp.take_along_axis(logp, action[..., None], axis=-1)[..., 0]
    ratio = jnp.exp(logp_a - old_log_prob)
    centred = reward - mean(reward)
    adv = centred / (jnp.sqrt(mean(centred ** 2)) + 1e-8) if normalize else reward
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * adv)
    return -mean(surrogate) - entropy_coef * mean(entropy(logits))


def days_per_update(config: IPPOStarConfig) -> int:
    per_env = math.ceil(config.batch_size / max(config.num_envs, 1))
    return config.update_every * math.ceil(per_env / config.update_every)


def make_network(config: IPPOStarConfig, env: RoutingEnv):
    """(init, apply, mlp, scale): one network per CAV (networks.make_per_cav_mlp)."""
    return make_per_cav_mlp(env, config.widths, config.normalize_obs)


def make_policy(config: IPPOStarConfig, env: RoutingEnv):
    """params -> policy(key, obs[C, D]) -> actions[C]; sample=False is URB's argmax test."""
    _, apply, _, _ = make_network(config, env)
    mask = jnp.asarray(env.action_mask)

    def policy_for(params: Any, sample: bool = True):
        def policy(key: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
            logits = masked(apply(params, obs, idx), take_agents(mask, idx))
            if sample:
                return jax.random.categorical(key, logits, axis=-1).astype(jnp.int32)
            return jnp.argmax(logits, axis=-1).astype(jnp.int32)

        return policy

    return policy_for


def make_learner(config: IPPOStarConfig, env: RoutingEnv) -> Learner:
    init_params, apply, mlp, scale = make_network(config, env)
    policy_for = make_policy(config, env)
    mask = jnp.asarray(env.action_mask)
    n_days = days_per_update(config)
    n_iters = max(1, config.num_episodes // n_days)
    tx = clipped_adam(config.max_grad_norm, config.lr)

    def agent_update(params: Any, opt_state: Any, obs: jnp.ndarray, action: jnp.ndarray,
                     logp_old: jnp.ndarray, reward: jnp.ndarray, mask_c: jnp.ndarray, key: jax.Array,
                     n_samples: int):
        """One CAV, its n_samples samples: num_epochs epochs on random batch_size subsets."""
        batch = min(config.batch_size, n_samples)

        def step(carry, k):
            params, opt_state = carry
            idx = jax.random.permutation(k, n_samples)[:batch]

            def loss(p):
                logits = masked(mlp.apply(p, obs[idx] / scale), mask_c)
                return bandit_ppo_loss(logits, action[idx], logp_old[idx], reward[idx], config.clip_eps,
                                       config.entropy_coef, config.normalize_advantage)

            return adam_step(tx, loss, params, opt_state)

        (params, opt_state), losses = jax.lax.scan(step, (params, opt_state),
                                                   jax.random.split(key, config.num_epochs))
        return params, opt_state, losses.mean()

    def agent_update_travelled(params: Any, opt_state: Any, obs: jnp.ndarray, action: jnp.ndarray,
                               logp_old: jnp.ndarray, reward: jnp.ndarray, mask_c: jnp.ndarray,
                               went: jnp.ndarray, key: jax.Array, n_samples: int):
        """One CAV under varying demand: its samples of days it travelled (`went` [n_samples])
        first in each epoch's subset; no update when it travelled on none."""
        batch = min(config.batch_size, n_samples)

        def step(carry, k):
            params, opt_state = carry
            _, idx = jax.lax.top_k(jnp.where(went, jax.random.uniform(k, (n_samples,)), -1.0), batch)

            def loss(p):
                logits = masked(mlp.apply(p, obs[idx] / scale), mask_c)
                return weighted_ppo_loss(logits, action[idx], logp_old[idx], reward[idx],
                                         went[idx].astype(jnp.float32), config.clip_eps, config.entropy_coef,
                                         config.normalize_advantage)

            return adam_step(tx, loss, params, opt_state)

        (new_params, new_opt), losses = jax.lax.scan(step, (params, opt_state),
                                                     jax.random.split(key, config.num_epochs))
        kept_params, kept_opt = select_tree(went.any(), (new_params, new_opt), (params, opt_state))
        return kept_params, kept_opt, losses.mean()

    def init(key: jax.Array) -> RunnerState:
        k_init, k_env, _ = jax.random.split(key, 3)
        params = init_params(k_init)
        return RunnerState(params, jax.vmap(tx.init)(params), reset_envs(env, k_env, config.num_envs),
                           env.default_params)

    def policy(runner: RunnerState, explore: bool = True):
        return policy_for(runner.params, sample=explore)

    def update_from_days(runner: RunnerState, days: Day, key: jax.Array):
        """On-policy: `days` must have been played by `policy(runner, True)`."""
        t, b = days_shape(days)
        logits = masked(apply(runner.params, days.obs), mask)
        logp = jnp.take_along_axis(jax.nn.log_softmax(logits), days.action[..., None], -1)[..., 0]

        def per_cav(x: jnp.ndarray) -> jnp.ndarray:  # [T, B, C, ...] -> [C, T*B, ...]
            return jnp.moveaxis(x.reshape(t * b, *x.shape[2:]), 1, 0)

        if days.active is not None:  # varying demand: each CAV learns from the days it travelled
            params, opt_state, loss = jax.vmap(functools.partial(agent_update_travelled, n_samples=t * b))(
                runner.params, runner.opt_state, per_cav(days.obs), per_cav(days.action), per_cav(logp),
                per_cav(days.reward), mask, per_cav(days.active), jax.random.split(key, env.n_cavs))
            went = days.active.any(axis=(0, 1))
            metrics = day_metrics(days) | {"loss": active_mean(loss, went)}
            return runner._replace(params=params, opt_state=opt_state), metrics
        params, opt_state, loss = jax.vmap(functools.partial(agent_update, n_samples=t * b))(
            runner.params, runner.opt_state, per_cav(days.obs), per_cav(days.action), per_cav(logp),
            per_cav(days.reward), mask, jax.random.split(key, env.n_cavs))
        metrics = day_metrics(days) | {"loss": loss.mean()}
        return runner._replace(params=params, opt_state=opt_state), metrics

    iteration = collect_then_update(env, policy, update_from_days, n_days)
    return Learner(init, iteration, update_from_days, policy, n_iters, n_days)


def make_train(config: IPPOStarConfig, env: RoutingEnv):
    return scan_train(make_learner(config, env), 3)
