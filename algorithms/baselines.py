"""Baseline CAV policies (URB_REFERENCE §9): aon, random, human; one table, `BASELINES`.

* aon: the minimum free-flow route (URB FFT, destination edge excluded), every day.
* random: a uniform route each day over each CAV's valid routes (padding repeats excluded).
* human: the CAV keeps the *trained* human model of that agent (costs C and personal beta from
  the human phase) and keeps learning with it, from -reward (= own time for selfish CAVs, as URB
  does with its CAV reward). URB instead builds a fresh model initialised at free-flow times; we
  keep the trained one because a "CAV that still behaves as its human" is then the no-change
  reference: with a selfish reward its days continue the human equilibrium, so any difference
  against other policies is due to the policy, not to forgetting 200 days of experience.

Each is a `CavPolicy` (init / act / learn over the CAV axis [C]), which the SUMO protocol drives
day by day (`urb_jax.training.protocol`, frozen in test days: it stops calling `learn`);
`baseline_policy` gives the same rule as a fixed `Policy` for `collect` / `evaluate`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.networks import take_agents
from urb_jax.algorithms.policy import masked
from urb_jax.core.choices import BASELINE_MODELS
from urb_jax.core.errors import ConfigError
from urb_jax.game.env import RoutingEnv
from urb_jax.game.humans import HumanParams, HumanState, act_jit, aon_routes, learn_jit
from urb_jax.game.rollout import Policy


class CavPolicy(Protocol):
    """A CAV decision rule over the CAV axis [C] (CAVs in departure order) that may learn from
    authoritative days. `init` sees the env after mutation (its `human_init`: the trained humans)."""

    @property
    def name(self) -> str: ...  # read-only: the policies are frozen dataclasses

    @property
    def uses_observation(self) -> bool: ...

    def init(self, key: jax.Array, env: RoutingEnv) -> Any: ...

    def act(self, key: jax.Array, state: Any, obs: jnp.ndarray, idx: jnp.ndarray | None = None
            ) -> jnp.ndarray: ...

    def learn(self, key: jax.Array, state: Any, obs: np.ndarray, actions: np.ndarray,
              rewards: np.ndarray) -> Any: ...


class _FixedRule:
    """A rule that does not learn: training days leave its state as it is."""

    def learn(self, key: jax.Array, state: jnp.ndarray, obs: np.ndarray, actions: np.ndarray,
              rewards: np.ndarray) -> jnp.ndarray:
        return state


@dataclass(frozen=True)
class AonPolicy(_FixedRule):
    name: str = "aon"
    uses_observation: bool = False

    def init(self, key: jax.Array, env: RoutingEnv) -> jnp.ndarray:
        """[C] int32 routes."""
        return jnp.asarray(aon_routes(env.scenario.fft, env.scenario.route_valid)[env.cav_index])

    def act(self, key: jax.Array, state: jnp.ndarray, obs: jnp.ndarray, idx: jnp.ndarray | None = None
            ) -> jnp.ndarray:
        return take_agents(state, idx)


@dataclass(frozen=True)
class RandomPolicy(_FixedRule):
    name: str = "random"
    uses_observation: bool = False

    def init(self, key: jax.Array, env: RoutingEnv) -> jnp.ndarray:
        """[C, K] uniform logits over valid routes (the key comes with each day's act)."""
        mask = jnp.asarray(env.action_mask)
        return masked(jnp.zeros(mask.shape), mask)

    def act(self, key: jax.Array, state: jnp.ndarray, obs: jnp.ndarray, idx: jnp.ndarray | None = None
            ) -> jnp.ndarray:
        return jax.random.categorical(key, take_agents(state, idx), axis=-1).astype(jnp.int32)


@dataclass(frozen=True)
class HumanPolicy:
    name: str = "human"
    uses_observation: bool = False

    def init(self, key: jax.Array, env: RoutingEnv) -> tuple[HumanState, HumanParams]:
        """The CAVs' rows of the trained humans (env.human_init) and the human model."""
        if env.human_init is None:
            raise ConfigError("the human baseline needs trained humans: build the env with human_init")
        return take_agents(env.human_init, jnp.asarray(env.cav_index)), env.human_params

    def act(self, key: jax.Array, state: tuple[HumanState, HumanParams], obs: jnp.ndarray,
            idx: jnp.ndarray | None = None) -> jnp.ndarray:
        sub, params = state
        return act_jit(key, take_agents(sub, idx), params)

    def learn(self, key: jax.Array, state: tuple[HumanState, HumanParams], obs: np.ndarray,
              actions: np.ndarray, rewards: np.ndarray) -> tuple[HumanState, HumanParams]:
        sub, params = state
        new = learn_jit(key, sub, jnp.asarray(actions), -jnp.asarray(rewards, jnp.float32), params)
        return new, params


@dataclass(frozen=True)
class FixedPolicy(_FixedRule):
    """A frozen policy trained outside urb-jax (JaxMARL, PyTorch via a callback, a rule) as a
    `CavPolicy`: `policy(key, obs [n, D], idx [n] | None) -> routes [n]` sees the env's own
    observations of the CAVs `idx` (rows of the CAV axis; None: all) and acts in departure order,
    as urb-jax's learners do (`game.rollout.act_by_levels`: it must be traceable by JAX)."""

    policy: Policy
    name: str = "outside"
    uses_observation: bool = True

    def init(self, key: jax.Array, env: RoutingEnv) -> None:
        return None

    def act(self, key: jax.Array, state: None, obs: jnp.ndarray, idx: jnp.ndarray | None = None
            ) -> jnp.ndarray:
        return self.policy(key, obs, idx)


# The names are urb_jax.core.choices.BASELINE_MODELS (`urb-jax baseline --model`, read without JAX).
BASELINES: dict[str, type[CavPolicy]] = dict(zip(BASELINE_MODELS, (AonPolicy, RandomPolicy, HumanPolicy),
                                                 strict=True))


def make_baseline(name: str) -> CavPolicy:
    """The baseline policy called `name` (aon, random, human)."""
    if name not in BASELINES:
        raise ConfigError(f"unknown baseline model '{name}'. Fix: use one of {', '.join(BASELINES)}.")
    return BASELINES[name]()


def baseline_policy(name: str, env: RoutingEnv, key: jax.Array | None = None) -> Policy:
    """The baseline as a fixed `Policy(key, obs, idx=None)` on `env` (state from `init(key)`; a
    learning baseline does not learn here), e.g. for `collect` / `evaluate` on a surrogate."""
    baseline = make_baseline(name)
    state = baseline.init(jax.random.PRNGKey(0) if key is None else key, env)

    def policy(k: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
        return baseline.act(k, state, obs, idx)

    return policy
