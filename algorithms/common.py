"""Shared pieces of the vectorised MARL algorithms (PureJaxRL / JaxMARL style).

Networks (flax linen, used functionally), observation scaling, OD embedding, shared or per-CAV
parameters, invalid-action masking, exploration schedules, a jitted ring replay buffer, the
day-collection loop (vmap over environments, lax.scan over days) and typed configs. Every
algorithm file builds on these and stays one readable `make_train`.

Units: a *sample* is one CAV's decision on one day (URB's "frame" is one CAV decision too, but it
carries every CAV's row; we keep only the real one). Update counts follow URB: per iteration
`num_epochs * max(1, frames // minibatch_size)` gradient steps, with frames = CAVs x days
collected, and a minibatch of `minibatch_size` samples taken as `max(1, minibatch_size // C)`
whole days, so joint methods (MAPPO, QMIX, VDN) see complete days.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from urb_jax.core.configio import find_config, load_json
from urb_jax.game.env import EnvState, RoutingEnv

NEG = -1e9
ACTIVATIONS: dict[str, Callable[[jnp.ndarray], jnp.ndarray]] = {
    "relu": nn.relu, "tanh": nn.tanh, "elu": nn.elu,
}


# ----------------------------------------------------------------------------- configs
@dataclass(frozen=True)
class TorchRLCommon:
    """Keys shared by URB's TorchRL configs (URB_REFERENCE §8) plus our vectorisation options."""

    agent_frames_per_batch: int = 20  # days collected per env per iteration
    n_iters: int = 200
    num_epochs: int = 2
    minibatch_size: int = 256  # samples (CAV decisions); taken as whole days
    mlp_depth: int = 4
    mlp_cells: int = 256
    lr: float = 5e-4
    gamma: float = 0.95  # only matters across days when dones are not all true (see docs)
    max_grad_norm: float = 1.0
    od_embedding_dim: int = 8  # 0 disables the OD embedding
    shared_parameters: bool = True  # URB: shared; False = one network per CAV (leading axis)
    normalize_obs: bool = True  # URB feeds raw seconds; we scale (see obs_scale)
    num_envs: int = 1
    # 0 = URB's update count (frames // minibatch_size steps per epoch, B times as many with B envs);
    # > 0 = PureJaxRL: this many Adam steps per epoch, each on 1/num_minibatches of the iteration's
    # days (minibatches grow with B instead of the step count). See update_plan.
    num_minibatches: int = 0


@dataclass(frozen=True)
class IQLConfig(TorchRLCommon):
    memory_size: int = 20000  # samples
    eps_init: float = 1.0
    eps_end: float = 0.1
    exploration_fraction: float = 0.5
    target_eps: float = 0.99  # URB key `eps`: target <- eps*target + (1-eps)*online, once per epoch


@dataclass(frozen=True)
class PPOConfig(TorchRLCommon):
    """IPPO and MAPPO."""

    clip_epsilon: float = 0.2
    lmbda: float = 0.9
    entropy_eps: float = 1e-3
    normalize_advantage: bool = True
    critic_coef: float = 1.0
    critic_depth: int = 4
    critic_cells: int = 256


@dataclass(frozen=True)
class MixerConfig(TorchRLCommon):
    """QMIX and VDN."""

    memory_size: int = 30000
    tau: float = 0.01  # soft target update after every gradient step
    eps_init: float = 1.0
    eps_end: float = 0.1
    exploration_fraction: float = 0.6
    mixing_embed_dim: int = 192  # QMIX only
    hypernet_hidden: int = 0  # QMIX only: 0 = URB's single linear hypernetwork; > 0 = pymarl's two layers
    # "team" (URB): Q_tot = mixer(q) on the mean CAV reward, so a CAV's Q, and the gap between its
    # routes, is 1/C of its own travel time. "own": the mixer sees q / C, so each CAV's Q lives on
    # its own travel-time scale, which Adam resolves with hundreds of CAVs; Q_tot and the target are
    # unchanged (docs/algorithms.md, "Per-CAV Q scale").
    q_scale: str = "team"

    def __post_init__(self) -> None:
        if self.q_scale not in ("team", "own"):
            from urb_jax.core.errors import ConfigError

            raise ConfigError(f"key 'q_scale' is {self.q_scale!r}. Fix: use 'team' (URB) or 'own'.")


