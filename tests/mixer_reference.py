"""Independent numpy forward pass of the QMIX mixer, for both hypernetwork forms."""

from __future__ import annotations

import jax
import numpy as np


def qmix_numpy(params, q, s) -> float:
    """Q_tot from the mixer's parameters: one linear hypernetwork layer (URB), or two with a ReLU
    where `<name>_hidden` layers exist (pymarl, `hypernet_hidden` > 0)."""
    p = jax.tree_util.tree_map(np.asarray, params["params"])

    def dense(name, x):
        return x @ p[name]["kernel"] + p[name]["bias"]

    def hyper(name, x):
        if f"{name}_hidden" in p:
            x = np.maximum(dense(f"{name}_hidden", x), 0.0)
        return dense(name, x)

    c = q.shape[-1]
    w1 = np.abs(hyper("hyper_w1", s)).reshape(c, -1)
    h = q @ w1 + dense("hyper_b1", s)
    h = np.where(h > 0, h, np.expm1(h))
    w2 = np.abs(hyper("hyper_w2", s))
    v = dense("hyper_v2", np.maximum(dense("hyper_v1", s), 0.0))[0]
    return float(h @ w2 + v)


def qmix_jnp(params, q, s):
    """The same mixer in plain jax.numpy (x @ kernel + bias, JAX's own autodiff): the reference for
    the gradients of QMixer, whose hypernetwork layers use networks.kernel_layout_dot.
    q [..., C], s [..., S] -> Q_tot [...]."""
    import jax.numpy as jnp

    p = params["params"]

    def dense(name, x):
        return x @ p[name]["kernel"] + p[name]["bias"]

    def hyper(name, x):
        if f"{name}_hidden" in p:
            x = jnp.maximum(dense(f"{name}_hidden", x), 0.0)
        return dense(name, x)

    w1 = jnp.abs(hyper("hyper_w1", s)).reshape(*q.shape, -1)
    h = jnp.einsum("...c,...ce->...e", q, w1) + dense("hyper_b1", s)
    h = jnp.where(h > 0, h, jnp.expm1(h))
    w2 = jnp.abs(hyper("hyper_w2", s))
    v = dense("hyper_v2", jnp.maximum(dense("hyper_v1", s), 0.0))[..., 0]
    return (h * w2).sum(-1) + v
