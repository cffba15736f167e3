"""The URB experiment over authoritative days (URB_REFERENCE §5): human learning for H days ->
mutation -> CAV training days -> test days (CAV policies frozen).

Days run one at a time on a `DayExecutor` (SUMO in this process by default; a run passes its
own, tests a fake), because day t+1's human choices depend on day t's times. After mutation a day
ends with the game's one day transition (`RoutingEnv.step_with_times`, under this protocol's day
keys); CAV policies follow the `CavPolicy` protocol (`urb_jax.algorithms.baselines`) and choose
in departure order (`urb_jax.game.rollout`). Every day is handed to `sink` (the results writer)
as a `DayRecord`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.baselines import CavPolicy
from urb_jax.city.scenario import Scenario
from urb_jax.core.progress import Progress
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.demand import ABSENT
from urb_jax.game.env import DayKeys, EnvState, RoutingEnv
from urb_jax.game.humans import (
    HumanParams,
    HumanState,
    act,
    act_jit,
    aon_routes,
    end_day,
    end_day_jit,
    init_humans_jit,
)
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.rollout import act_at_once, act_by_levels
from urb_jax.reporting.records import DayRecord
from urb_jax.sumo_bridge import DayExecutor, InProcessExecutor, one_day

PHASE_HUMAN, PHASE_TRAIN, PHASE_TEST = "human", "train", "test"


@dataclass
class ExperimentOutcome:
    is_cav: np.ndarray
    humans: HumanState
    policy_state: Any
    days: int
    human_days: int
    training_days: int
    test_days: int


def run_experiment(
    scenario: Scenario,
    task: TaskConfig,
    env: EnvConfig,
    policy: CavPolicy,
    *,
    env_seed: int = 42,
    executor: DayExecutor | None = None,
    sink: Callable[[DayRecord], None] | None = None,
    training_days: int | None = None,
    progress: bool = False,
    sumo: bool = True,
) -> ExperimentOutcome:
    """Run the phases; return the final state. `executor` runs the days (None: SUMO in this
    process, closed at the end); `training_days` defaults to task.training_eps."""
    days = InProcessExecutor() if executor is None else executor
    try:
        return _phases(scenario, task, env, policy, env_seed, days, sink, training_days, progress, sumo)
    finally:
        if executor is None:
            days.close()


def _phases(scenario: Scenario, task: TaskConfig, env: EnvConfig, policy: CavPolicy, env_seed: int,
            executor: DayExecutor, sink: Callable[[DayRecord], None] | None, training_days: int | None,
            progress: bool, sumo: bool) -> ExperimentOutcome:
    T = task.training_eps if training_days is None else int(training_days)
    H, E = task.human_learning_episodes, task.test_eps
    bar = Progress(H + T + E, progress)
    # Phase 1: human learning; mutation.
    hp = task.human_params()
    humans = train_humans(scenario, hp, H, env_seed=env_seed, executor=executor, bar=bar, sink=sink,
                          sumo=sumo)
    is_cav = draw_cavs(env_seed, scenario.n_agents, task.ratio_machines, agent_id=scenario.agent_id)
    game = RoutingEnv(scenario, is_cav, human_params=hp,
                      reward_coefficients=task.reward_coefficients, observation_type=env.observations,
                      humans_adapt=task.should_humans_adapt, human_init=humans,
                      day_demand=task.day_demand(env_seed), depart_jitter=task.departure_jitter(env_seed))
    pstate = policy.init(jax.random.fold_in(jax.random.PRNGKey(env_seed), 0x2), game)
    # Phases 3-4: CAV training, then test with frozen policies.
    cav_days = _CavDays(game, policy, env_seed, executor, bar, sink, sumo)
    pstate, humans = cav_days.run(pstate, range(H + 1, H + T + E + 1), H + T)
    bar.close()
    return ExperimentOutcome(is_cav, humans, pstate, H + T + E, H, T, E)


def _protocol_keys(root: jax.Array, day: int) -> jax.Array:
    """[4] keys of a day after mutation: the humans' draw, their learning, the CAVs' acting, the
    policy's learning."""
    return jax.random.split(jax.random.fold_in(root, day), 4)