@dataclass(frozen=True)
class IQLStarConfig:
    """URB scripts/iql.py: one Q network per CAV, a bandit on its own day reward."""

    num_episodes: int = 4000  # training days (per env)
    eps_init: float = 1.0
    eps_decay: float = 0.9985
    eps_min: float = 0.0
    buffer_size: int = 2048
    batch_size: int = 32
    lr: float = 1e-3
    num_epochs: int = 1
    widths: tuple[int, ...] = (64, 64)
    update_every: int = 1
    normalize_obs: bool = True
    num_envs: int = 1


@dataclass(frozen=True)
class IPPOStarConfig:
    """URB scripts/ippo.py: one policy per CAV, PPO-clip on its own (standardised) day reward."""

    num_episodes: int = 4000
    batch_size: int = 64
    update_every: int = 2
    lr: float = 3e-4
    num_epochs: int = 3
    widths: tuple[int, ...] = (64, 64)
    clip_eps: float = 0.2
    normalize_advantage: bool = True
    entropy_coef: float = 0.01
    max_grad_norm: float = 1.0
    normalize_obs: bool = True
    num_envs: int = 1


CONFIG_CLASSES: dict[str, type] = {
    "iql": IQLConfig, "ippo": PPOConfig, "mappo": PPOConfig, "qmix": MixerConfig, "vdn": MixerConfig,
    "iql_star": IQLStarConfig, "ippo_star": IPPOStarConfig,
}


def load_algo_config(algorithm: str, name: str = "config1") -> Any:
    """configs/algo/<algorithm>/<name>.json (or a path) -> the algorithm's typed config."""
    if algorithm not in CONFIG_CLASSES:
        from urb_jax.core.errors import ConfigError

        raise ConfigError(f"unknown algorithm '{algorithm}'. Fix: use one of {', '.join(CONFIG_CLASSES)}.")
    return load_json(CONFIG_CLASSES[algorithm], find_config("algo", name, subdir=algorithm))


# ----------------------------------------------------------------------------- networks
class MLP(nn.Module):
    hidden: Sequence[int]
    out: int
    activation: str = "relu"

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        act = ACTIVATIONS[self.activation]
        for width in self.hidden:
            x = act(nn.Dense(width)(x))
        return nn.Dense(self.out)(x)


class ODNet(nn.Module):
    """MLP on [obs, embedding(OD)] (the TorchRL scripts' 8-dim OD embedding, one row per OD pair
    instead of URB's |origins|*|destinations| mostly unused rows)."""

    hidden: Sequence[int]
    out: int
    activation: str
    n_od: int
    embed_dim: int

    @nn.compact
    def __call__(self, obs: jnp.ndarray, od: jnp.ndarray) -> jnp.ndarray:
        x = obs
        if self.embed_dim > 0:
            emb = nn.Embed(self.n_od, self.embed_dim)(od)
            x = jnp.concatenate([obs, jnp.broadcast_to(emb, (*obs.shape[:-1], self.embed_dim))], axis=-1)
        return MLP(tuple(self.hidden), self.out, self.activation)(x)


def obs_scale(env: RoutingEnv) -> np.ndarray:
    """[D] divisor bringing observations to about [0, 1]: start time / latest departure, counts /
    largest group (URB feeds raw seconds, 0-1800, which saturates tanh networks)."""
    scn = env.scenario
    spec = env.obs_spec
    group_max = scn.n_agents if spec.kind == "global_previous_agents" else np.bincount(scn.agent_od).max()
    counts = np.full(env.n_actions, max(float(group_max), 1.0))
    if spec.kind == "previous_agents":
        return counts.astype(np.float32)
    return np.concatenate([[max(float(scn.agent_depart.max()), 1.0)], counts]).astype(np.float32)


