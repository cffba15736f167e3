"""Per-CAV networks used functionally: shared parameters with an OD embedding, or one network
per CAV (a leading [C] axis on every leaf); observation scaling."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.game.env import RoutingEnv

ACTIVATIONS: dict[str, Callable[[jnp.ndarray], jnp.ndarray]] = {
    "relu": nn.relu, "tanh": nn.tanh, "elu": nn.elu,
}


@jax.custom_vjp
def kernel_layout_dot(x: jnp.ndarray, kernel: jnp.ndarray) -> jnp.ndarray:
    """x [..., I] @ kernel [I, O], with the kernel's gradient computed as x^T g in the kernel's own
    [I, O] layout. JAX's dot transpose builds it as (g^T x)^T, and for a wide kernel XLA then
    transposes O x I elements in every pass of the update; in the kernel's layout the gradient
    (a plain product for one-row minibatches) fuses into the optimiser's passes. For URB's QMIX
    hypernetwork (the state -> C x 192 weights, C^2 x 960 parameters) this is most of its cost."""
    return jax.lax.dot_general(x, kernel, (((x.ndim - 1,), (0,)), ((), ())))


def _kernel_layout_fwd(x: jnp.ndarray, kernel: jnp.ndarray):
    return kernel_layout_dot(x, kernel), (x, kernel)


def _kernel_layout_bwd(res: tuple[jnp.ndarray, jnp.ndarray], g: jnp.ndarray):
    x, kernel = res
    dx = jax.lax.dot_general(g, kernel, (((g.ndim - 1,), (1,)), ((), ())))
    rows_x, rows_g = x.reshape(-1, x.shape[-1]), g.reshape(-1, g.shape[-1])  # [R, I], [R, O]
    return dx, jax.lax.dot_general(rows_x, rows_g, (((0,), (0,)), ((), ())))


kernel_layout_dot.defvjp(_kernel_layout_fwd, _kernel_layout_bwd)


def _dense_dot(lhs: jnp.ndarray, rhs: jnp.ndarray, dimension_numbers: Any, precision: Any = None,
               preferred_element_type: Any = None) -> jnp.ndarray:
    """nn.Dense's dot_general hook (it always contracts the input's last axis with the kernel's first)."""
    assert dimension_numbers == (((lhs.ndim - 1,), (0,)), ((), ())), dimension_numbers
    return kernel_layout_dot(lhs, rhs)


def WideDense(features: int, name: str | None = None) -> nn.Dense:  # noqa: N802 - a layer, named as one
    """nn.Dense (same parameters, names and initialisation) whose kernel gradient keeps the kernel's
    layout: for layers with very wide kernels, such as QMIX's hypernetworks."""
    return nn.Dense(features, name=name, dot_general=_dense_dot)


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
            # cast: flax types apply as output | (output, variables), the latter only with `mutable`
            return cast(jax.Array, net.apply(params, obs / scale, od if idx is None else od[idx]))
    else:
        def init(key: jax.Array) -> Any:
            keys = jax.random.split(key, n_cav)
            return jax.vmap(lambda k, o: net.init(k, jnp.zeros((d,)), o))(keys, od)

        def apply(params: Any, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
            x = jnp.moveaxis(obs / scale, -2, 0)  # [C, ..., D]
            p, o = (params, od) if idx is None else (take_agents(params, idx), od[idx])
            y = cast(jax.Array, jax.vmap(lambda pi, xi, oi: net.apply(pi, xi, oi))(p, x, o))
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
        return jnp.moveaxis(cast(jax.Array, jax.vmap(mlp.apply)(take_agents(params, idx), x)), 0, -2)

    return PerCavMLP(init, apply, mlp, scale)


def take_agents(tree: Any, idx: jnp.ndarray | None) -> Any:
    """Rows `idx` of the leading (CAV) axis of every leaf; everything when idx is None."""
    return tree if idx is None else jax.tree_util.tree_map(lambda x: x[idx], tree)


def hidden_layers(depth: int, cells: int) -> tuple[int, ...]:
    return (cells,) * depth
