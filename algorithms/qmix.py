"""QMIX (URB's `qmix_torchrl.py`): per-CAV Q networks (Tanh, shared parameters + OD embedding)
mixed by a monotonic hypernetwork into Q_tot, trained on the team reward (mean CAV reward).

Mixer (Rashid et al. 2018, TorchRL's QMixer): from the global state s (every CAV's scaled
observation, flattened), W1 = |Hyper_w1(s)| [C, E], b1 = Hyper_b1(s), h = elu(q W1 + b1),
w2 = |Hyper_w2(s)| [E], V(s) = two-layer hypernet; Q_tot = h . w2 + V(s). Hyper_w1/w2 are one
linear layer (URB) or, with `hypernet_hidden` > 0, two layers with a ReLU (pymarl). Non-negative weights
make dQ_tot/dq_i >= 0, so per-CAV argmax is the joint argmax. `mixer="vdn"` is VDN (sum).

Replay of whole days (memory_size frames = memory_size // C days); TD(0) target
y = r_team + gamma * (1 - done) * Q_tot_target(max_a Q_target(s'), s'); soft target update
target <- (1 - tau) target + tau online after every gradient step; epsilon-greedy as IQL.
`q_scale="own"` feeds q_i / C to the mixer so per-CAV Qs keep one CAV's scale (docs/algorithms.md).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

from urb_jax.algorithms.buffer import Buffer, buffer_add, buffer_init
from urb_jax.algorithms.configs import MixerConfig
from urb_jax.algorithms.frames import make_replay
from urb_jax.algorithms.learner import Day, Learner, collect_then_update, day_metrics, reset_envs, scan_train
from urb_jax.algorithms.networks import WideDense, hidden_layers, make_agent_net, obs_scale
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


class QMixer(nn.Module):
    """hypernet_hidden = 0: URB's (TorchRL) single linear layer state -> C x E weights (S*C*E
    parameters: 7.4 M on saint_arnoult); > 0: pymarl's state -> hidden (ReLU) -> weights for W1 and
    w2, S*H + H*C*E parameters."""

    n_agents: int
    embed_dim: int
    hypernet_hidden: int = 0

    def hyper(self, name: str, out: int, state: jnp.ndarray) -> jnp.ndarray:
        if self.hypernet_hidden <= 0:
            return WideDense(out, name=name)(state)
        hidden = nn.relu(WideDense(self.hypernet_hidden, name=f"{name}_hidden")(state))
        return WideDense(out, name=name)(hidden)

    @nn.compact
    def __call__(self, q: jnp.ndarray, state: jnp.ndarray) -> jnp.ndarray:
        """q [..., C] chosen-action values, state [..., S] -> Q_tot [...]."""
        e = self.embed_dim
        w1 = jnp.abs(self.hyper("hyper_w1", self.n_agents * e, state)).reshape(*q.shape, e)
        b1 = WideDense(e, name="hyper_b1")(state)
        hidden = nn.elu(jnp.einsum("...c,...ce->...e", q, w1) + b1)
        w2 = jnp.abs(self.hyper("hyper_w2", e, state))
        v = nn.Dense(1, name="hyper_v2")(nn.relu(WideDense(e, name="hyper_v1")(state)))[..., 0]
        return (hidden * w2).sum(-1) + v


class VDNMixer(nn.Module):
    @nn.compact
    def __call__(self, q: jnp.ndarray, state: jnp.ndarray) -> jnp.ndarray:
        return q.sum(-1)


class RunnerState(NamedTuple):
    params: Any  # {"agent": ..., "mixer": ...}
    target: Any
    opt_state: Any
    buffer: Buffer
    env_states: EnvState
    env_params: EnvParams  # travel-time parameters the envs simulate with
    day: jnp.ndarray


def make_mixer(config: MixerConfig, env: RoutingEnv, mixer: str) -> nn.Module:
    if mixer == "qmix":
        return QMixer(env.n_cavs, config.mixing_embed_dim, config.hypernet_hidden)
    return VDNMixer()


def mixed_td_loss(q_apply, mix_apply, params: Any, target: Any, batch: Day, mask: jnp.ndarray,
                  gamma: float, state_fn, q_scale: float = 1.0, agent_credit: float = 0.0) -> jnp.ndarray:
    """Mean squared TD(0) error of Q_tot on the team reward (mean over CAVs) per day; the mixer
    sees each CAV's Q times `q_scale` (1, or 1/C for per-CAV Qs on their own scale). `agent_credit`
    > 0 adds that weight times each CAV's own TD error (Q_i toward its own reward, on the scale the
    mixer gives Q_i: reward / (C q_scale))."""
    q = q_apply(params["agent"], batch.obs)  # [M, C, K]
    q_a = jnp.take_along_axis(q, batch.action[..., None], axis=-1)[..., 0]
    q_tot = mix_apply(params["mixer"], q_scale * q_a, state_fn(batch.obs))
    q_next = masked(q_apply(target["agent"], batch.next_obs), mask).max(-1)
    q_tot_next = mix_apply(target["mixer"], q_scale * q_next, state_fn(batch.next_obs))
    team_reward = batch.reward.mean(-1)
    done = batch.done.all(-1).astype(jnp.float32)
    y = team_reward + gamma * (1.0 - done) * q_tot_next
    loss = jnp.mean((q_tot - jax.lax.stop_gradient(y)) ** 2)
    if agent_credit > 0.0:  # static: URB's loss compiles without it
        unit = 1.0 / (q_a.shape[-1] * q_scale)  # the share of the team reward one Q_i stands for
        y_i = unit * batch.reward + gamma * (1.0 - batch.done.astype(jnp.float32)) * q_next
        loss = loss + agent_credit * jnp.mean((q_a - jax.lax.stop_gradient(y_i)) ** 2)
    return loss


def make_network(config: MixerConfig, env: RoutingEnv):
    return make_agent_net(env, hidden_layers(config.mlp_depth, config.mlp_cells), env.n_actions, "tanh",
                          shared=config.shared_parameters, embed_dim=config.od_embedding_dim,
                          normalize=config.normalize_obs)


def make_policy(config: MixerConfig, env: RoutingEnv):
    """(params, eps) -> policy(key, obs[C, D]) -> actions[C] (eps=0: greedy test policy)."""
    net = make_network(config, env)
    mask = jnp.asarray(env.action_mask)

    return eps_greedy_policy(lambda p, obs, idx=None: net.apply(p["agent"], obs, idx), mask)


def make_learner(config: MixerConfig, env: RoutingEnv, mixer: str = "qmix") -> Learner:
    net = make_network(config, env)
    mix = make_mixer(config, env, mixer)
    policy_for = make_policy(config, env)
    mask = jnp.asarray(env.action_mask)
    scale = jnp.asarray(obs_scale(env)) if config.normalize_obs else 1.0
    n_cav, n_envs, n_days = env.n_cavs, config.num_envs, config.agent_frames_per_batch
    _, mb_iter = update_plan(config.num_minibatches, config.minibatch_size, n_days * n_envs, n_cav)
    capacity = max(config.memory_size // max(n_cav, 1), mb_iter)
    replay = make_replay(config.frames, env, config.num_minibatches, config.minibatch_size, capacity)
    eps_at = linear_schedule(config.eps_init, config.eps_end,
                             config.exploration_fraction * n_days * config.n_iters)
    tx = clipped_adam(config.max_grad_norm, config.lr, fused_clip=mixer == "qmix")

    q_scale = 1.0 / max(n_cav, 1) if config.q_scale == "own" else 1.0

    def state_fn(obs: jnp.ndarray) -> jnp.ndarray:
        return env.global_state(obs / scale)

    def loss_fn(params: Any, target: Any, batch: Day) -> jnp.ndarray:
        return mixed_td_loss(net.apply, mix.apply, params, target, batch, mask, config.gamma, state_fn,
                             q_scale, config.agent_credit)

    def init(key: jax.Array) -> RunnerState:
        k_agent, k_mix, k_env, _ = jax.random.split(key, 4)
        c, d = n_cav, env.obs_size
        params = {"agent": net.init(k_agent),
                  "mixer": mix.init(k_mix, jnp.zeros((c,)), jnp.zeros((c * d,)))}
        return RunnerState(params, params, tx.init(params),
                           buffer_init(replay.example(Day.zeros(c, d)), capacity),
                           reset_envs(env, k_env, n_envs), env.default_params, jnp.zeros((), jnp.int32))

    def policy(runner: RunnerState, explore: bool = True):
        return policy_for(runner.params, eps_at(runner.day) if explore else 0.0)

    def update_from_days(runner: RunnerState, days: Day, key: jax.Array):
        t, b = days_shape(days)
        steps_per_epoch, mb = replay.plan(t * b)
        n_steps = config.num_epochs * steps_per_epoch
        q_fn = functools.partial(net.apply, runner.params["agent"])  # the policy that emitted the days
        buffer = buffer_add(runner.buffer, replay.store(key, q_fn, eps_at(runner.day), flatten_days(days)))

        def sgd_step(carry, k):
            params, target, opt_state = carry
            batch = replay.sample(buffer, k, mb)
            (params, opt_state), loss = adam_step(tx, loss_fn, params, opt_state, target, batch)
            return (params, polyak(target, params, 1.0 - config.tau), opt_state), loss

        old = (runner.params, runner.target, runner.opt_state)
        new, losses = jax.lax.scan(sgd_step, old, jax.random.split(key, n_steps))
        params, target, opt_state = select_tree(replay.ready(buffer, mb), new, old)
        metrics = day_metrics(days) | {"loss": losses.mean()}
        return runner._replace(params=params, target=target, opt_state=opt_state, buffer=buffer,
                               day=runner.day + t), metrics

    iteration = collect_then_update(env, policy, update_from_days, n_days,
                                    exploration=lambda runner: {"eps": eps_at(runner.day)})
    return Learner(init, iteration, update_from_days, policy, config.n_iters, n_days)


def make_train(config: MixerConfig, env: RoutingEnv, mixer: str = "qmix"):
    return scan_train(make_learner(config, env, mixer), 4)
