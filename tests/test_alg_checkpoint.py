"""Orbax checkpoint round-trip of policy + optimiser state, and the shipped URB algo configs."""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import optax
import pytest
from standin import make_env

from urb_jax.algorithms import iql
from urb_jax.algorithms.configs import IQLConfig
from urb_jax.algorithms.registry import ALGORITHMS, load_algo_config
from urb_jax.core.errors import ConfigError
from urb_jax.surrogate import SumoSample
from urb_jax.training.checkpoints import (
    RoundMeta,
    restore_checkpoint,
    restore_round,
    save_checkpoint,
    save_round,
)


def test_checkpoint_round_trip(grid_scenario, tmp_path):
    env = make_env(grid_scenario)
    config = IQLConfig(mlp_depth=1, mlp_cells=16)
    params = iql.make_network(config, env).init(jax.random.PRNGKey(3))
    tx = optax.adam(1e-3)
    opt_state = tx.init(params)
    grads = jax.tree_util.tree_map(np.ones_like, params)
    _, opt_state = tx.update(grads, opt_state, params)  # non-trivial moments
    state = {"params": params, "opt_state": opt_state, "day": np.int32(40)}
    path = save_checkpoint(tmp_path / "ckpt", state)
    assert path.is_absolute() and path.is_dir()
    restored = restore_checkpoint(path, jax.tree_util.tree_map(np.zeros_like, state))
    for a, b in zip(jax.tree_util.tree_leaves(state), jax.tree_util.tree_leaves(restored), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    policy = iql.make_policy(config, env)
    obs = env.reset(jax.random.PRNGKey(0))[0]
    np.testing.assert_array_equal(policy(params)(jax.random.PRNGKey(0), obs),
                                  policy(restored["params"])(jax.random.PRNGKey(0), obs))


def test_a_round_restores_into_shapes_alone(tmp_path):
    """A resume restores the group's state into `jax.eval_shape`'s structs: no fresh state is made
    beside the restored one (URB's QMIX config1: GBs a seed), and the leaves come back as saved,
    as jax arrays that are not weakly typed (the jitted round sees the types it was compiled for)."""

    def make():
        return {"w": jax.numpy.arange(6.0).reshape(2, 3) * 1.5, "n": jax.numpy.int32(7),
                "k": (jax.numpy.ones(4, jax.numpy.uint32),)}

    state = make()
    sample = SumoSample(np.zeros((1, 3), np.int32), np.ones((1, 3), np.float32), np.ones((1, 3), bool))
    save_round(tmp_path, state, [sample], RoundMeta(2, 8, [0], ["a"], [1], [[{"round": 1}]]))
    shapes = jax.eval_shape(make)
    restored, samples, meta = restore_round(tmp_path, shapes, [0])
    assert meta.rounds_done == 2 and np.array_equal(samples[0].travel_time, sample.travel_time)
    for a, b in zip(jax.tree_util.tree_leaves(state), jax.tree_util.tree_leaves(restored), strict=True):
        assert isinstance(b, jax.Array) and b.dtype == a.dtype and b.shape == a.shape and not b.weak_type
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_shipped_configs_load_with_urb_values():
    counts = {"iql": 5, "ippo": 5, "mappo": 5, "qmix": 5, "vdn": 5, "iql_star": 5, "ippo_star": 6}
    for alg, n in counts.items():
        for i in range(1, n + 1):
            assert isinstance(load_algo_config(alg, f"config{i}"), ALGORITHMS[alg].config_class)
    qmix3 = load_algo_config("qmix", "config3")
    days = qmix3.agent_frames_per_batch * qmix3.n_iters
    assert (days, qmix3.mixing_embed_dim, qmix3.tau) == (4000, 256, 0.003)
    assert load_algo_config("mappo", "config5").lmbda == 0.75
    assert load_algo_config("ippo_star", "config6").num_episodes == 20000
    assert load_algo_config("iql_star", "config4").widths == (96, 64, 32)


def test_unknown_config_key_names_file_and_key(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**dataclasses.asdict(IQLConfig()), "learning_rate": 1.0}))
    with pytest.raises(ConfigError, match=r"bad\.json.*learning_rate"):
        load_algo_config("iql", str(bad))