@dataclass(frozen=True)
class _CavDays:
    """The days after mutation: humans choose, CAVs choose in departure order, the day runs, the
    game's day transition pays the CAVs and ends the humans' day, the policy learns (training days).

    Keys per day: k_act, k_learn, k_cav, k_plearn = split(fold_in(PRNGKey(env_seed), day), 4); the
    day ends under DayKeys(k_learn, tomorrow's k_act). Humans learn only when the task lets them
    adapt (`game.humans_adapt`), with or without CAVs."""

    game: RoutingEnv
    policy: CavPolicy
    env_seed: int
    executor: DayExecutor
    bar: Progress
    sink: Callable[[DayRecord], None] | None
    sumo: bool

    def run(self, pstate: Any, days: range, last_train_day: int) -> tuple[Any, HumanState]:
        """(policy state, humans) after `days`, training on those up to `last_train_day`."""
        game, root = self.game, jax.random.PRNGKey(self.env_seed)
        scn, hp = game.scenario, game.human_params
        humans = game.human_init
        assert humans is not None  # run_experiment builds the game with the trained humans
        # Before the first CAV day, as env.reset: yesterday's CAV routes AON, times free-flow.
        keys = _protocol_keys(root, days[0])
        state = EnvState(humans, act_jit(keys[0], humans, hp, jnp.asarray(scn.fft, dtype=jnp.float32)),
                         jnp.asarray(aon_routes(scn.fft, scn.route_valid)[game.cav_index]),
                         jnp.asarray(scn.fft_full.min(axis=1)), jnp.asarray(days[0] - 1, jnp.int32))
        for day in days:
            phase = PHASE_TRAIN if day <= last_train_day else PHASE_TEST
            tomorrow = _protocol_keys(root, day + 1)
            pstate, state = self._day(pstate, state, day, phase, keys, tomorrow[0])
            keys = tomorrow
        return pstate, state.humans

    def _day(self, pstate: Any, state: EnvState, day: int, phase: str, keys_today: jax.Array,
             k_act_tomorrow: jax.Array) -> tuple[Any, EnvState]:
        game = self.game
        _, k_learn, k_cav, k_plearn = keys_today
        obs, cav_actions = _cav_choices(game, self.policy, pstate, k_cav, state)
        choices = np.asarray(game.joint_actions(state, jnp.asarray(cav_actions)))
        res = one_day(self.executor, game.sumo_scenario(int(state.day)), choices, self.env_seed, game.is_cav)
        self.bar.update(1, phase)
        times = np.asarray(res.travel_time, dtype=np.float64)
        keys = DayKeys(k_learn, k_act_tomorrow)
        _, state, cav_rewards_c, _, _ = game.step_with_times(keys, state, jnp.asarray(cav_actions),
                                                             jnp.asarray(times, jnp.float32))
        rewards_c = np.asarray(cav_rewards_c)  # [C]
        if phase == PHASE_TRAIN and game.n_cavs:
            pstate = self.policy.learn(k_plearn, pstate, obs, cav_actions, rewards_c)
        if self.sink is not None:
            self.sink(self._record(day, phase, choices, res, obs, rewards_c, times))
        return pstate, state

    def _record(self, day: int, phase: str, choices: np.ndarray, res: Any, obs: np.ndarray,
                rewards_c: np.ndarray, times: np.ndarray) -> DayRecord:
        """The day's record: CAVs' observations and rewards on their rows, humans' minus their time."""
        game = self.game
        obs_all = np.full((game.n_agents, game.obs_size), np.nan, dtype=np.float32)
        obs_all[game.cav_index] = obs
        paid = np.zeros(game.n_agents, dtype=rewards_c.dtype)
        paid[game.cav_index] = rewards_c
        rewards = np.where(game.is_cav, paid, -times)
        if game.day_demand is not None:  # stayed home (day_participation): no trip, no reward
            rewards = np.where(choices == ABSENT, np.nan, rewards)
        return DayRecord(day, phase, choices, game.is_cav, res, rewards, obs_all, self.sumo)


