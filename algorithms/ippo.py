"""IPPO (URB's `ippo_torchrl.py`): independent PPO, shared parameters + OD embedding.

Actor: Tanh MLP -> masked categorical logits (sampled in training and, as URB tests, or argmax).
Critic: ReLU MLP on the CAV's own observation (+ OD embedding). Per iteration: collect
`agent_frames_per_batch` days in each of `num_envs` envs, GAE(gamma, lmbda) over the days (a done
day does not bootstrap: URB's one-day episodes make advantage = reward - V(obs)), then
`num_epochs` epochs over shuffled minibatches of whole days with the clipped PPO objective,
entropy bonus `entropy_eps`, smooth-L1 critic loss (TorchRL default, coefficient `critic_coef`)
and optional advantage normalisation; one Adam (grad-norm clip) on both. `num_minibatches` > 0
splits each epoch into that many minibatches (PureJaxRL) instead of URB's fixed-size ones.
`frames="urb"` trains on URB's TorchRL frames instead (algorithms/frames.py): C frames per day,
each with every CAV's row and a freshly sampled action outside its turn, GAE run across the
frames (the day's reward arrives on its last frame), minibatches of `minibatch_size` frames.

Advantage normalisation is over the whole iteration's batch, not per minibatch as TorchRL does:
with a cooperative reward and a broadcast centralised value every CAV of a day has the same
advantage, so a one-day minibatch (minibatch_size < 2C) would normalise it to zero.

`make_train(config, env, centralised=True)` is MAPPO (see mappo.py): the critic sees the global
state (every CAV's observation) and its single value is broadcast to all CAVs.
"""

from __future__ import annotations

from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import optax

from urb_jax.algorithms.configs import PPOConfig
from urb_jax.algorithms.frames import frame_obs, turn_positions, unacted
from urb_jax.algorithms.learner import (
    Day,
    Learner,
    active_mean,
    collect_then_update,
    day_metrics,
    reset_envs,
    scan_train,
)
from urb_jax.algorithms.networks import MLP, hidden_layers, make_agent_net, obs_scale, take_agents
from urb_jax.algorithms.policy import entropy, masked
from urb_jax.algorithms.updates import adam_step, clipped_adam, days_shape, flatten_days, gae, minibatch_days
from urb_jax.game.env import EnvParams, EnvState, RoutingEnv


class RunnerState(NamedTuple):
    params: Any  # {"actor": ..., "critic": ...}
    opt_state: Any
    env_states: EnvState
    env_params: EnvParams  # travel-time parameters the envs simulate with


class Batch(NamedTuple):
    obs: jnp.ndarray  # [M, C, D]
    action: jnp.ndarray  # [M, C]
    log_prob: jnp.ndarray  # [M, C] behaviour policy
    advantage: jnp.ndarray  # [M, C]
    target: jnp.ndarray  # [M, C] value target (GAE return)
    active: jnp.ndarray | None = None  # [M, C] the CAVs that travelled (Day.active); None: all


def ppo_loss(actor_logits: jnp.ndarray, values: jnp.ndarray, batch: Batch, clip_eps: float,
             entropy_coef: float, critic_coef: float) -> tuple[jnp.ndarray, dict[str, jnp.ndarray]]:
    """Clipped surrogate + critic smooth-L1 - entropy bonus, means over every CAV-day sample."""
    logp = jax.nn.log_softmax(actor_logits, axis=-1)
    logp_a = jnp.take_along_axis(logp, batch.action[..., None], axis=-1)[..., 0]
    ratio = jnp.exp(logp_a - batch.log_prob)
    adv = batch.advantage
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * adv)
    policy_loss = -active_mean(surrogate, batch.active)
    value_loss = active_mean(optax.huber_loss(values, batch.target, delta=1.0), batch.active)
    ent = active_mean(entropy(actor_logits), batch.active)
    total = policy_loss + critic_coef * value_loss - entropy_coef * ent
    return total, {"policy_loss": policy_loss, "value_loss": value_loss, "entropy": ent}


