"""The routing game as a functional JAX environment (gymnax / JaxMARL style).

One step = one day. CAVs (a fixed set after mutation) pick routes; humans pick by their learned
model (`urb_jax.game.humans`); travel times come from a jittable `travel_time_fn` (the surrogate,
or anything else) or are measured outside (SUMO: `step_with_times`); CAV rewards follow the task's
behaviour (`urb_jax.game.rewards`). Parameters of `travel_time_fn` are explicit, gymnax-style:
`step(key, state, actions, params)`, so a refitted surrogate swaps in without recompiling; an
env with `default_params` calls `travel_time_fn(params, choices)`, one without `travel_time_fn(choices)`;
where departures or demand vary day to day the day's departure shifts [N] come last.

Departure order (AEC semantics): a CAV observes the choices of agents that departed earlier
today. Humans' choices for a day are drawn when the previous day ends (stored in the state), so
`observe(state, cav_actions)` is a pure function; `urb_jax.game.rollout` makes the CAVs choose in
departure order on it.

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
from urb_jax.game.demand import ABSENT, DayDemand, DepartureJitter, scenario_on_day, travelled
from urb_jax.game.humans import HumanParams, HumanState, act, act_jit, aon_routes, end_day_jit, init_humans
from urb_jax.game.observations import ObservationSpec, make_observation_spec, observe
from urb_jax.game.rewards import (
    CREDITS,
    cav_rewards,
    credit_rewards,
    externalities,
    fleet_rewards,
    marginal_cost_rewards,
)

# Parameters of travel_time_fn (a pytree, e.g. the surrogate's); None for a parameter-free model.
EnvParams = Any
# travel_time_fn(choices[N]) -> minutes [N], or travel_time_fn(params, choices[N]) with default_params;
# with depart_jitter or day_demand also the day's departure shifts: travel_time_fn(params, choices, shift).
TravelTimeFn = Callable[..., jnp.ndarray]
StepResult = tuple[jnp.ndarray, "EnvState", jnp.ndarray, jnp.ndarray, dict[str, jnp.ndarray]]
Margins = tuple[jnp.ndarray, jnp.ndarray]  # (externalities [3, N], model times [N]): rewards.externalities


class DayKeys(NamedTuple):
    """The keys of a day's end: the humans' learning today and their draw of tomorrow's routes.
    `step` splits one key into them; a caller with its own key schedule (the SUMO protocol,
    PettingZoo) passes them to `step_with_times`, so each driver keeps its bytes."""

    learn: jax.Array
    act_next: jax.Array


class EnvState(NamedTuple):
    humans: HumanState
    human_actions: jnp.ndarray  # [N] today's human choices (entries of CAVs unused)
    cav_actions: jnp.ndarray  # [C] yesterday's CAV choices (observation fallback)
    times: jnp.ndarray  # [N] yesterday's travel times, minutes
    day: jnp.ndarray  # int32


@dataclass(frozen=True, eq=False)
class RoutingEnv:
    scenario: Scenario
    is_cav: np.ndarray  # [N] bool, fixed after mutation
    travel_time_fn: TravelTimeFn | None = None  # None: days are simulated outside (step_with_times)
    human_params: HumanParams = field(default_factory=HumanParams)
    reward_coefficients: tuple[float, float, float, float] = (-1.0, 0.0, 0.0, 0.0)
    observation_type: str = "previous_agents_plus_start_time"
    humans_adapt: bool = False  # humans keep learning while CAVs train
    human_init: HumanState | None = None  # trained human knowledge from the human phase
    default_params: EnvParams = None  # set: travel_time_fn takes (params, choices); step's default
    # "marginal": CAVs are paid per-agent credit from the travel-time model's derivative
    # (game.rewards.credit_rewards); travel_time_fn must then also take probabilities [N, K]
    reward_credit: str = "group"
    # URB's marginal-cost tasks: minus beta x the delay each CAV adds to everyone else, from the same
    # derivative (game.rewards.marginal_cost_rewards); 0: none
    marginal_cost_beta: float = 0.0
    # Demand that varies day to day (game.demand): who travels on day `state.day`; None: everyone
    day_demand: DayDemand | None = None
    # Departures that vary day to day (game.demand): SUMO's day `state.day` runs `sumo_scenario(day)`;
    # None: as scheduled. Where departures or demand vary (`varies_insertion`), travel_time_fn takes
    # the day's departure shifts [N] (zeros without jitter) as a last argument
    depart_jitter: DepartureJitter | None = None
    # Competing fleets (game.mutation.split_fleets): [N] each agent's fleet, -1 for a human, and each
    # fleet's reward coefficients; None: one fleet, paid `reward_coefficients`
    cav_fleet: np.ndarray | None = None
    fleet_coefficients: tuple[tuple[float, float, float, float], ...] | None = None

    @property
    def varies_insertion(self) -> bool:
        """SUMO's insertion order changes day to day (departures or who travels), and with it the
        speed factor each driver gets: travel_time_fn is told the day's departures."""
        return self.depart_jitter is not None or self.day_demand is not None

    def day_shifts(self, day: jax.Array | int) -> jax.Array:
        """[N] seconds each driver leaves off its schedule on day `day` (zeros without jitter)."""
        if self.depart_jitter is None:
            return jnp.zeros(self.n_agents, jnp.float32)
        return self.depart_jitter.shift(day, self.scenario.agent_depart)

    @property
    def uses_model(self) -> bool:
        """Its rewards need the travel-time model's derivative (marginal credit or marginal cost)."""
        return self.reward_credit == "marginal" or self.marginal_cost_beta != 0.0

    def __post_init__(self) -> None:
        if self.reward_credit not in CREDITS:
            raise ValueError(f"reward_credit {self.reward_credit!r}: use one of {CREDITS}")
        if self.day_demand is not None and self.uses_model:
            raise ValueError("day_demand with reward_credit 'marginal' or marginal_cost_beta: the model's "
                             "externalities do not leave out the drivers who stay home")
        if (self.cav_fleet is None) != (self.fleet_coefficients is None):
            raise ValueError("cav_fleet and fleet_coefficients go together")
        if self.cav_fleet is not None and (self.uses_model or self.day_demand is not None):
            raise ValueError("fleets support group rewards and fixed demand only")
        scn = self.scenario
        is_cav = np.asarray(self.is_cav, dtype=bool)
        object.__setattr__(self, "is_cav", is_cav)
        if self.cav_fleet is not None:
            fleet = np.asarray(self.cav_fleet, dtype=np.int32)
            if fleet.shape != is_cav.shape or not np.array_equal(fleet >= 0, is_cav):
                raise ValueError("cav_fleet [N] must name a fleet (>= 0) for exactly the CAVs")
            object.__setattr__(self, "cav_fleet", fleet)
        object.__setattr__(self, "cav_index", np.flatnonzero(is_cav))
        spec = make_observation_spec(self.observation_type, scn.agent_od, scn.agent_depart, scn.k)
        object.__setattr__(self, "obs_spec", spec)
        object.__setattr__(self, "_day_outputs_jit", jax.jit(self._day_outputs))

    cav_index: np.ndarray = field(init=False)
    obs_spec: ObservationSpec = field(init=False)
    _day_outputs_jit: Callable[..., tuple[jnp.ndarray, dict[str, jnp.ndarray]]] = field(init=False,
                                                                                           repr=False)

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
        cav_actions = jnp.asarray(aon_routes(scn.fft, scn.route_valid)[self.cav_index])
        state = EnvState(humans, human_actions, cav_actions, jnp.asarray(scn.fft_full.min(axis=1)),
                         jnp.zeros((), jnp.int32))
        return self.observe(state, cav_actions), state

    def joint_actions(self, state: EnvState, cav_actions: jnp.ndarray) -> jnp.ndarray:
        """[N] everyone's route today; ABSENT (-1) for a driver who stays home on day `state.day`
        (`day_demand`), so every consumer of the day's choices (observations, SUMO, the
        surrogate, the humans' learning) sees the same drivers."""
        joint = state.human_actions.at[self.cav_index].set(cav_actions.astype(jnp.int32))
        if self.day_demand is None:
            return joint
        return jnp.where(self.day_demand.present(state.day, self.n_agents), joint, ABSENT)

    def sumo_scenario(self, day: int) -> Scenario:
        """The Scenario SUMO runs on day index `day` (`state.day`, the index `day_demand` draws on):
        the env's own, or with that day's departures (`depart_jitter`)."""
        return scenario_on_day(self.scenario, self.depart_jitter, int(day))

    def active(self, state: EnvState) -> jnp.ndarray | None:
        """[C] bool: the CAVs that travel on day `state.day` (None: every CAV, fixed demand)."""
        if self.day_demand is None:
            return None
        return self.day_demand.present(state.day, self.n_agents)[self.cav_index]

    def observe(self, state: EnvState, cav_actions: jnp.ndarray) -> jnp.ndarray:
        """[C, obs_size] CAV observations given today's CAV choices (earlier departures only count)."""
        obs_all = observe(self.obs_spec, self.joint_actions(state, cav_actions))
        return obs_all[self.cav_index]

    def global_state(self, obs: jnp.ndarray) -> jnp.ndarray:
        """Centralised critic / mixer input: every CAV's observation, flattened [C * obs_size]."""
        return obs.reshape(*obs.shape[:-2], -1)

    def travel_times(self, params: EnvParams, choices: jnp.ndarray, day: jax.Array | int | None = None
                     ) -> jnp.ndarray:
        """[N] minutes of `choices` [N] from travel_time_fn (params None: default_params) on day
        index `day` (`state.day`; needed where departures or demand vary: the fn gets the day's shifts)."""
        if self.travel_time_fn is None:
            raise TypeError("this env has no travel_time_fn: its days are simulated outside "
                            "(use step_with_times)")
        args = (choices,) if self.default_params is None else (
            self.default_params if params is None else params, choices)
        if not self.varies_insertion:
            return self.travel_time_fn(*args)
        if day is None:
            raise ValueError("departures or demand vary day to day: travel_times needs the day index")
        return self.travel_time_fn(*args, self.day_shifts(day))

    def step(self, key: jax.Array, state: EnvState, cav_actions: jnp.ndarray,
             params: EnvParams = None) -> StepResult:
        """Simulate one day with travel_time_fn under `params` (default_params when None). Returns
        (provisional obs for tomorrow, state, CAV rewards [C], dones [C] (every day ends the CAVs'
        episode, as in URB), info)."""
        choices = self.joint_actions(state, cav_actions)
        keys = DayKeys(*jax.random.split(key))
        if self.uses_model:
            model = self.model_externalities(params, choices, state.day)
            return self._end_day(keys, state, cav_actions, choices, model[1], model)
        return self._end_day(keys, state, cav_actions, choices, self.travel_times(params, choices, state.day))

    def model_externalities(self, params: EnvParams, choices: jnp.ndarray,
                            day: jax.Array | int | None = None) -> Margins:
        """(externalities [3, N], model times [N]) of `choices` under travel_time_fn on day index
        `day` (game.rewards.externalities)."""
        return externalities(lambda probs: self.travel_times(params, probs, day), choices, self.is_cav,
                             self.n_actions)

    def step_with_times(self, key: jax.Array | DayKeys, state: EnvState, cav_actions: jnp.ndarray,
                        times: jnp.ndarray, model: Margins | None = None) -> StepResult:
        """The same day with measured travel times [N] (minutes, e.g. SUMO's) of today's choices;
        `key`: split as `step` splits it, or the day's explicit `DayKeys`; `model`:
        `model_externalities` of today's choices under a travel-time model (required with
        reward_credit marginal: SUMO measures the day, the model its derivative)."""
        keys = key if isinstance(key, DayKeys) else DayKeys(*jax.random.split(key))
        return self._end_day(keys, state, cav_actions, self.joint_actions(state, cav_actions), times, model)

    def _end_day(self, keys: DayKeys, state: EnvState, cav_actions: jnp.ndarray, choices: jnp.ndarray,
                 times: jnp.ndarray, model: Margins | None = None) -> StepResult:
        """The one day transition: CAV rewards, the humans' day end (they learn when the task lets
        them adapt), tomorrow's human choices. Called eagerly (a SUMO day at a time), the rewards
        run op by op and the rest as three compiled calls; traced, those inline."""
        is_cav = jnp.asarray(self.is_cav)
        if self.uses_model and model is None:
            raise ValueError("reward_credit 'marginal' and marginal_cost_beta need the model's externalities "
                             "of a measured day (step_with_times(..., model=env.model_externalities(params, "
                             "choices)))")
        went = None if self.day_demand is None else travelled(choices)  # [N] who travelled
        if went is not None:  # a driver who stayed home has no time (SUMO: NaN): 0, masked below
            times = jnp.where(went, times, 0.0)
        if self.cav_fleet is not None:
            assert self.fleet_coefficients is not None  # __post_init__: they go together
            rewards_all = fleet_rewards(times, self.cav_fleet, self.fleet_coefficients)
        elif self.reward_credit == "marginal":
            assert model is not None  # uses_model: refused above when missing
            rewards_all = credit_rewards(times, is_cav, self.reward_coefficients, model[0])
        else:
            rewards_all = cav_rewards(times, is_cav, self.reward_coefficients, went)
        if went is not None:
            rewards_all = jnp.where(went, rewards_all, 0.0)
        if self.marginal_cost_beta != 0.0:
            assert model is not None  # uses_model: refused above when missing
            rewards_all = marginal_cost_rewards(rewards_all, model[0], self.marginal_cost_beta)
        humans = end_day_jit(keys.learn, state.humans, choices, times, self.human_params, self.is_cav,
                             learn_today=self.humans_adapt, travelled=went)
        human_actions = act_jit(keys.act_next, humans, self.human_params, jnp.asarray(self.scenario.fft))
        new_state = EnvState(humans, human_actions, cav_actions.astype(jnp.int32), times, state.day + 1)
        next_obs, info = self._day_outputs_jit(new_state, choices)
        return next_obs, new_state, rewards_all[self.cav_index], jnp.ones((self.n_cavs,), dtype=bool), info

    def _day_outputs(self, new_state: EnvState, choices: jnp.ndarray
                     ) -> tuple[jnp.ndarray, dict[str, jnp.ndarray]]:
        """(tomorrow's provisional CAV observations [C, D], the day's info) after a day (jitted once
        per env as `_day_outputs_jit`)."""
        is_cav, times = jnp.asarray(self.is_cav), new_state.times
        cav, human = is_cav, ~is_cav
        if self.day_demand is not None:  # the day's means cover the drivers who travelled
            went = travelled(choices)
            cav, human = cav & went, human & went
        info = {
            "times": times,
            "choices": choices,
            "mean_time_cav": jnp.where(cav, times, 0.0).sum() / jnp.maximum(cav.sum(), 1),
            "mean_time_human": jnp.where(human, times, 0.0).sum() / jnp.maximum(human.sum(), 1),
        }
        if self.day_demand is not None:
            info["active"] = went[self.cav_index]  # [C] the CAVs that travelled (acted) today
        return self.observe(new_state, new_state.cav_actions), info
