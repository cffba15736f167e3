"""Compilation paid once: departure levels as scanned blocks (same actions as one call per level,
a jaxpr that does not grow with the levels), the growing SUMO-day set predicted at bucketed sizes,
and the persistent compilation cache (entries when on, none when off, identical records warm)."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from standin import make_env
from support.digests import result_digests

from urb_jax.algorithms.registry import algorithm, load_algo_config
from urb_jax.core.compile_cache import COMPILE_CACHE_ENV, disable_compile_cache, enable_compile_cache
from urb_jax.game.env import EnvState, RoutingEnv
from urb_jax.game.rollout import (
    MAX_BLOCKS,
    Policy,
    act_by_levels,
    block_bounds,
    dependency_levels,
    level_blocks,
)
from urb_jax.surrogate import SumoSample, build_static, init_params, predict_jit
from urb_jax.surrogate.calibrate import route_bias
from urb_jax.surrogate.model import bucket_size, predict_bucketed

REPO = Path(__file__).resolve().parents[1]


def act_one_call_per_level(env: RoutingEnv, key: jax.Array, state: EnvState, policy: Policy,
                           levels: tuple[np.ndarray, ...]) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The unrolled loop act_by_levels replaced: one policy call of exactly the level's CAVs (a
    Python loop over one jitted level, compiled once per level size)."""
    @jax.jit
    def level(actions: jnp.ndarray, lv: jnp.ndarray, idx: jnp.ndarray) -> jnp.ndarray:
        obs = env.observe(state, actions)
        chosen = policy(jax.random.fold_in(key, lv), obs[idx], idx)
        return actions.at[idx].set(chosen.astype(jnp.int32))

    actions = state.cav_actions
    for lv, idx in enumerate(levels):
        actions = level(actions, jnp.asarray(lv), jnp.asarray(idx))
    return env.observe(state, actions), actions


@pytest.mark.parametrize("obs_kind", ["previous_agents_plus_start_time", "global_previous_agents"])
@pytest.mark.parametrize("alg", ["iql_star", "ippo"])
def test_scanned_levels_equal_one_call_per_level(grid_scenario, obs_kind, alg):
    """Exploring policies (random draws on padded rows) of per-CAV and shared networks, levels of
    different sizes (urb_grid: 14 levels of 1..25 CAVs; global observations: many small levels):
    the scanned blocks give the same observations and actions as the unrolled loop."""
    env = make_env(grid_scenario, observation_type=obs_kind)
    levels = dependency_levels(env)
    assert len(levels) > MAX_BLOCKS and len({len(lv) for lv in levels}) > 2
    learner = algorithm(alg).make_learner(load_algo_config(alg, "config1"), env)
    policy = learner.policy(learner.init(jax.random.PRNGKey(0)), True)
    _, state = env.reset(jax.random.PRNGKey(3))
    key = jax.random.PRNGKey(4)
    new = jax.jit(lambda k: act_by_levels(env, k, state, policy, levels))(key)
    old = act_one_call_per_level(env, key, state, policy, levels)
    np.testing.assert_array_equal(new[1], old[1])
    np.testing.assert_array_equal(new[0], old[0])
    assert len(np.unique(np.asarray(new[1]))) > 1


def test_level_blocks_write_every_cav_once():
    levels = (np.array([4, 0, 7]), np.array([2]), np.array([1, 5]), np.array([3]), np.array([6]))
    blocks = level_blocks(levels, 8)
    written = np.concatenate([b.write.ravel() for b in blocks])
    assert sorted(written[written < 8].tolist()) == list(range(8))
    assert sum(len(b.idx) for b in blocks) == len(levels) and len(blocks) <= MAX_BLOCKS
    for b in blocks:  # padding reads a real CAV of its own level, writes out of range
        for row, lv in enumerate(levels[b.first:b.first + len(b.idx)]):
            assert set(b.idx[row].tolist()) == set(lv.tolist())


def test_block_bounds_minimise_padded_rows():
    """Against brute force over every split into at most MAX_BLOCKS runs."""
    rng = np.random.default_rng(0)
    for _ in range(30):
        sizes = rng.integers(1, 12, rng.integers(1, 9))
        n, penalty = len(sizes), float(rng.uniform(0, 5))

        splits = [[0, *cut, n] for k in range(MAX_BLOCKS) for cut in itertools.combinations(range(1, n), k)]
        best = min(_padded_rows(sizes, b, penalty) for b in splits)
        got = block_bounds(sizes, block_rows=penalty)
        assert got[0] == 0 and got[-1] == n and len(got) - 1 <= MAX_BLOCKS
        assert _padded_rows(sizes, got, penalty) == pytest.approx(best)


def _padded_rows(sizes: np.ndarray, bounds: list[int], penalty: float) -> float:
    return sum((hi - lo) * sizes[lo:hi].max() + penalty for lo, hi in itertools.pairwise(bounds))


def test_act_by_levels_jaxpr_does_not_grow_with_levels(grid_scenario):
    """The unrolled loop's program grew with the levels (85 on saint_arnoult with global
    observations: 64 s to compile); the blocks' program is bounded."""
    few = make_env(grid_scenario, observation_type="previous_agents_plus_start_time")
    many = make_env(grid_scenario, observation_type="global_previous_agents")
    assert len(dependency_levels(many)) > 5 * len(dependency_levels(few))

    def n_eqns(env: RoutingEnv) -> int:
        _, state = env.reset(jax.random.PRNGKey(0))
        policy = algorithm("iql_star").make_learner(load_algo_config("iql_star", "config1"), env).policy
        runner = algorithm("iql_star").make_learner(load_algo_config("iql_star", "config1"), env).init(
            jax.random.PRNGKey(0))
        jaxpr = jax.make_jaxpr(lambda k: act_by_levels(env, k, state, policy(runner, True)))(
            jax.random.PRNGKey(1))
        return len(jaxpr.eqns)

    assert n_eqns(many) <= n_eqns(few) + 10