def make_networks(config: PPOConfig, env: RoutingEnv, centralised: bool = False):
    """(actor AgentNet, critic init, critic apply(params, obs[..., C, D]) -> values[..., C])."""
    actor = make_agent_net(env, hidden_layers(config.mlp_depth, config.mlp_cells), env.n_actions, "tanh",
                           shared=config.shared_parameters, embed_dim=config.od_embedding_dim,
                           normalize=config.normalize_obs)
    critic_hidden = hidden_layers(config.critic_depth, config.critic_cells)
    if not centralised:
        net = make_agent_net(env, critic_hidden, 1, "relu", shared=config.shared_parameters,
                             embed_dim=config.od_embedding_dim, normalize=config.normalize_obs)
        return actor, net.init, lambda p, obs: net.apply(p, obs)[..., 0]
    scale = jnp.asarray(obs_scale(env)) if config.normalize_obs else 1.0
    n_cav = env.n_cavs
    # Shared parameters (URB): one value for the team, broadcast to every CAV. Per-CAV parameters
    # (TorchRL's centralised critic without sharing): one value head per CAV on the global state,
    # here as C heads on one trunk, so each CAV's own-reward advantage has its own baseline.
    heads = 1 if config.shared_parameters else n_cav
    mlp = MLP(critic_hidden, heads, "relu")

    def critic_init(key: jax.Array) -> Any:
        return mlp.init(key, jnp.zeros((env.n_cavs * env.obs_size,)))

    def critic_apply(params: Any, obs: jnp.ndarray) -> jnp.ndarray:
        state = env.global_state(obs / scale)  # [..., C * D]
        value = cast(jax.Array, mlp.apply(params, state))  # [..., 1] or [..., C]
        return jnp.broadcast_to(value, (*value.shape[:-1], n_cav))

    return actor, critic_init, critic_apply


def make_policy(config: PPOConfig, env: RoutingEnv, centralised: bool = False):
    """params -> policy(key, obs[C, D]) -> actions[C]; sample=False is the argmax test policy."""
    actor, _, _ = make_networks(config, env, centralised)
    mask = jnp.asarray(env.action_mask)

    def policy_for(params: Any, sample: bool = True):
        def policy(key: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
            logits = masked(actor.apply(params["actor"], obs, idx), take_agents(mask, idx))
            if sample:
                return jax.random.categorical(key, logits, axis=-1).astype(jnp.int32)
            return jnp.argmax(logits, axis=-1).astype(jnp.int32)

        return policy

    return policy_for


def frame_batch(logits_fn, value_fn, days: Day, turn: jnp.ndarray, k: int, key: jax.Array, gamma: float,
                lmbda: float) -> Batch:
    """[T * C, B] URB frames in play order (algorithms/frames.py) from days [T, B] played by the
    policy with masked logits `logits_fn(obs[..., C, D])`: frame j of a day has every CAV's frame
    observation, the turn CAV's executed action and fresh samples for the others; GAE runs across
    the frames with the day's reward and done on its last frame. `value_fn(obs[..., C, D]) ->
    [..., C]` is the critic (own observation, or the frame's global state for MAPPO)."""
    t, b = days_shape(days)
    n_cav = turn.shape[0]
    frames = jnp.arange(n_cav)
    acted = turn <= frames[:, None]  # [Cf, C]
    obs = frame_obs(days.obs[:, :, None], turn, frames[None, None], k)  # [T, B, Cf, C, D]
    logits_acted = logits_fn(days.obs)[:, :, None]  # [T, B, 1, C, K]: two evaluations per CAV-day
    logits_before = logits_fn(unacted(days.obs, k))[:, :, None]
    logits = jnp.where(acted[..., None], logits_acted, logits_before)  # [T, B, Cf, C, K]
    drawn = jax.random.categorical(key, logits, axis=-1)
    action = jnp.where(turn == frames[:, None], days.action[:, :, None], drawn).astype(jnp.int32)
    log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], -1)[..., 0]
    values = value_fn(obs)  # [T, B, Cf, C]
    last = frames == n_cav - 1
    reward = jnp.where(last[:, None], days.reward[:, :, None], 0.0)
    done = jnp.broadcast_to(last[:, None], reward.shape)

    def in_play_order(x: jnp.ndarray) -> jnp.ndarray:  # [T, B, Cf, ...] -> [T * Cf, B, ...]
        return jnp.moveaxis(x, 2, 1).reshape(t * n_cav, b, *x.shape[3:])

    adv, targets = gae(in_play_order(reward), in_play_order(values), in_play_order(done),
                       jnp.zeros((b, n_cav)), gamma, lmbda)
    return Batch(in_play_order(obs), in_play_order(action), in_play_order(log_prob), adv, targets)


