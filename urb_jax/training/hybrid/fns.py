"""The hybrid trainer's jitted pieces, built once per seed group in one place.

Every piece runs over the leading seed axis [S]: vmapped, except that a big learner's pieces
(`seed_map`, on a CPU) run the seeds one after another inside the program (`lax.map`). On XLA:CPU a
vmapped big learner (URB's QMIX config1 from Provins' 209 CAVs up) costs about 2x a seed at 2
seeds and 2.9x at 5 against one seed alone, where `lax.map` stays linear (benchmarks/seed_axis.py;
where XLA loses the time, presumably the batched products of per-seed weights, was not traced).
This is also the trainer's one seam with
the env on real (SUMO) days: the real-day env, CAVs acting in departure order on it, and feeding it
SUMO's measured travel times (`RoutingEnv.step_with_times`) all live here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from urb_jax.algorithms.learner import Day, Learner, Metrics, collect
from urb_jax.game.env import EnvState, RoutingEnv
from urb_jax.game.rollout import act_by_levels, dependency_levels
from urb_jax.surrogate import Static
from urb_jax.surrogate.calibrate import Params
from urb_jax.surrogate.model import predict_days
from urb_jax.training.hybrid.memory import tree_size

Runner = Any  # the learner's runner state (an algorithm-specific pytree), [S] leading
# (runner [S], keys [S, P, 2], real states [S, P])
#   -> (obs [S, P, C, D], CAV actions [S, P, C], joint choices [S, P, N])
ActFn = Callable[[Runner, jax.Array, EnvState], tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]]


class TrainerFns(NamedTuple):
    """Jitted (except `split_p`), over seeds (vmap, or the learner's pieces by `lax.map`).
    `sur_round`, `sur_round_adapt` and `update` donate their runner (and population): XLA then
    writes the new learner state over the old, so a round holds the state about once less at its
    peak (URB's QMIX config1: GBs a seed; measured in hybrid/memory.py). The caller must not read
    what it passed."""

    # surrogate iterations, one per key: (runner [S], keys [S, L, 2]) -> (runner, metrics [S, L])
    sur_round: Callable[[Runner, jax.Array], tuple[Runner, Metrics]]
    # adapting humans: (runner [S], population [S], keys [S, L, 2]) -> (runner, population, metrics)
    sur_round_adapt: Callable[[Runner, EnvState, jax.Array], tuple[Runner, EnvState, Metrics]]
    iter_keys: Callable[[jax.Array], jax.Array]  # a round's key [S, 2] -> its iterations' keys [S, n, 2]
    update: Callable[[Runner, Day, jax.Array], tuple[Runner, Metrics]]  # one update on given days
    act_explore: ActFn  # exploring policies on the real days
    act_greedy: ActFn  # frozen test policies on the real days
    # (keys [S, R, 2], real [S, R], obs, actions, SUMO times [S, R, N], surrogate params [S])
    #   -> (real, days [S, 1, R, ...]); the params give the marginal credit's derivative
    sumo_step: Callable[[jax.Array, EnvState, jnp.ndarray, jnp.ndarray, jnp.ndarray, Params],
                        tuple[EnvState, Day]]
    # (params [S], choices [S, P, N], each day's departure shifts [S, P, N] or None) -> minutes [S, P, N]
    predict_days: Callable[[Params, jnp.ndarray, jnp.ndarray | None], jnp.ndarray]
    split_p: Callable[[jax.Array], jax.Array]  # keys [S, 2] -> [S, P, 2]
    round_keys: Callable[[jax.Array, int], jax.Array]  # (keys [S, 2], round) -> [S, 4, 2]
    fresh_runner_real: Callable[[jax.Array], tuple[Runner, EnvState]]  # start keys [S, 2]


# Above this many learner parameters `seed_axis: auto` maps the seeds on a CPU. Measured (5 seeds x
# 16 envs of URB's QMIX config1, benchmarks/seed_axis.py): 7.9 M (saint_arnoult, 88 CAVs) vmap 1.0x
# of one seed alone, map 1.18x; 42.8 M (provins, 209 CAVs) vmap 2.0x at 2 seeds, map 1.0x. Between
# the two it is unmeasured. On one H100 vmap wins at any size measured: 48.2 M (5 seeds) vmap 0.80x,
# map 1.04x; 166 M (ingolstadt_custom, 414 CAVs, 3 seeds) vmap 0.93x, map 1.01x (docs/results.md,
# "GPU"), so `auto` maps on the CPU backend only.
MAP_SEEDS_PARAMS = 10_000_000


def maps_seeds(seed_axis: str, params: Any, backend: str | None = None) -> bool:
    """Whether a learner with these parameters (one seed's, arrays or shapes) maps its seeds on
    `backend` (default: JAX's default backend, "cpu", "gpu" or "tpu")."""
    if seed_axis != "auto":
        return seed_axis == "map"
    backend = jax.default_backend() if backend is None else backend
    return backend == "cpu" and tree_size(params) > MAP_SEEDS_PARAMS


def seeds_map(fn: Callable[..., Any]) -> Callable[..., Any]:
    """fn over a leading seed axis of every argument, one seed after another (`lax.map`): each
    seed runs fn's unbatched program, so the seeds of a group compute what each would alone."""
    return lambda *args: jax.lax.map(lambda xs: fn(*xs), args)


def build_fns(env: RoutingEnv, env_kwargs: dict[str, Any], learner: Learner, static: Static, P: int,
              n_iters_round: int, n_real: int | None = None, seed_map: bool = False) -> TrainerFns:
    """The pieces for `learner` trained on the surrogate env `env`, P real days per round, played
    by `n_real` copies of the real humans (P: frozen humans, days side by side; 1: adapting humans,
    one population living the days in order). `seed_map`: the learner's pieces (surrogate rounds,
    updates, acting, init) go over the seeds by `lax.map`, not vmap.

    A round's surrogate iterations take their keys as an argument (`iter_keys`), so the trainer can
    run a round as chunks of one compiled scan and time them from the host: no host callback in
    the program, which JAX's persistent compilation cache would refuse to store."""
    real_env = RoutingEnv(env.scenario, env.is_cav, human_init=env.human_init, **env_kwargs)  # SUMO days
    levels = dependency_levels(env)
    over = seeds_map if seed_map else jax.vmap  # the learner's pieces
    n_real = P if n_real is None else n_real

    def _sur_round(runner: Runner, keys: jax.Array) -> tuple[Runner, Metrics]:
        return jax.lax.scan(learner.iteration, runner, keys)

    def _sur_round_adapt(runner: Runner, pop: EnvState, keys: jax.Array) -> tuple[Runner, EnvState, Metrics]:
        """Adapting humans: every iteration the learner's B envs start from the population's day,
        then the population lives the iteration's B x days_per_iter days in order (the exploring
        CAVs of the updated policy, the surrogate's times), so human learning days = URB's days."""
        n_envs = jax.tree_util.tree_leaves(runner.env_states)[0].shape[0]
        n_days = learner.days_per_iter * n_envs

        def body(carry: tuple[Runner, EnvState], key: jax.Array) -> tuple[tuple[Runner, EnvState], Metrics]:
            runner, pop = carry
            k_it, k_pop = jax.random.split(key)
            envs = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (n_envs, *x.shape)), pop)
            runner, metrics = learner.iteration(runner._replace(env_states=envs), k_it)
            pops, days = collect(env, learner.policy(runner, True), k_pop,
                                 jax.tree_util.tree_map(lambda x: x[None], pop), n_days, runner.env_params)
            pop = jax.tree_util.tree_map(lambda x: x[0], pops)
            return (runner, pop), {**metrics, "population_time_human": days.time_human.mean(),
                                   "population_time_cav": days.time_cav.mean()}

        (runner, pop), metrics = jax.lax.scan(body, (runner, pop), keys)
        return runner, pop, metrics

    def _act(runner: Runner, keys: jax.Array, states: EnvState, explore: bool
             ) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
        pol = learner.policy(runner, explore)
        obs, actions = jax.vmap(lambda k, s: act_by_levels(real_env, k, s, pol, levels))(keys, states)
        return obs, actions, jax.vmap(real_env.joint_actions)(states, actions)

    def _sumo_step(keys: jax.Array, states: EnvState, obs: jnp.ndarray, actions: jnp.ndarray,
                   times: jnp.ndarray, params: Params) -> tuple[EnvState, Day]:
        if real_env.uses_model:  # SUMO measures the day, the surrogate its derivative
            choices = jax.vmap(real_env.joint_actions)(states, actions)
            model = jax.vmap(lambda c, d: env.model_externalities(params, c, d))(choices, states.day)
            step = jax.vmap(real_env.step_with_times)
            next_obs, states, rewards, dones, info = step(keys, states, actions, times, model)
        else:
            step = jax.vmap(real_env.step_with_times)
            next_obs, states, rewards, dones, info = step(keys, states, actions, times)
        day = Day(obs, actions, rewards, dones, next_obs, info["mean_time_cav"], info["mean_time_human"],
                  info.get("active"))
        return states, jax.tree_util.tree_map(lambda x: x[None], day)  # [1, P, ...]

    @jax.jit
    def fresh_runner_real(k_start: jax.Array) -> tuple[Runner, EnvState]:
        def one(k: jax.Array) -> tuple[Runner, EnvState]:
            k_init, k_real = jax.random.split(k)
            _, real = jax.vmap(real_env.reset)(jax.random.split(k_real, P))
            return learner.init(k_init), jax.tree_util.tree_map(lambda x: x[:n_real], real)

        return over(one)(k_start)

    return TrainerFns(
        sur_round=jax.jit(over(_sur_round), donate_argnums=0),
        sur_round_adapt=jax.jit(over(_sur_round_adapt), donate_argnums=(0, 1)),
        iter_keys=jax.jit(jax.vmap(lambda k: jax.random.split(k, n_iters_round))),
        update=jax.jit(over(learner.update_from_days), donate_argnums=0),
        act_explore=jax.jit(over(lambda r, k, s: _act(r, k, s, True))),
        act_greedy=jax.jit(over(lambda r, k, s: _act(r, k, s, False))),
        sumo_step=jax.jit(jax.vmap(_sumo_step)),
        predict_days=jax.jit(jax.vmap(lambda params, choices, shift: predict_days(params, static, choices,
                                                                                  shift))),
        split_p=jax.vmap(lambda k: jax.random.split(k, P)),
        round_keys=jax.jit(jax.vmap(lambda k, r: jax.random.split(jax.random.fold_in(k, r), 4), (0, None))),
        fresh_runner_real=fresh_runner_real,
    )