class AgentNet(NamedTuple):
    """Functional per-CAV network: init(key) -> params; apply(params, obs[..., C, D]) -> [..., C, out],
    or apply(params, obs[..., n, D], idx[n]) for the subset `idx` of the CAV axis.

    Shared parameters: one set for all CAVs (with OD embedding). Per-agent: every leaf has a
    leading [C] axis and the network is vmapped over it."""

    init: Callable[[jax.Array], Any]
    apply: Callable[..., jnp.ndarray]


def make_agent_net(
    env: RoutingEnv, hidden: Sequence[int], out: int, activation: str, *, shared: bool = True,
    embed_dim: int = 8, normalize: bool = True,
) -> AgentNet:
    n_cav, d = env.n_cavs, env.obs_size
    od = jnp.asarray(env.cav_od, dtype=jnp.int32)
    scale = jnp.asarray(obs_scale(env) if normalize else np.ones(d, np.float32))
    n_od = env.scenario.n_od
    net = ODNet(tuple(hidden), out, activation, n_od, embed_dim if shared else 0)

    if shared:
        def init(key: jax.Array) -> Any:
            return net.init(key, jnp.zeros((n_cav, d)), od)

        def apply(params: Any, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
            return net.apply(params, obs / scale, od if idx is None else od[idx])
    else:
        def init(key: jax.Array) -> Any:
            keys = jax.random.split(key, n_cav)
            return jax.vmap(lambda k, o: net.init(k, jnp.zeros((d,)), o))(keys, od)

        def apply(params: Any, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
            x = jnp.moveaxis(obs / scale, -2, 0)  # [C, ..., D]
            p, o = (params, od) if idx is None else (take_agents(params, idx), od[idx])
            y = jax.vmap(lambda pi, xi, oi: net.apply(pi, xi, oi))(p, x, o)
            return jnp.moveaxis(y, 0, -2)

    return AgentNet(init, apply)


class PerCavMLP(NamedTuple):
    """One plain MLP per CAV (URB's IQL*/IPPO*): leaves carry a leading [C] axis. `mlp` and
    `scale` let a per-CAV update apply one CAV's network directly."""

    init: Callable[[jax.Array], Any]
    apply: Callable[..., jnp.ndarray]
    mlp: MLP
    scale: jnp.ndarray


def make_per_cav_mlp(env: RoutingEnv, widths: Sequence[int], normalize: bool) -> PerCavMLP:
    """init(key) -> stacked params; apply(params, obs[..., C, D], idx=None) -> [..., C, K]."""
    mlp = MLP(tuple(widths), env.n_actions, "relu")
    scale = jnp.asarray(obs_scale(env) if normalize else np.ones(env.obs_size, np.float32))

    def init(key: jax.Array) -> Any:
        return jax.vmap(lambda k: mlp.init(k, jnp.zeros((env.obs_size,))))(jax.random.split(key, env.n_cavs))

    def apply(params: Any, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
        x = jnp.moveaxis(obs / scale, -2, 0)
        return jnp.moveaxis(jax.vmap(mlp.apply)(take_agents(params, idx), x), 0, -2)

    return PerCavMLP(init, apply, mlp, scale)


def take_agents(tree: Any, idx: jnp.ndarray | None) -> Any:
    """Rows `idx` of the leading (CAV) axis of every leaf; everything when idx is None."""
    return tree if idx is None else jax.tree_util.tree_map(lambda x: x[idx], tree)


def hidden_layers(depth: int, cells: int) -> tuple[int, ...]:
    return (cells,) * depth


# ----------------------------------------------------------------------------- actions
def masked(logits: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    """Invalid routes (padding repeats for ODs with fewer than K routes) get -1e9."""
    return jnp.where(mask, logits, NEG)


def eps_greedy(key: jax.Array, q: jnp.ndarray, mask: jnp.ndarray, eps: jnp.ndarray) -> jnp.ndarray:
    """[..., K] values -> actions; with probability eps a uniform valid route."""
    k_rand, k_explore = jax.random.split(key)
    greedy = jnp.argmax(masked(q, mask), axis=-1)
    rand = jax.random.categorical(k_rand, jnp.where(mask, 0.0, NEG), axis=-1)
    explore = jax.random.uniform(k_explore, greedy.shape) < eps
    return jnp.where(explore, rand, greedy).astype(jnp.int32)


def eps_greedy_policy(apply: Callable[..., jnp.ndarray], mask: jnp.ndarray) -> Callable[..., Policy]:
    """(params, eps) -> policy(key, obs[n, D], idx=None) -> actions[n]: epsilon-greedy over valid
    routes (eps=0: the greedy test policy) for any Q network `apply(params, obs, idx)`."""

    def policy_for(params: Any, eps: float | jnp.ndarray = 0.0) -> Policy:
        def policy(key: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
            return eps_greedy(key, apply(params, obs, idx), take_agents(mask, idx), eps)

        return policy

    return policy_for


def linear_schedule(start: float, end: float, steps: float) -> Callable[[jnp.ndarray], jnp.ndarray]:
    def schedule(t: jnp.ndarray) -> jnp.ndarray:
        frac = jnp.clip(t / max(steps, 1.0), 0.0, 1.0)
        return start + frac * (end - start)

    return schedule


def entropy(logits: jnp.ndarray) -> jnp.ndarray:
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -(jnp.exp(logp) * logp).sum(-1)


def select_tree(pred: jnp.ndarray, on_true: Any, on_false: Any) -> Any:
    return jax.tree_util.tree_map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)


def polyak(target: Any, online: Any, keep: float) -> Any:
    """target <- keep * target + (1 - keep) * online."""
    return jax.tree_util.tree_map(lambda t, o: keep * t + (1.0 - keep) * o, target, online)


# ----------------------------------------------------------------------------- replay buffer
class Buffer(NamedTuple):
    data: Any  # pytree, every leaf [capacity, ...]
    pos: jnp.ndarray
    size: jnp.ndarray


def buffer_init(example: Any, capacity: int) -> Buffer:
    data = jax.tree_util.tree_map(
        lambda x: jnp.zeros((capacity, *jnp.shape(x)), jnp.asarray(x).dtype), example)
    return Buffer(data, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))


def buffer_add(buf: Buffer, batch: Any) -> Buffer:
    """Append a batch (leading axis n) FIFO; if n > capacity only the newest `capacity` stay."""
    cap = jax.tree_util.tree_leaves(buf.data)[0].shape[0]
    n = jax.tree_util.tree_leaves(batch)[0].shape[0]
    if n > cap:
        batch = jax.tree_util.tree_map(lambda x: x[n - cap:], batch)
        n = cap
    idx = (buf.pos + jnp.arange(n)) % cap
    data = jax.tree_util.tree_map(lambda d, x: d.at[idx].set(x), buf.data, batch)
    return Buffer(data, (buf.pos + n) % cap, jnp.minimum(buf.size + n, cap))


def buffer_sample(buf: Buffer, key: jax.Array, n: int) -> Any:
    """n distinct stored entries, uniformly (no replacement, as TorchRL's sampler); valid once
    `buf.size >= n`."""
    cap = jax.tree_util.tree_leaves(buf.data)[0].shape[0]
    scores = jnp.where(jnp.arange(cap) < buf.size, jax.random.uniform(key, (cap,)), -1.0)
    _, idx = jax.lax.top_k(scores, n)
    return jax.tree_util.tree_map(lambda d: d[idx], buf.data)


# ----------------------------------------------------------------------------- collection
class Day(NamedTuple):
    """One day of one environment, arrays over CAVs [C] (leading [T, B] after collect)."""

    obs: jnp.ndarray  # [C, D] observation each CAV acted on (departure order)
    action: jnp.ndarray  # [C]
    reward: jnp.ndarray  # [C] the day's reward (arrives at the end of the day)
    done: jnp.ndarray  # [C] True: every day ends the CAVs' episode (URB)
    next_obs: jnp.ndarray  # [C, D] provisional observation of the next day
    time_cav: jnp.ndarray  # [] mean CAV travel time, minutes
    time_human: jnp.ndarray  # []


# policy(key, obs[n, D], idx[n] | None) -> actions[n]: idx names the CAVs (None = all C, the
# signature env.act_in_order and SUMO days use).
Policy = Callable[..., jnp.ndarray]


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


def days_shape(days: Any) -> tuple[int, int]:
    """(T, B) of Day arrays [T, B, ...]."""
    leaf = jax.tree_util.tree_leaves(days)[0]
    return int(leaf.shape[0]), int(leaf.shape[1])


def reset_envs(env: RoutingEnv, key: jax.Array, n_envs: int) -> EnvState:
    _, states = jax.vmap(env.reset)(jax.random.split(key, n_envs))
    return states


def day_metrics(days: Day) -> dict[str, jnp.ndarray]:
    return {
        "reward": days.reward.mean(),
        "time_cav": days.time_cav.mean(),
        "time_human": days.time_human.mean(),
    }


def adam_step(tx: optax.GradientTransformation, loss_fn: Callable[..., Any], params: Any, opt_state: Any,
              *args: Any, has_aux: bool = False) -> tuple[tuple[Any, Any], Any]:
    """One optimiser step on `loss_fn(params, *args)`: ((params, opt_state), loss or (loss, aux))."""
    out, grads = jax.value_and_grad(loss_fn, has_aux=has_aux)(params, *args)
    updates, opt_state = tx.update(grads, opt_state, params)
    return (optax.apply_updates(params, updates), opt_state), out


def minibatch_days(minibatch_size: int, n_cavs: int) -> int:
    return max(1, minibatch_size // max(n_cavs, 1))


def n_updates(num_epochs: int, days_collected: int, n_cavs: int, minibatch_size: int) -> int:
    """URB's Adam steps per iteration: num_epochs * floor(frames / minibatch), at least num_epochs."""
    return num_epochs * max(1, days_collected * n_cavs // max(minibatch_size, 1))


def update_plan(num_minibatches: int, minibatch_size: int, days: int, n_cavs: int,
                capacity_days: int | None = None) -> tuple[int, int]:
    """(Adam steps per epoch, whole days per minibatch) for an update on `days` collected days.

    num_minibatches == 0 (URB): `max(1, days * C // minibatch_size)` steps of
    `max(1, minibatch_size // C)` days, so B environments mean B times as many steps.
    num_minibatches > 0 (PureJaxRL): `num_minibatches` steps of `days // num_minibatches` days (at
    least 1; at most `capacity_days`, a replay buffer's size), so the step count is independent of B
    and the minibatch grows with it. Every epoch repeats the plan (num_epochs x steps in all)."""
    if num_minibatches <= 0:
        return n_updates(1, days, n_cavs, minibatch_size), minibatch_days(minibatch_size, n_cavs)
    mb = max(1, days // num_minibatches)
    if capacity_days is not None:
        mb = min(mb, capacity_days)
    return num_minibatches, mb


def flatten_days(tree: Any) -> Any:
    """[T, B, ...] -> [T*B, ...]."""
    return jax.tree_util.tree_map(lambda x: x.reshape(-1, *x.shape[2:]), tree)


# ----------------------------------------------------------------------------- returns, evaluation
def gae(rewards: jnp.ndarray, values: jnp.ndarray, dones: jnp.ndarray, last_value: jnp.ndarray,
        gamma: float, lmbda: float) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Generalised advantage estimation over the leading (day) axis; a done day does not bootstrap.
    With URB's one-day episodes (every done true) it reduces to advantage = reward - value."""
    def body(carry: tuple[jnp.ndarray, jnp.ndarray], x: tuple[jnp.ndarray, ...]):
        adv, next_value = carry
        r, v, d = x
        not_done = 1.0 - d.astype(jnp.float32)
        delta = r + gamma * next_value * not_done - v
        adv = delta + gamma * lmbda * not_done * adv
        return (adv, v), adv

    _, advantages = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), (rewards, values, dones),
                                 reverse=True)
    return advantages, advantages + values


def evaluate(env: RoutingEnv, policy: Policy, key: jax.Array, n_days: int, n_envs: int = 1,
             states: EnvState | None = None) -> dict[str, jnp.ndarray]:
    """Mean CAV / human travel time (minutes) and reward of a fixed policy over n_days x n_envs."""
    k_reset, k_run = jax.random.split(key)
    if states is None:
        states = reset_envs(env, k_reset, n_envs)
    _, days = collect(env, policy, k_run, states, n_days)
    return day_metrics(days)
