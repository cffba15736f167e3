"""Baseline CAV policies (URB_REFERENCE §9): aon, random, human.

* aon: the minimum free-flow route, every day.
* random: a uniform route each day (seeded from the env seed; padding repeats excluded).
* human: the CAV keeps the *trained* human model of that agent (costs C and personal beta from
  the human phase) and keeps learning with it, from -reward (= own time for selfish CAVs, as URB
  does with its CAV reward). URB instead builds a fresh model initialised at free-flow times; we
  keep the trained one because a "CAV that still behaves as its human" is then the no-change
  reference: with a selfish reward its days continue the human equilibrium, so any difference
  against other policies is due to the policy, not to forgetting 200 days of experience.
Policies are frozen in test days (the runner stops calling `learn`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.experiment.protocol import CavContext
from urb_jax.game.humans import HumanParams, HumanState, act, learn

BASELINES = ("aon", "random", "human")

_act = jax.jit(act, static_argnames=("params",))
_learn = jax.jit(learn, static_argnames=("params",))


def aon_routes(fft: np.ndarray, route_valid: np.ndarray) -> np.ndarray:
    """Each row's minimum free-flow route (the first on ties): URB's all-or-nothing choice."""
    return np.argmin(np.where(route_valid, fft, np.inf), axis=1).astype(np.int32)


@dataclass(frozen=True)
class AonPolicy:
    name: str = "aon"
    uses_observation: bool = False

    def init(self, key: jax.Array, ctx: CavContext) -> np.ndarray:
        return aon_routes(ctx.fft, ctx.route_valid)

    def act(self, key: jax.Array, state: np.ndarray, obs: np.ndarray) -> np.ndarray:
        return state

    def learn(self, key: jax.Array, state: Any, obs: np.ndarray, actions: np.ndarray,
              rewards: np.ndarray) -> Any:
        return state


@dataclass(frozen=True)
class RandomPolicy:
    name: str = "random"
    uses_observation: bool = False

    def init(self, key: jax.Array, ctx: CavContext) -> jnp.ndarray:
        return jnp.where(jnp.asarray(ctx.route_valid), 0.0, -jnp.inf)  # uniform logits

    def act(self, key: jax.Array, state: jnp.ndarray, obs: np.ndarray) -> np.ndarray:
        if state.shape[0] == 0:
            return np.zeros(0, dtype=np.int32)
        return np.asarray(jax.random.categorical(key, state, axis=1), dtype=np.int32)

    def learn(self, key: jax.Array, state: Any, obs: np.ndarray, actions: np.ndarray,
              rewards: np.ndarray) -> Any:
        return state


@dataclass(frozen=True)
class HumanPolicy:
    name: str = "human"
    uses_observation: bool = False

    def init(self, key: jax.Array, ctx: CavContext) -> tuple[HumanState, HumanParams]:
        h = ctx.humans
        idx = jnp.asarray(ctx.cav_index)
        sub = HumanState(h.cost[idx], h.beta[idx], h.last_action[idx], h.memory[idx])
        return sub, ctx.human_params

    def act(self, key: jax.Array, state: tuple[HumanState, HumanParams], obs: np.ndarray) -> np.ndarray:
        sub, params = state
        if sub.cost.shape[0] == 0:
            return np.zeros(0, dtype=np.int32)
        return np.asarray(_act(key, sub, params), dtype=np.int32)

    def learn(self, key: jax.Array, state: tuple[HumanState, HumanParams], obs: np.ndarray,
              actions: np.ndarray, rewards: np.ndarray) -> tuple[HumanState, HumanParams]:
        sub, params = state
        new = _learn(key, sub, jnp.asarray(actions), -jnp.asarray(rewards, jnp.float32), params)
        return new, params


def make_baseline(name: str):
    """The baseline policy called `name` (aon, random, human)."""
    from urb_jax.core.errors import ConfigError

    if name == "aon":
        return AonPolicy()
    if name == "random":
        return RandomPolicy()
    if name == "human":
        return HumanPolicy()
    raise ConfigError(f"unknown baseline model '{name}'. Fix: use one of {', '.join(BASELINES)}.")