@pytest.fixture(scope="module")
def grid_static(grid_scenario):
    static = build_static(grid_scenario)
    rng = np.random.default_rng(0)
    params = {k: v + 0.05 * rng.standard_normal(np.shape(v)).astype(np.float32)
              for k, v in init_params(static).items()}
    return static, params


def _choices(scn, d: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([[rng.choice(np.flatnonzero(scn.route_valid[n])) for n in range(scn.n_agents)]
                     for _ in range(d)]).astype(np.int32)  # [d, N]


def test_bucket_sizes():
    assert [bucket_size(n) for n in (0, 1, 8, 9, 58, 64, 65, 130)] == [8, 8, 8, 16, 64, 64, 128, 256]


def test_predict_bucketed_equals_unpadded_and_compiles_once_per_bucket(grid_scenario, grid_static):
    """Growing day sets (58, 62 days: one bucket of 64) compile predict once; every day's times
    equal the unpadded call's (XLA's vectorised loops may change the last bit)."""
    static, params = grid_static
    before = predict_jit._cache_size()
    for d in (58, 62):
        ch = _choices(grid_scenario, d, d)
        got = predict_bucketed(params, static, ch)
        assert got.shape == (d, static.n)
        np.testing.assert_allclose(got, np.asarray(predict_jit(params, static, jnp.asarray(ch))), rtol=1e-6)
    assert predict_jit._cache_size() - before == 3  # bucket 64 once, the two unpadded references


def test_route_bias_on_padded_days_equals_unpadded(grid_scenario, grid_static):
    static, params = grid_static
    ch = _choices(grid_scenario, 13, 1)
    pred = np.asarray(predict_jit(params, static, jnp.asarray(ch)))
    rng = np.random.default_rng(2)
    times = (pred * rng.uniform(0.9, 1.2, pred.shape)).astype(np.float32)
    arrived = rng.uniform(size=pred.shape) > 0.05
    bias = np.asarray(route_bias(params, static, SumoSample(ch, times, arrived), 2.0))
    sums, counts = np.zeros((static.n, static.k)), np.zeros((static.n, static.k))
    agents = np.broadcast_to(np.arange(static.n), ch.shape)
    np.add.at(sums, (agents, ch), np.where(arrived, times - pred, 0.0))
    np.add.at(counts, (agents, ch), arrived)
    np.testing.assert_allclose(bias, sums / (counts + 2.0), rtol=1e-5, atol=1e-6)


@pytest.fixture
def fresh_compile_cache(tmp_path, monkeypatch):
    """A private urb-jax cache dir; the persistent cache is switched off again afterwards."""
    monkeypatch.setenv("URB_JAX_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(COMPILE_CACHE_ENV, raising=False)
    yield tmp_path / "cache" / "jax"
    disable_compile_cache()


def _compile_something(tag: float) -> None:
    """A program JAX has not compiled in this process (the constant makes it new)."""
    jax.block_until_ready(jax.jit(lambda x: jnp.sin(x) * tag + x @ x.T)(jnp.ones((9, 9))))


def test_compile_cache_stores_entries_when_on(fresh_compile_cache):
    assert enable_compile_cache() == fresh_compile_cache.resolve()
    _compile_something(1.25)
    assert len(list(fresh_compile_cache.iterdir())) >= 1  # small, fast compiles are stored too


def test_compile_cache_opt_out_stores_nothing(fresh_compile_cache, monkeypatch):
    monkeypatch.setenv(COMPILE_CACHE_ENV, "off")
    assert enable_compile_cache() is None
    _compile_something(2.5)
    assert not fresh_compile_cache.exists() or not any(fresh_compile_cache.iterdir())


@pytest.mark.slow
def test_warm_compile_cache_gives_identical_records(tmp_path):
    """Two processes, one compile cache: the second compiles nothing (every program it asks for is
    a cache hit: none carries a host callback, which JAX would compile afresh every process) and
    writes byte-identical records and metrics."""
    env = {**os.environ, "URB_JAX_CACHE": str(tmp_path / "cache"),
           "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "tests")])}  # support.compile_cache_run
    env.pop(COMPILE_CACHE_ENV, None)
    digests, entries, compiles = [], [], []
    for run in ("cold", "warm"):
        out = tmp_path / run
        subprocess.run([sys.executable, "-m", "support.compile_cache_run", str(out)], env=env, check=True,
                       timeout=600)
        [folder] = [p.parent for p in out.glob("*/exp_config.json")]
        digests.append(result_digests(folder))
        assert digests[-1] is not None
        entries.append(sorted(p.name for p in (tmp_path / "cache" / "jax").iterdir()))
        compiles.append(json.loads((out / "compiles.json").read_text()))
    assert digests[0] == digests[1]
    assert compiles[0]["requests"] > 20 and compiles[0]["hits"] < compiles[0]["requests"]
    assert compiles[1]["hits"] == compiles[1]["requests"] == compiles[0]["requests"]
    assert len(entries[0]) > 20 and entries[1] == entries[0]