def make_learner(config: PPOConfig, env: RoutingEnv, centralised: bool = False) -> Learner:
    actor, critic_init, critic_apply = make_networks(config, env, centralised)
    policy_for = make_policy(config, env, centralised)
    mask = jnp.asarray(env.action_mask)
    n_envs, n_days = config.num_envs, config.agent_frames_per_batch
    tx = clipped_adam(config.max_grad_norm, config.lr)

    def loss_fn(params: Any, batch: Batch):
        logits = masked(actor.apply(params["actor"], batch.obs), mask)
        values = critic_apply(params["critic"], batch.obs)
        return ppo_loss(logits, values, batch, config.clip_epsilon, config.entropy_eps, config.critic_coef)

    def init(key: jax.Array) -> RunnerState:
        k_actor, k_critic, k_env, _ = jax.random.split(key, 4)
        params = {"actor": actor.init(k_actor), "critic": critic_init(k_critic)}
        return RunnerState(params, tx.init(params), reset_envs(env, k_env, n_envs), env.default_params)

    def policy(runner: RunnerState, explore: bool = True):
        return policy_for(runner.params, sample=explore)

    def day_batch(params: Any, days: Day) -> Batch:
        """[T, B] rows: each CAV's decision of each day, GAE over the days."""
        logits = masked(actor.apply(params["actor"], days.obs), mask)
        log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), days.action[..., None], -1)[..., 0]
        values = critic_apply(params["critic"], days.obs)  # [T, B, C]
        last_value = critic_apply(params["critic"], days.next_obs[-1])
        adv, targets = gae(days.reward, values, days.done, last_value, config.gamma, config.lmbda)
        return Batch(days.obs, days.action, log_prob, adv, targets, days.active)

    turn = jnp.asarray(turn_positions(env))
    n_cav = env.n_cavs

    def update_from_days(runner: RunnerState, days: Day, key: jax.Array):
        """On-policy: `days` must have been played by `policy(runner, True)`."""
        t, b = days_shape(days)
        params = runner.params
        if config.frames == "urb":  # URB: minibatches of minibatch_size frames
            key, k_frames = jax.random.split(key)
            batch = frame_batch(lambda obs: masked(actor.apply(params["actor"], obs), mask),
                                lambda obs: critic_apply(params["critic"], obs), days, turn, env.n_actions,
                                k_frames, config.gamma, config.lmbda)
            total = t * b * n_cav
            mb = min(config.minibatch_size, total)  # frames
            n_minibatches = max(1, total // mb)
        else:
            batch = day_batch(params, days)
            total = t * b
            if config.num_minibatches > 0:  # PureJaxRL: a fixed count of minibatches that grow with B
                n_minibatches = min(config.num_minibatches, total)
                mb = total // n_minibatches
            else:  # URB: minibatches of minibatch_size samples, B times as many with B envs
                mb = min(minibatch_days(config.minibatch_size, env.n_cavs), total)
                n_minibatches = max(1, total // mb)
        adv = batch.advantage
        if config.normalize_advantage and batch.active is not None:  # over the CAVs that travelled
            mean = active_mean(adv, batch.active)
            adv = (adv - mean) / (jnp.sqrt(active_mean((adv - mean) ** 2, batch.active)) + 1e-8)
        elif config.normalize_advantage:  # over the iteration's batch: see module docstring
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        data = flatten_days(batch._replace(advantage=adv))

        def epoch(carry, k):
            perm = jax.random.permutation(k, total)[: n_minibatches * mb]
            shuffled = jax.tree_util.tree_map(
                lambda x: x[perm].reshape(n_minibatches, mb, *x.shape[1:]), data)

            def sgd_step(carry, batch: Batch):
                params, opt_state = carry
                carry, (loss, aux) = adam_step(tx, loss_fn, params, opt_state, batch, has_aux=True)
                return carry, aux | {"loss": loss}

            return jax.lax.scan(sgd_step, carry, shuffled)

        (params, opt_state), aux = jax.lax.scan(
            epoch, (params, runner.opt_state), jax.random.split(key, config.num_epochs))
        metrics = day_metrics(days) | jax.tree_util.tree_map(jnp.mean, aux)
        return runner._replace(params=params, opt_state=opt_state), metrics

    iteration = collect_then_update(env, policy, update_from_days, n_days)
    return Learner(init, iteration, update_from_days, policy, config.n_iters, n_days)


def make_train(config: PPOConfig, env: RoutingEnv, centralised: bool = False):
    return scan_train(make_learner(config, env, centralised), 4)
