"""Independent forward pass of the QMIX mixer, for both hypernetwork forms: in numpy (the values)
and in plain jax.numpy (x @ kernel + bias under JAX's own autodiff: the reference for the
gradients of QMixer, whose hypernetwork layers use networks.kernel_layout_dot)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def qmix_reference(p, q, s, xp):
    """Q_tot [...] from the mixer's parameters `p` (params["params"]), q [..., C], s [..., S]: one
    linear hypernetwork layer (URB), or two with a ReLU where `<name>_hidden` layers exist
    (pymarl, `hypernet_hidden` > 0). `xp` is numpy or jax.numpy."""

    def dense(name, x):
        return x @ p[name]["kernel"] + p[name]["bias"]

    def hyper(name, x):
        if f"{name}_hidden" in p:
            x = xp.maximum(dense(f"{name}_hidden", x), 0.0)
        return dense(name, x)

    w1 = xp.abs(hyper("hyper_w1", s)).reshape(*q.shape, -1)
    h = xp.einsum("...c,...ce->...e", q, w1) + dense("hyper_b1", s)
    h = xp.where(h > 0, h, xp.expm1(h))
    w2 = xp.abs(hyper("hyper_w2", s))
    v = dense("hyper_v2", xp.maximum(dense("hyper_v1", s), 0.0))[..., 0]
    return (h * w2).sum(-1) + v


def qmix_numpy(params, q, s) -> float:
    return float(qmix_reference(jax.tree_util.tree_map(np.asarray, params["params"]), q, s, np))


def qmix_jnp(params, q, s):
    return qmix_reference(params["params"], q, s, jnp)
