"""The hybrid trainer's jitted pieces, built once per seed group in one place.

Every piece is vmapped over the leading seed axis [S]. This is also the trainer's one seam with
the env on real (SUMO) days: the real-day env, CAVs acting in departure order on it, and feeding it
SUMO's measured travel times (`RoutingEnv.step_with_times`) all live here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from urb_jax.algorithms.learner import Day, Learner
from urb_jax.game.env import EnvState, RoutingEnv
from urb_jax.game.rollout import act_by_levels, dependency_levels
from urb_jax.surrogate import Static, predict
from urb_jax.surrogate.calibrate import Params

Runner = Any  # the learner's runner state (an algorithm-specific pytree), [S] leading
Metrics = dict[str, jnp.ndarray]
# (runner [S], keys [S, P, 2], real states [S, P])
#   -> (obs [S, P, C, D], CAV actions [S, P, C], joint choices [S, P, N])
ActFn = Callable[[Runner, jax.Array, EnvState], tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]]


class TrainerFns(NamedTuple):
    """Jitted (except `split_p`) and vmapped over seeds."""

    sur_round: Callable[[Runner, jax.Array], tuple[Runner, Metrics]]  # a round of surrogate iterations
    update: Callable[[Runner, Day, jax.Array], tuple[Runner, Metrics]]  # one update on given days
    act_explore: ActFn  # exploring policies on the real days
    act_greedy: ActFn  # frozen test policies on the real days
    # (keys [S, P, 2], real [S, P], obs, actions, SUMO times [S, P, N]) -> (real, days [S, 1, P, ...])
    sumo_step: Callable[[jax.Array, EnvState, jnp.ndarray, jnp.ndarray, jnp.ndarray], tuple[EnvState, Day]]
    predict_days: Callable[[Params, jnp.ndarray], jnp.ndarray]  # surrogate times [S, P, N]
    split_p: Callable[[jax.Array], jax.Array]  # keys [S, 2] -> [S, P, 2]
    round_keys: Callable[[jax.Array, int], jax.Array]  # (keys [S, 2], round) -> [S, 4, 2]
    fresh_runner_real: Callable[[jax.Array], tuple[Runner, EnvState]]  # start keys [S, 2]


def build_fns(env: RoutingEnv, env_kwargs: dict[str, Any], learner: Learner, static: Static, P: int,
              n_iters_round: int) -> TrainerFns:
    """The pieces for `learner` trained on the surrogate env `env`, P real days per round."""
    real_env = RoutingEnv(env.scenario, env.is_cav, human_init=env.human_init, **env_kwargs)  # SUMO days
    levels = dependency_levels(env)

    def _sur_round(runner: Runner, key: jax.Array) -> tuple[Runner, Metrics]:
        return jax.lax.scan(learner.iteration, runner, jax.random.split(key, n_iters_round))

    def _act(runner: Runner, keys: jax.Array, states: EnvState, explore: bool
             ) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
        pol = learner.policy(runner, explore)
        obs, actions = jax.vmap(lambda k, s: act_by_levels(real_env, k, s, pol, levels))(keys, states)
        return obs, actions, jax.vmap(real_env.joint_actions)(states, actions)

    def _sumo_step(keys: jax.Array, states: EnvState, obs: jnp.ndarray, actions: jnp.ndarray,
                   times: jnp.ndarray) -> tuple[EnvState, Day]:
        step = jax.vmap(real_env.step_with_times)
        next_obs, states, rewards, dones, info = step(keys, states, actions, times)
        day = Day(obs, actions, rewards, dones, next_obs, info["mean_time_cav"], info["mean_time_human"])
        return states, jax.tree_util.tree_map(lambda x: x[None], day)  # [1, P, ...]

    @jax.jit
    def fresh_runner_real(k_start: jax.Array) -> tuple[Runner, EnvState]:
        def one(k: jax.Array) -> tuple[Runner, EnvState]:
            k_init, k_real = jax.random.split(k)
            _, real = jax.vmap(real_env.reset)(jax.random.split(k_real, P))
            return learner.init(k_init), real

        return jax.vmap(one)(k_start)

    return TrainerFns(
        sur_round=jax.jit(jax.vmap(_sur_round)),
        update=jax.jit(jax.vmap(learner.update_from_days)),
        act_explore=jax.jit(jax.vmap(lambda r, k, s: _act(r, k, s, True))),
        act_greedy=jax.jit(jax.vmap(lambda r, k, s: _act(r, k, s, False))),
        sumo_step=jax.jit(jax.vmap(_sumo_step)),
        predict_days=jax.jit(jax.vmap(lambda params, choices: predict(params, static, choices))),
        split_p=jax.vmap(lambda k: jax.random.split(k, P)),
        round_keys=jax.jit(jax.vmap(lambda k, r: jax.random.split(jax.random.fold_in(k, r), 4), (0, None))),
        fresh_runner_real=fresh_runner_real,
    )
