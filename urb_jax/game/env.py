"""The routing game as a functional JAX environment (gymnax / JaxMARL style).

One step = one day. CAVs (a fixed set after mutation) pick routes; humans pick by their learned
model (`urb_jax.humans`); travel times come from a jittable `travel_time_fn(choices[N]) -> [N]`
(the surrogate, or anything else); CAV rewards follow the task's behaviour (`urb_jax.rewards`).
When `travel_params` is given, the function is called as `travel_time_fn(params, choices)` with
the params read from the state: a refitted surrogate then swaps in with `with_travel_params`
without recompiling anything.

Departure order (AEC semantics): a CAV observes the choices of agents that departed earlier
today. Humans' choices for a day are drawn when the previous day ends (stored in the state), so
`observe(state, cav_actions)` is a pure function; `act_in_order` iterates obs -> act `depth`
times, which reproduces the sequential order exactly (see `urb_jax.observations`).

Arrays over CAVs use the CAV axis [C] (CAVs in departure order); arrays over all agents use the
Scenario's agent axis [N].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.game.humans import HumanParams, HumanState, act, init_humans, learn
from urb_jax.game.observations import ObservationSpec, dependency_depth, make_observation_spec, observe
from urb_jax.game.rewards import cav_rewards

TravelTimeFn = Callable[[jnp.ndarray], jnp.ndarray]
PolicyFn = Callable[[jax.Array, jnp.ndarray], jnp.ndarray]  # (key, obs[C, D]) -> actions[C]


class EnvState(NamedTuple):
    humans: HumanState
    human_actions: jnp.ndarray  # [N] today's human choices (entries of CAVs unused)
    cav_actions: jnp.ndarray  # [C] yesterday's CAV choices (observation fallback)
    times: jnp.ndarray  # [N] yesterday's travel times, minutes
    day: jnp.ndarray  # int32
    travel_params: Any = None  # parameters of travel_time_fn (e.g. the surrogate's), if any


@dataclass(frozen=True, eq=False)
class RoutingEnv:
    scenario: Scenario
    is_cav: np.ndarray  # [N] bool, fixed after mutation
    travel_time_fn: TravelTimeFn
    human_params: HumanParams = field(default_factory=HumanParams)
    reward_coefficients: tuple[float, float, float, float] = (-1.0, 0.0, 0.0, 0.0)
    observation_type: str = "previous_agents_plus_start_time"
    humans_adapt: bool = False  # humans keep learning while CAVs train
    human_init: HumanState | None = None  # trained human knowledge from the human phase
    travel_params: Any = None  # if set: travel_time_fn(params, choices), params carried in the state

    def __post_init__(self) -> None:
        scn = self.scenario
        is_cav = np.asarray(self.is_cav, dtype=bool)
        object.__setattr__(self, "is_cav", is_cav)
        object.__setattr__(self, "cav_index", np.flatnonzero(is_cav))
        spec = make_observation_spec(self.observation_type, scn.agent_od, scn.agent_depart, scn.k)
        object.__setattr__(self, "obs_spec", spec)
        depth = dependency_depth(scn.agent_od, scn.agent_depart, is_cav, self.observation_type)
        object.__setattr__(self, "depth", max(depth, 1))

    cav_index: np.ndarray = field(init=False)
    obs_spec: ObservationSpec = field(init=False)
    depth: int = field(init=False)

    # ---- sizes
    @property
    def n_agents(self) -> int:
        return self.scenario.n_agents

    @property
    def n_cavs(self) -> int:
        return int(self.cav_index.shape[0])

    @property
    def n_actions(self) -> int:
        return self.scenario.k

    @property
    def obs_size(self) -> int:
        return self.obs_spec.size

    @property
    def action_mask(self) -> np.ndarray:
        """[C, K] routes that exist (False for padding repeats)."""
        return self.scenario.route_valid[self.cav_index]

    @property
    def cav_od(self) -> np.ndarray:
        """[C] OD index of each CAV, e.g. for an OD embedding."""
        return self.scenario.agent_od[self.cav_index]

    # ---- functional API
    def reset(self, key: jax.Array) -> tuple[jnp.ndarray, EnvState]:
        k_init, k_act = jax.random.split(key)
        scn = self.scenario
        humans = self.human_init
        if humans is None:
            fft, valid = jnp.asarray(scn.fft), jnp.asarray(scn.route_valid)
            humans = init_humans(k_init, fft, valid, self.human_params)
        human_actions = act(k_act, humans, self.human_params, jnp.asarray(scn.fft))
        free_flow_choice = jnp.asarray(np.argmin(np.where(scn.route_valid, scn.fft, np.inf), axis=1))
        cav_actions = free_flow_choice[self.cav_index].astype(jnp.int32)
        state = EnvState(humans, human_actions, cav_actions, jnp.asarray(scn.fft_full.min(axis=1)),
                         jnp.zeros((), jnp.int32), self.travel_params)
        return self.observe(state, cav_actions), state

    def joint_actions(self, state: EnvState, cav_actions: jnp.ndarray) -> jnp.ndarray:
        """[N] everyone's route today."""
        return state.human_actions.at[self.cav_index].set(cav_actions.astype(jnp.int32))

    def observe(self, state: EnvState, cav_actions: jnp.ndarray) -> jnp.ndarray:
        """[C, obs_size] CAV observations given today's CAV choices (earlier departures only count)."""
        obs_all = observe(self.obs_spec, self.joint_actions(state, cav_actions))
        return obs_all[self.cav_index]

    @staticmethod
    def with_travel_params(state: EnvState, params: Any) -> EnvState:
        """Swap the travel-time parameters of a (batched) state; batch axes are broadcast."""
        batch = state.day.shape
        return state._replace(travel_params=jax.tree_util.tree_map(
            lambda p: jnp.broadcast_to(p, batch + jnp.shape(p)), params))

    def global_state(self, obs: jnp.ndarray) -> jnp.ndarray:
        """Centralised critic / mixer input: every CAV's observation, flattened [C * obs_size]."""
        return obs.reshape(*obs.shape[:-2], -1)

    def act_in_order(
        self, key: jax.Array, state: EnvState, policy: PolicyFn
    ) -> tuple[jnp.ndarray, jnp.ndarray]:
        """(obs [C, D], actions [C]) consistent with departure order. The same key is used in every
        round, so a CAV's action changes only if its observation did."""
        actions = state.cav_actions

        def round_(actions, _):
            obs = self.observe(state, actions)
            return policy(key, obs).astype(jnp.int32), None

        actions, _ = jax.lax.scan(round_, actions, None, length=self.depth)
        return self.observe(state, actions), actions

    def step(
        self, key: jax.Array, state: EnvState, cav_actions: jnp.ndarray
    ) -> tuple[jnp.ndarray, EnvState, jnp.ndarray, jnp.ndarray, dict[str, jnp.ndarray]]:
        """Simulate one day. Returns (provisional obs for tomorrow, state, CAV rewards [C],
        dones [C] (every day ends the CAVs' episode, as in URB), info)."""
        k_learn, k_act = jax.random.split(key)
        choices = self.joint_actions(state, cav_actions)
        if self.travel_params is None:
            times = self.travel_time_fn(choices)
        else:
            times = self.travel_time_fn(state.travel_params, choices)
        rewards_all = cav_rewards(times, jnp.asarray(self.is_cav), self.reward_coefficients)
        humans = state.humans
        if self.humans_adapt or self.n_cavs == 0:
            is_human = ~jnp.asarray(self.is_cav)
            humans = learn(k_learn, humans, choices, times, self.human_params, learning=is_human)
        else:
            humans = humans._replace(last_action=choices)
        human_actions = act(k_act, humans, self.human_params, jnp.asarray(self.scenario.fft))
        new_state = EnvState(humans, human_actions, cav_actions.astype(jnp.int32), times, state.day + 1,
                             state.travel_params)
        rewards = rewards_all[self.cav_index]
        dones = jnp.ones((self.n_cavs,), dtype=bool)
        is_cav = jnp.asarray(self.is_cav)
        info = {
            "times": times,
            "choices": choices,
            "mean_time_cav": jnp.where(is_cav, times, 0.0).sum() / jnp.maximum(is_cav.sum(), 1),
            "mean_time_human": jnp.where(~is_cav, times, 0.0).sum() / jnp.maximum((~is_cav).sum(), 1),
        }
        return self.observe(new_state, new_state.cav_actions), new_state, rewards, dones, info