def _cav_choices(game: RoutingEnv, policy: CavPolicy, pstate: Any, key: jax.Array,
                 state: EnvState) -> tuple[np.ndarray, np.ndarray]:
    """(obs [C, D], actions [C]) of the CAVs in departure order; a policy that ignores observations
    acts once for every CAV with `key` (`act_at_once`)."""
    def fn(k: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
        return policy.act(k, pstate, obs, idx)

    rollout = act_by_levels if policy.uses_observation else act_at_once
    obs, actions = rollout(game, key, state, fn)
    return np.asarray(obs), np.asarray(actions, dtype=np.int32)


def train_humans(scenario: Scenario, hp: HumanParams, days: int, *, env_seed: int, executor: DayExecutor,
                 bar: Progress | None = None, bar_label: str = PHASE_HUMAN,
                 sink: Callable[[DayRecord], None] | None = None, sumo: bool = True,
                 first_day: int = 1, humans: HumanState | None = None) -> HumanState:
    """The human learning phase: days `first_day`..`days` of humans only, every one a learning day,
    run on `executor` (each ticks `bar` with `bar_label`); returns the trained knowledge.
    `humans`: the knowledge before `first_day` (default: day 1's, free-flow)."""
    root = jax.random.PRNGKey(env_seed)
    fft = jnp.asarray(scenario.fft, dtype=jnp.float32)
    if humans is None:
        humans = _first_humans(scenario, hp, root)
    no_cav = np.zeros(scenario.n_agents, dtype=bool)
    for day in range(first_day, days + 1):
        k_act, k_learn = jax.random.split(jax.random.fold_in(root, day))
        choices = np.asarray(act_jit(k_act, humans, hp, fft))
        res = one_day(executor, scenario, choices, env_seed)  # no CAV mask: a humans-only day
        if bar is not None:
            bar.update(1, bar_label)
        times = jnp.asarray(res.travel_time, dtype=jnp.float32)
        humans = end_day_jit(k_learn, humans, jnp.asarray(choices), times, hp, no_cav, learn_today=True)
        if sink is not None:
            sink(DayRecord(day, PHASE_HUMAN, choices, no_cav, res, -np.asarray(res.travel_time), None, sumo))
    return humans


def train_humans_on_model(scenario: Scenario, hp: HumanParams, days: int, *, env_seed: int,
                          travel_times: Callable[[jnp.ndarray], jnp.ndarray]
                          ) -> tuple[HumanState, np.ndarray]:
    """Human days 1..`days` on a travel-time model (choices [N] -> minutes [N], e.g. the calibrated
    surrogate) in one jitted scan: the same day keys and day rule as `train_humans`, so its SUMO
    days can continue from the returned knowledge. Returns (knowledge, each day's mean time [days])."""
    root = jax.random.PRNGKey(env_seed)
    fft = jnp.asarray(scenario.fft, dtype=jnp.float32)
    no_cav = np.zeros(scenario.n_agents, dtype=bool)

    def day(humans: HumanState, d: jnp.ndarray) -> tuple[HumanState, jnp.ndarray]:
        k_act, k_learn = jax.random.split(jax.random.fold_in(root, d))
        choices = act(k_act, humans, hp, fft)
        times = travel_times(choices)
        return end_day(k_learn, humans, choices, times, hp, no_cav, learn_today=True), times.mean()

    scan = jax.jit(lambda h: jax.lax.scan(day, h, jnp.arange(1, days + 1)))
    humans, means = scan(_first_humans(scenario, hp, root))
    return humans, np.asarray(means)


def _first_humans(scenario: Scenario, hp: HumanParams, root: jax.Array) -> HumanState:
    return init_humans_jit(jax.random.fold_in(root, 0x1), jnp.asarray(scenario.fft, dtype=jnp.float32),
                           jnp.asarray(scenario.route_valid), hp)
