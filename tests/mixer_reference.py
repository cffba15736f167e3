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
