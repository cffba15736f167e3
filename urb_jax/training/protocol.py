"""The URB experiment over authoritative days (URB_REFERENCE §5): human learning for H days ->
mutation -> CAV training days -> test days (CAV policies frozen).

Days are simulated one at a time by an injected `day_fn(scenario, choices, *, seed, is_cav)`
returning a `DayResult` (SUMO via `sumo_bridge.run_day` by default; tests inject a fake, the
hybrid trainer its own executor), because day t+1's human choices depend on day t's times.
Humans follow the game's day rule (`urb_jax.game.humans`, jitted once); CAV policies follow the
`CavPolicy` protocol (`urb_jax.algorithms.baselines`) and choose in departure order
(`urb_jax.game.rollout`). Every day is handed to `sink` (the results writer) as a `DayRecord`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.baselines import CavPolicy
from urb_jax.city.scenario import Scenario
from urb_jax.core.progress import Progress
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.env import EnvState, RoutingEnv
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
from urb_jax.game.rewards import cav_rewards
from urb_jax.game.rollout import act_at_once, act_by_levels
from urb_jax.reporting.records import DayRecord
from urb_jax.sumo_bridge import run_day

PHASE_HUMAN, PHASE_TRAIN, PHASE_TEST = "human", "train", "test"


class DayFn(Protocol):
    def __call__(self, scenario: Scenario, choices: np.ndarray, *, seed: int,
                 is_cav: np.ndarray | None = None) -> Any: ...


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
    day_fn: DayFn | None = None,
    sink: Callable[[DayRecord], None] | None = None,
    training_days: int | None = None,
    progress: bool = False,
    sumo: bool = True,
) -> ExperimentOutcome:
    """Run the phases; return the final state. `training_days` defaults to task.training_eps."""
    day_fn = day_fn or run_day
    T = task.training_eps if training_days is None else int(training_days)
    H, E = task.human_learning_episodes, task.test_eps
    bar = Progress(H + T + E, progress)

    def simulate(day: int, phase: str, choices: np.ndarray, is_cav: np.ndarray) -> Any:
        res = day_fn(scenario, choices, seed=env_seed, is_cav=is_cav)
        bar.update(1, phase)
        return res

    # Phase 1: human learning; mutation.
    hp = task.human_params()
    humans = train_humans(scenario, hp, H, env_seed=env_seed, simulate=simulate, sink=sink, sumo=sumo)
    is_cav = draw_cavs(env_seed, scenario.n_agents, task.ratio_machines, agent_id=scenario.agent_id)
    game = RoutingEnv(scenario, is_cav, human_params=hp,
                      reward_coefficients=task.reward_coefficients, observation_type=env.observations,
                      humans_adapt=task.should_humans_adapt, human_init=humans)
    pstate = policy.init(jax.random.fold_in(jax.random.PRNGKey(env_seed), 0x2), game)
    # Phases 3-4: CAV training, then test with frozen policies.
    pstate, humans = _cav_days(game, policy, pstate, range(H + 1, H + T + E + 1), H + T, env_seed=env_seed,
                               simulate=simulate, sink=sink, sumo=sumo)
    bar.close()
    return ExperimentOutcome(is_cav, humans, pstate, H + T + E, H, T, E)


def _cav_days(game: RoutingEnv, policy: CavPolicy, pstate: Any, days: range, last_train_day: int, *,
              env_seed: int, simulate: Callable[[int, str, np.ndarray, np.ndarray], Any],
              sink: Callable[[DayRecord], None] | None, sumo: bool) -> tuple[Any, HumanState]:
    """The days after mutation: humans choose, CAVs choose in departure order, the day runs, the
    policy learns (training days), humans end the day; returns (policy state, humans).

    Keys per day: k_act, k_learn, k_cav, k_plearn = split(fold_in(PRNGKey(env_seed), day), 4).
    Humans learn only when the task lets them adapt (`game.humans_adapt`), with or without CAVs:
    unlike `RoutingEnv.humans_learn`, a CAV-free day here is still a post-mutation day.
    """
    scn, hp, is_cav, cav_index = game.scenario, game.human_params, game.is_cav, game.cav_index
    coefficients = game.reward_coefficients
    root = jax.random.PRNGKey(env_seed)
    fft = jnp.asarray(scn.fft, dtype=jnp.float32)
    humans = game.human_init
    assert humans is not None  # run_experiment builds the game with the trained humans
    # Before the first CAV day, as env.reset: yesterday's CAV routes AON, times free-flow.
    yesterday = jnp.asarray(aon_routes(scn.fft, scn.route_valid)[cav_index])
    yesterday_times = jnp.asarray(scn.fft_full.min(axis=1))
    for day in days:
        phase = PHASE_TRAIN if day <= last_train_day else PHASE_TEST
        k_act, k_learn, k_cav, k_plearn = jax.random.split(jax.random.fold_in(root, day), 4)
        state = EnvState(humans, act_jit(k_act, humans, hp, fft), yesterday, yesterday_times,
                         jnp.asarray(day - 1, jnp.int32))
        obs, cav_actions = _cav_choices(game, policy, pstate, k_cav, state)
        choices = np.asarray(game.joint_actions(state, jnp.asarray(cav_actions)))
        res = simulate(day, phase, choices, is_cav)
        times = np.asarray(res.travel_time, dtype=np.float64)
        rewards_all = np.asarray(cav_rewards(jnp.asarray(times), jnp.asarray(is_cav), coefficients))
        if phase == PHASE_TRAIN and cav_index.size:
            pstate = policy.learn(k_plearn, pstate, obs, cav_actions, rewards_all[cav_index])
        humans = end_day_jit(k_learn, humans, jnp.asarray(choices), jnp.asarray(times, jnp.float32), hp,
                             is_cav, learn_today=game.humans_adapt)
        yesterday, yesterday_times = jnp.asarray(cav_actions), jnp.asarray(times, jnp.float32)
        if sink is not None:
            obs_all = np.full((scn.n_agents, game.obs_size), np.nan, dtype=np.float32)
            obs_all[cav_index] = obs
            rewards = np.where(is_cav, rewards_all, -times)
            sink(DayRecord(day, phase, choices, is_cav, res, rewards, obs_all, sumo))
    return pstate, humans


def _cav_choices(game: RoutingEnv, policy: CavPolicy, pstate: Any, key: jax.Array,
                 state: EnvState) -> tuple[np.ndarray, np.ndarray]:
    """(obs [C, D], actions [C]) of the CAVs in departure order; a policy that ignores observations
    acts once for every CAV with `key` (`act_at_once`)."""
    def fn(k: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
        return policy.act(k, pstate, obs, idx)

    rollout = act_by_levels if policy.uses_observation else act_at_once
    obs, actions = rollout(game, key, state, fn)
    return np.asarray(obs), np.asarray(actions, dtype=np.int32)


def train_humans(scenario: Scenario, hp: HumanParams, days: int, *, env_seed: int,
                 simulate: Callable[[int, str, np.ndarray, np.ndarray], Any],
                 sink: Callable[[DayRecord], None] | None = None, sumo: bool = True,
                 first_day: int = 1, humans: HumanState | None = None) -> HumanState:
    """The human learning phase: days `first_day`..`days` of humans only, every one a learning day;
    returns the trained knowledge. `simulate(day, phase, choices, is_cav)` returns the day's
    DayResult. `humans`: the knowledge before `first_day` (default: day 1's, free-flow)."""
    root = jax.random.PRNGKey(env_seed)
    fft = jnp.asarray(scenario.fft, dtype=jnp.float32)
    if humans is None:
        humans = _first_humans(scenario, hp, root)
    no_cav = np.zeros(scenario.n_agents, dtype=bool)
    for day in range(first_day, days + 1):
        k_act, k_learn = jax.random.split(jax.random.fold_in(root, day))
        choices = np.asarray(act_jit(k_act, humans, hp, fft))
        res = simulate(day, PHASE_HUMAN, choices, no_cav)
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
