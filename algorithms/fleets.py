"""Competing CAV fleets: one learner per fleet, driven as one `Learner` by the trainers.

A task with `fleets` (game.config.FleetConfig) splits its CAVs (`game.mutation.split_fleets`);
the env pays each fleet its own behaviour (`game.rewards.fleet_rewards`). Each fleet's learner is
its algorithm's own, built on the fleet's view of the env (`fleet_env`: the same routing game with
only that fleet's CAVs on its CAV axis, so its networks, buffers and critics are the fleet's). The
fleets' learner (`make_fleets_learner`) acts for every CAV in departure order, each CAV by its own
fleet's policy (`fleets_policy`), so every fleet observes the others' choices as it observes the
humans'; collects days on the shared env; and gives each fleet's learner the rows of its own CAVs
(`fleet_days`) for that learner's own update. Nothing of one fleet's learner sees another's
parameters or rewards.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.learner import Day, Learner, Metrics, collect, day_metrics, reset_envs
from urb_jax.game.env import EnvParams, EnvState, RoutingEnv
from urb_jax.game.rollout import Policy


@dataclass(frozen=True)
class FleetsAlgoConfig:
    """The algorithm config of a run with fleets: each fleet's name, algorithm id and typed config
    (the algorithm's own config class, loaded from the fleet's alg_conf)."""

    names: tuple[str, ...]
    algs: tuple[str, ...]
    configs: tuple[Any, ...]


class FleetsRunner(NamedTuple):
    """The fleets' learners' runners (each with its own parameters, optimiser, buffer) and the
    shared envs every fleet acts in."""

    fleets: tuple[Any, ...]
    env_states: EnvState
    env_params: EnvParams

    @property
    def params(self) -> tuple[Any, ...]:
        """Every fleet's learner parameters (what the trainer checks for divergence)."""
        return tuple(r.params for r in self.fleets)


def fleet_rows(env: RoutingEnv) -> tuple[np.ndarray, ...]:
    """For each fleet, the rows of the env's CAV axis [C] its CAVs hold (departure order kept)."""
    if env.cav_fleet is None or env.fleet_coefficients is None:
        raise ValueError("the env has no fleets (cav_fleet)")
    fleet = env.cav_fleet[env.cav_index]
    return tuple(np.flatnonzero(fleet == f) for f in range(len(env.fleet_coefficients)))


def fleet_env(env: RoutingEnv, f: int) -> RoutingEnv:
    """Fleet f's view of the routing game: its CAVs alone on the CAV axis, its behaviour's reward.
    Its learner is built on it (network, buffer and critic sizes, action masks, ODs, turn order);
    its days are the fleets' env's (`fleet_days`)."""
    assert env.cav_fleet is not None and env.fleet_coefficients is not None
    return dataclasses.replace(env, is_cav=env.cav_fleet == f, cav_fleet=None, fleet_coefficients=None,
                               reward_coefficients=env.fleet_coefficients[f])


def fleet_days(days: Day, rows: np.ndarray) -> Day:
    """The rows of one fleet's CAVs of days [..., C, ...] (the CAV axis follows the leading axes)."""
    lead = days.time_cav.ndim  # [T, B] after collect, [1, P] on SUMO days

    def take(x: jnp.ndarray) -> jnp.ndarray:
        return jnp.take(x, jnp.asarray(rows), axis=lead)

    return Day(take(days.obs), take(days.action), take(days.reward), take(days.done), take(days.next_obs),
               days.time_cav, days.time_human, None if days.active is None else take(days.active))


