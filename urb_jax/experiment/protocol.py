"""The URB experiment over authoritative days (URB_REFERENCE §5): human learning for H days ->
mutation -> CAV training days -> test days (CAV policies frozen).

Days are simulated one at a time by an injected `day_fn(scenario, choices, *, seed, is_cav)`
returning a `DayResult` (SUMO via `sumo_bridge.run_day` by default; tests inject a fake, the
hybrid trainer its own executor), because day t+1's human choices depend on day t's times.
Humans are vectorised (`urb_jax.humans`, jitted once); CAV policies follow the small
`CavPolicy` protocol (see `urb_jax.baselines`). Every day is handed to `sink` (the results
writer) as a `DayRecord`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.progress import Progress
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.humans import HumanParams, HumanState, act, init_humans, learn
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.observations import ObservationSpec, dependency_depth, make_observation_spec, observe
from urb_jax.game.rewards import cav_rewards
from urb_jax.results.records import DayRecord

PHASE_HUMAN, PHASE_TRAIN, PHASE_TEST = "human", "train", "test"

_act = jax.jit(act, static_argnames=("params",))
_learn = jax.jit(learn, static_argnames=("params",))
_init = jax.jit(init_humans, static_argnames=("params",))


class DayFn(Protocol):
    def __call__(self, scenario: Scenario, choices: np.ndarray, *, seed: int,
                 is_cav: np.ndarray | None = None) -> Any: ...


class CavPolicy(Protocol):
    """A CAV decision rule over the CAV axis [C] (CAVs in departure order)."""

    name: str
    uses_observation: bool

    def init(self, key: jax.Array, ctx: CavContext) -> Any: ...

    def act(self, key: jax.Array, state: Any, obs: np.ndarray) -> np.ndarray: ...

    def learn(self, key: jax.Array, state: Any, obs: np.ndarray, actions: np.ndarray,
              rewards: np.ndarray) -> Any: ...


@dataclass(frozen=True)
class CavContext:
    """What a policy may know when CAVs appear."""

    scenario: Scenario
    cav_index: np.ndarray  # [C] agent positions
    fft: np.ndarray  # [C, K] minutes
    route_valid: np.ndarray  # [C, K]
    humans: HumanState  # trained human knowledge of every agent, [N] rows
    human_params: HumanParams


@dataclass
class ExperimentOutcome:
    is_cav: np.ndarray
    humans: HumanState
    policy_state: Any
    days: int
    human_days: int
    training_days: int
    test_days: int


def _sumo_day_fn() -> DayFn:
    from urb_jax.sumo_bridge import run_day

    return run_day


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
    day_fn = day_fn or _sumo_day_fn()
    n, k = scenario.n_agents, scenario.k
    T = task.training_eps if training_days is None else int(training_days)
    H, E = task.human_learning_episodes, task.test_eps
    hp = task.human_params()
    coeffs = task.reward_coefficients
    root = jax.random.PRNGKey(env_seed)
    fft = jnp.asarray(scenario.fft, dtype=jnp.float32)
    valid = np.asarray(scenario.route_valid)
    bar = Progress(H + T + E, progress)

    def simulate(day: int, phase: str, choices: np.ndarray, is_cav: np.ndarray) -> Any:
        res = day_fn(scenario, choices, seed=env_seed, is_cav=is_cav)
        bar.update(1, phase)
        return res

    # Phase 1: human learning.
    humans = train_humans(scenario, hp, H, env_seed=env_seed, simulate=simulate, sink=sink, sumo=sumo)

    # Mutation.
    is_cav = draw_cavs(env_seed, n, task.ratio_machines, agent_id=scenario.agent_id)
    cav_index = np.flatnonzero(is_cav)
    spec = make_observation_spec(env.observations, scenario.agent_od, scenario.agent_depart, k)
    depth = max(dependency_depth(scenario.agent_od, scenario.agent_depart, is_cav, env.observations), 1)
    ctx = CavContext(scenario, cav_index, np.asarray(scenario.fft)[cav_index], valid[cav_index], humans, hp)
    pstate = policy.init(jax.random.fold_in(root, 0x2), ctx)
    learning_mask = jnp.asarray(~is_cav)
    yesterday_cav = np.argmin(np.where(valid, scenario.fft, np.inf), axis=1)[cav_index]

    # Phases 3-4: CAV training, then test with frozen policies.
    for day in range(H + 1, H + T + E + 1):
        phase = PHASE_TRAIN if day <= H + T else PHASE_TEST
        kd = jax.random.fold_in(root, day)
        k_act, k_learn, k_cav, k_plearn = jax.random.split(kd, 4)
        human_choices = np.asarray(_act(k_act, humans, hp, fft))
        cav_actions, obs = _cav_decisions(policy, pstate, k_cav, spec, human_choices, cav_index,
                                          yesterday_cav, depth)
        choices = human_choices.copy()
        choices[cav_index] = cav_actions
        res = simulate(day, phase, choices, is_cav)
        times = np.asarray(res.travel_time, dtype=np.float64)
        rewards_all = np.asarray(cav_rewards(jnp.asarray(times), jnp.asarray(is_cav), coeffs))
        if phase == PHASE_TRAIN and cav_index.size:
            pstate = policy.learn(k_plearn, pstate, obs, cav_actions, rewards_all[cav_index])
        if task.should_humans_adapt:
            humans = _learn(k_learn, humans, jnp.asarray(choices), jnp.asarray(times, jnp.float32), hp,
                            learning_mask)
        else:
            humans = humans._replace(last_action=jnp.asarray(choices, jnp.int32))
        yesterday_cav = cav_actions
        if sink is not None:
            rewards = np.where(is_cav, rewards_all, -times)
            obs_all = np.full((n, spec.size), np.nan, dtype=np.float32)
            obs_all[cav_index] = obs
            sink(DayRecord(day, phase, choices, is_cav, res, rewards, obs_all, sumo))
    bar.close()
    return ExperimentOutcome(is_cav, humans, pstate, H + T + E, H, T, E)


def train_humans(scenario: Scenario, hp: HumanParams, days: int, *, env_seed: int,
                 simulate: Callable[[int, str, np.ndarray, np.ndarray], Any],
                 sink: Callable[[DayRecord], None] | None = None, sumo: bool = True) -> HumanState:
    """The human learning phase: `days` days of humans only; returns the trained knowledge.
    `simulate(day, phase, choices, is_cav)` returns the day's DayResult."""
    root = jax.random.PRNGKey(env_seed)
    n = scenario.n_agents
    fft = jnp.asarray(scenario.fft, dtype=jnp.float32)
    humans = _init(jax.random.fold_in(root, 0x1), fft, jnp.asarray(scenario.route_valid), hp)
    no_cav = np.zeros(n, dtype=bool)
    for day in range(1, days + 1):
        k_act, k_learn = jax.random.split(jax.random.fold_in(root, day))
        choices = np.asarray(_act(k_act, humans, hp, fft))
        res = simulate(day, PHASE_HUMAN, choices, no_cav)
        times = jnp.asarray(res.travel_time, dtype=jnp.float32)
        humans = _learn(k_learn, humans, jnp.asarray(choices), times, hp)
        if sink is not None:
            sink(DayRecord(day, PHASE_HUMAN, choices, no_cav, res, -np.asarray(res.travel_time), None, sumo))
    return humans


def _cav_decisions(policy: CavPolicy, pstate: Any, key: jax.Array, spec: ObservationSpec,
                   human_choices: np.ndarray, cav_index: np.ndarray, yesterday: np.ndarray,
                   depth: int) -> tuple[np.ndarray, np.ndarray]:
    """CAV actions consistent with departure order, and the observations they acted on.

    A CAV sees today's choices of agents that departed earlier; iterating obs -> act `depth`
    times with one key reproduces the sequential order (urb_jax.observations). Policies that
    ignore observations need one round.
    """
    actions = np.asarray(yesterday, dtype=np.int32)
    rounds = depth if policy.uses_observation else 1
    for _ in range(rounds):
        joint = human_choices.copy()
        joint[cav_index] = actions
        obs = np.asarray(observe(spec, jnp.asarray(joint)))[cav_index]
        new = np.asarray(policy.act(key, pstate, obs), dtype=np.int32)
        if np.array_equal(new, actions) and policy.uses_observation:
            break
        actions = new
    joint = human_choices.copy()
    joint[cav_index] = actions
    obs = np.asarray(observe(spec, jnp.asarray(joint)))[cav_index]
    return actions, obs
