"""The surrogate-backed routing game as a JaxMARL `MultiAgentEnv` (optional: pip install 'urb-jax[jaxmarl]').

JaxMARL's baselines (IPPO, MAPPO, IQL, ...) expect `reset(key) -> (obs dict, state)`,
`step(key, state, actions dict) -> (obs, state, rewards, dones, infos)`, `agents`,
`observation_space(agent)`, `action_space(agent)`. `JaxMARLRoutingEnv` gives them over a
`RoutingEnv` whose days the calibrated surrogate simulates (`urb_jax.interop.outside`), so such
a baseline trains on a URB network unchanged, and `evaluate_on_sumo` (same module) judges it in SUMO.

Semantics (docs/jaxmarl.md):
* agents: the CAVs, named `cav_<agent id>`, in departure order; actions: a route index < K.
* one step is one day; every CAV's episode ends with its day (dones all True, as in URB) and the
  next day continues the same world (humans, yesterday's choices): the base class's auto-reset
  would forget both, so `step` does not reset.
* rewards: exactly `RoutingEnv.step`'s (the task's behaviour, minutes), under `params`.
* observations: all CAVs act at once on the observation of the day's start: today's human
  choices and the CAVs' choices of yesterday (`RoutingEnv.observe(state, state.cav_actions)`).
  urb-jax's own learners act in departure order instead (a CAV sees earlier CAVs' choices of the
  same day, `game.rollout`); a MultiAgentEnv step takes every action at once, so it cannot. At a
  fixed point of the policy (yesterday's choices repeated) the two coincide. `evaluate_on_sumo`
  acts in departure order, URB's order.
* `normalize_obs` divides by urb-jax's own scale (start time / latest departure, counts / the
  largest OD group, `algorithms.networks.obs_scale`); `od_onehot` appends the CAV's OD as a one-hot over
  the CAVs' ODs (what URB's TorchRL scripts give shared networks as an embedding).
* infos: `travel_time` [per agent] (minutes), so JaxMARL scripts that reshape infos per actor work.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np
from jaxmarl.environments.multi_agent_env import MultiAgentEnv
from jaxmarl.environments.spaces import Box, Discrete

from urb_jax.algorithms.networks import obs_scale
from urb_jax.core.errors import ConfigError
from urb_jax.game.env import EnvParams, EnvState, RoutingEnv
from urb_jax.game.rollout import Policy

Obs = dict[str, jnp.ndarray]


class RoutingState(NamedTuple):
    """The day's state and the travel-time model's parameters. The parameters travel in the state
    so that the jitted step takes them as arguments (design change 7): closed over as constants,
    XLA constant-folds the surrogate for minutes, and a refit could not swap them."""

    day: EnvState
    params: EnvParams


class JaxMARLRoutingEnv(MultiAgentEnv):
    """`env`'s days (travel_time_fn under `params`, default env.default_params) for JaxMARL."""

    def __init__(self, env: RoutingEnv, params: EnvParams = None, *, normalize_obs: bool = True,
                 od_onehot: bool = False) -> None:
        if env.travel_time_fn is None:
            raise ValueError("JaxMARLRoutingEnv needs an env with a travel_time_fn (the surrogate): "
                             "build it with urb_jax.interop.outside.surrogate_env_from_run")
        if env.n_cavs == 0:
            raise ValueError("the env has no CAV: a JaxMARL env needs at least one agent")
        if env.day_demand is not None:
            raise ConfigError("task key 'day_participation' < 1: the JaxMARL env gives every CAV a turn "
                              "every day and has no mask for the CAVs who stay home. Fix: set "
                              "day_participation to 1 in the run's task config.")
        if env.cav_fleet is not None:
            raise ConfigError("task key 'fleets': the JaxMARL env has one CAV fleet. Fix: train fleets with "
                              "`urb-jax train`, or use a run without 'fleets'.")
        super().__init__(env.n_cavs)
        self.env = env
        self.params = env.default_params if params is None else params
        self.agents = [f"cav_{int(a)}" for a in env.scenario.agent_id[env.cav_index]]
        self.scale = obs_scale(env) if normalize_obs else np.ones(env.obs_size, np.float32)  # [D]
        ods = env.cav_od
        self.od_rank = np.unique(ods, return_inverse=True)[1] if od_onehot else None  # [C]
        self.n_features = env.obs_size + (int(cast(np.ndarray, self.od_rank).max()) + 1 if od_onehot else 0)
        self.observation_spaces = {a: Box(0.0, np.inf, (self.n_features,)) for a in self.agents}
        self.action_spaces = {a: Discrete(env.n_actions) for a in self.agents}

    # ---- observations
    def features(self, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
        """[n, F] what the agents see, from the env's raw observations [n, D] of CAVs `idx` (rows of
        the CAV axis; None: all C)."""
        x = jnp.asarray(obs, jnp.float32) / jnp.asarray(self.scale)
        if self.od_rank is None:
            return x
        rank = jnp.asarray(self.od_rank) if idx is None else jnp.asarray(self.od_rank)[idx]
        return jnp.concatenate([x, jax.nn.one_hot(rank, self.n_features - x.shape[-1])], axis=-1)

    def as_dict(self, x: jnp.ndarray) -> Obs:
        return {a: x[i] for i, a in enumerate(self.agents)}

    # override: JaxMARL types its methods with its own envs' State; this env's state is RoutingState
    def get_obs(self, state: RoutingState) -> Obs:  # type: ignore[override]
        return self.as_dict(self.features(self.env.observe(state.day, state.day.cav_actions)))

    # ---- the MultiAgentEnv interface
    @partial(jax.jit, static_argnums=(0,))
    def reset(self, key: jax.Array) -> tuple[Obs, RoutingState]:
        state = RoutingState(self.env.reset(key)[1], self.params)
        return self.get_obs(state), state

    @partial(jax.jit, static_argnums=(0,))
    def step(self, key: jax.Array, state: RoutingState, actions: dict[str, jnp.ndarray],
             reset_state: RoutingState | None = None) -> tuple[Obs, RoutingState, dict, dict, dict]:
        """One day. No auto-reset: the day ends every episode, the world goes on (module doc);
        `reset_state`, given, replaces the next day's state (JaxMARL's override)."""
        obs, state, rewards, dones, infos = self.step_env(key, state, actions)
        if reset_state is not None:
            state, obs = reset_state, self.get_obs(reset_state)
        return obs, state, rewards, dones, infos

    def step_env(self, key: jax.Array, state: RoutingState, actions: dict[str, jnp.ndarray]  # type: ignore[override]
                 ) -> tuple[Obs, RoutingState, dict, dict, dict]:
        # [C]; an action may come as shape () or (1,) (JaxMARL's unbatchify gives (1,))
        cav_actions = jnp.stack([jnp.asarray(actions[a]).reshape(()) for a in self.agents]).astype(jnp.int32)
        _, day, rewards, dones, info = self.env.step(key, state.day, cav_actions, state.params)
        state = RoutingState(day, state.params)
        times = info["times"][jnp.asarray(self.env.cav_index)]  # [C]
        done = {a: dones[i] for i, a in enumerate(self.agents)} | {"__all__": jnp.all(dones)}
        return (self.get_obs(state), state, {a: rewards[i] for i, a in enumerate(self.agents)}, done,
                {"travel_time": times})

    @partial(jax.jit, static_argnums=(0,))
    def get_avail_actions(self, state: RoutingState) -> dict[str, jnp.ndarray]:
        """Routes that exist; a padding slot repeats a real route, so choosing it is harmless."""
        mask = jnp.asarray(self.env.action_mask)  # [C, K]
        return {a: mask[i] for i, a in enumerate(self.agents)}

    @property
    def agent_classes(self) -> dict[str, list[str]]:
        return {"cav": list(self.agents)}

    # ---- back to urb-jax
    def policy(self, act: Policy) -> Policy:
        """urb-jax's `Policy(key, obs [n, D], idx)` (raw observations, e.g. for `evaluate_on_sumo`)
        from a JaxMARL-side `act(key, features [n, F]) -> routes [n]`."""
        def policy(key: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
            return act(key, self.features(obs, idx))

        return policy