def fleets_policy(policies: Sequence[Policy], rows: Sequence[np.ndarray], n_cavs: int) -> Policy:
    """One policy for every CAV: a CAV acts by its own fleet's policy (fleet f's policy reads the
    CAV's position among fleet f's CAVs). policy(key, obs [n, D], idx [n] | None) -> actions [n]."""
    fleet_of = np.zeros(n_cavs, np.int32)
    pos = np.zeros(n_cavs, np.int32)
    for f, r in enumerate(rows):
        fleet_of[r] = f
        pos[r] = np.arange(len(r), dtype=np.int32)
    fleet_of_j, pos_j = jnp.asarray(fleet_of), jnp.asarray(pos)

    def policy(key: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
        keys = jax.random.split(key, len(policies))
        if idx is None:  # every CAV at once: each fleet acts on its own rows
            actions = jnp.zeros(obs.shape[0], jnp.int32)
            for f, (pol, r) in enumerate(zip(policies, rows, strict=True)):
                actions = actions.at[jnp.asarray(r)].set(pol(keys[f], obs[jnp.asarray(r)]).astype(jnp.int32))
            return actions
        which = fleet_of_j[idx]
        actions = jnp.zeros(idx.shape, jnp.int32)
        for f, (pol, r) in enumerate(zip(policies, rows, strict=True)):  # each fleet's policy on every
            own = jnp.clip(pos_j[idx], 0, max(len(r) - 1, 0))  # row, kept where the row is its CAV's
            actions = jnp.where(which == f, pol(keys[f], obs, own).astype(jnp.int32), actions)
        return actions

    return policy


def fleet_updates_per_iter(days_per_iter: Sequence[int]) -> tuple[int, tuple[int, ...]]:
    """(days one iteration of the fleets collects, each fleet's updates on them): the least common
    multiple D of the fleets' days per iteration, and D / d_f, so each fleet's learner updates on
    chunks of the days it would collect alone (IQL* 1 day, MAPPO's agent_frames_per_batch)."""
    n_days = math.lcm(*days_per_iter)
    return n_days, tuple(n_days // d for d in days_per_iter)


def make_fleets_learner(env: RoutingEnv, learners: Sequence[Learner], names: Sequence[str],
                        num_envs: int) -> Learner:
    """The fleets' learners as one: `learners[f]` built on `fleet_env(env, f)`; `env` the fleets'
    env (cav_fleet set). An iteration collects D days (`fleet_updates_per_iter`) in each of
    `num_envs` envs under every fleet's exploring policy, then each fleet's learner updates D / d_f
    times, on consecutive chunks of its days per iteration, on its CAVs' rows. `update_from_days`
    (given days, e.g. SUMO's) is one update of each fleet's learner on all of them, as each would
    alone."""
    rows = fleet_rows(env)
    n_days, n_updates = fleet_updates_per_iter([lr.days_per_iter for lr in learners])

    def init(key: jax.Array) -> FleetsRunner:
        keys = jax.random.split(key, len(learners) + 1)
        fleets = tuple(lr.init(keys[f]) for f, lr in enumerate(learners))
        return FleetsRunner(fleets, reset_envs(env, keys[-1], num_envs), env.default_params)

    def policy(runner: FleetsRunner, explore: bool = True) -> Policy:
        return fleets_policy([lr.policy(r, explore) for lr, r in zip(learners, runner.fleets, strict=True)],
                             rows, env.n_cavs)

    def update(runner: FleetsRunner, days: Day, key: jax.Array, chunks: Sequence[int]
               ) -> tuple[FleetsRunner, Metrics]:
        """Fleet f's learner updates chunks[f] times on its rows of days [T, ...] cut in chunks[f]."""
        keys = jax.random.split(key, len(learners))
        fleets, metrics, losses = [], day_metrics(days), []
        for f, (lr, r) in enumerate(zip(learners, runner.fleets, strict=True)):
            own = fleet_days(days, rows[f])
            size = days.reward.shape[0] // chunks[f]
            ms = []
            for j in range(chunks[f]):
                part = jax.tree_util.tree_map(lambda x, j=j, size=size: x[j * size:(j + 1) * size], own)
                k = jax.random.fold_in(keys[f], j) if chunks[f] > 1 else keys[f]
                r, m = lr.update_from_days(r, part, k)
                ms.append(m)
            fleets.append(r)
            metrics[f"{names[f]}_reward"] = jnp.mean(jnp.stack([m["reward"] for m in ms]))
            if "loss" in ms[0]:
                metrics[f"{names[f]}_loss"] = jnp.mean(jnp.stack([m["loss"] for m in ms]))
                losses.append(metrics[f"{names[f]}_loss"])
        if losses:
            metrics["loss"] = jnp.mean(jnp.stack(losses))
        return runner._replace(fleets=tuple(fleets)), metrics

    def update_from_days(runner: FleetsRunner, days: Day, key: jax.Array) -> tuple[FleetsRunner, Metrics]:
        return update(runner, days, key, (1,) * len(learners))

    def iteration(runner: FleetsRunner, key: jax.Array) -> tuple[FleetsRunner, Metrics]:
        k_col, k_upd = jax.random.split(key)
        env_states, days = collect(env, policy(runner, True), k_col, runner.env_states, n_days,
                                   runner.env_params)
        return update(runner._replace(env_states=env_states), days, k_upd, n_updates)

    return Learner(init, iteration, update_from_days, policy, max(lr.n_iters for lr in learners), n_days)
