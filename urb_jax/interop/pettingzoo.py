"""PettingZoo environments over authoritative (SUMO) days, as RouteRL offers: AEC and Parallel.

One episode = one day. Agents are the CAVs (names `str(agent_id)`), acting once per day; humans
are not agents — their choices for the day are drawn at `reset` from their learned model. A CAV
observes its own start time and, per route, how many agents of its observation group (its OD)
with a strictly earlier departure took that route today (humans' today choices and earlier CAVs'
actions). After the last CAV acts, the day runs on the env's `executor` (SUMO in this process by
default) and ends with the game's one day transition (`RoutingEnv.step_with_times`): every CAV
gets its behaviour reward (minutes), all CAVs terminate, humans learn if the task lets them adapt
and draw tomorrow's routes. The human learning phase runs in the constructor unless `humans` is
given.

`UrbAECEnv` steps one CAV at a time in departure order (RouteRL's order). `UrbParallelEnv` steps
one dependency level at a time (`urb_jax.game.rollout.cav_levels`): the CAVs of a level observe
only lower levels' actions, so acting level by level gives every CAV exactly its AEC observation,
and the same policy gives the same day in both envs (docs/pettingzoo.md).

Observations are kept current incrementally (`IncrementalObservations`): a CAV's action updates
its group's later rows, O(N) at most, instead of recomputing all N observations after each step.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar, cast

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils import AgentSelector

from urb_jax.city.scenario import Scenario
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.env import DayKeys, EnvState, RoutingEnv
from urb_jax.game.humans import HumanState, act_jit
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.observations import IncrementalObservations
from urb_jax.game.rollout import cav_levels
from urb_jax.sumo_bridge import DayExecutor, InProcessExecutor, one_day
from urb_jax.training.protocol import train_humans


@jax.jit
def _day_keys(key: jax.Array, day: int) -> tuple[jax.Array, jax.Array]:
    """(humans' draw key, humans' day-end key) of a day: one dispatch instead of three."""
    day_key = jax.random.fold_in(key, day)
    return jax.random.fold_in(day_key, 1), jax.random.fold_in(day_key, 2)


class _SumoDays:
    """What both envs share: the humans, the CAVs, and one day's start, actions, observations and
    end. Subclasses call `_setup` from their constructor."""

    def _setup(self, scenario: Scenario, task: TaskConfig | None, env_config: EnvConfig | None,
               env_seed: int, executor: DayExecutor | None, humans: HumanState | None,
               is_cav: np.ndarray | None) -> None:
        self.scenario = scenario
        self.task = task or TaskConfig()
        if self.task.surrogate_reward_keys:
            raise ConfigError("the PettingZoo envs run SUMO days without a surrogate, so they pay URB's "
                              "group rewards only: task key reward_credit 'marginal' and marginal_cost_beta "
                              "need the surrogate's derivative. Fix: use them with `urb-jax train` (hybrid "
                              "or surrogate mode), or set reward_credit 'group' and marginal_cost_beta 0.")
        if self.task.varies_daily:
            raise ConfigError(f"task key 'day_participation' = {self.task.day_participation}: the PettingZoo "
                              "envs run URB's fixed demand (every driver every day). Fix: set "
                              "day_participation to 1, or train with `urb-jax train`.")
        if self.task.jitters_departures:
            raise ConfigError(f"task key 'day_departure_jitter_s' = {self.task.day_departure_jitter_s}: the "
                              "PettingZoo envs run URB's scheduled departures. Fix: set "
                              "day_departure_jitter_s to 0, or train with `urb-jax train`.")
        if self.task.fleets:
            raise ConfigError("task key 'fleets': the PettingZoo envs have one CAV fleet, paid the task's "
                              "av_behavior. Fix: train fleets with `urb-jax train`, or use a task without "
                              "'fleets'.")
        self.env_config = env_config or EnvConfig()
        self.env_seed = env_seed
        self._owns_executor = executor is None
        self.executor: DayExecutor = InProcessExecutor() if executor is None else executor
        self.hp = self.task.human_params()
        n = scenario.n_agents
        self.fft = jnp.asarray(scenario.fft, dtype=jnp.float32)
        if humans is None:
            humans = train_humans(scenario, self.hp, self.task.human_learning_episodes, env_seed=env_seed,
                                  executor=self.executor)
        self.humans = humans
        self.is_cav = (draw_cavs(env_seed, n, self.task.ratio_machines, agent_id=scenario.agent_id)
                       if is_cav is None else np.asarray(is_cav, dtype=bool))
        self.game = RoutingEnv(scenario, self.is_cav, human_params=self.hp,
                               reward_coefficients=self.task.reward_coefficients,
                               observation_type=self.env_config.observations,
                               humans_adapt=self.task.should_humans_adapt, human_init=humans)
        self.cav_index = self.game.cav_index  # departure order (the Scenario is sorted)
        self.possible_agents = [str(int(scenario.agent_id[i])) for i in self.cav_index]
        self._pos = dict(zip(self.possible_agents, range(len(self.possible_agents)), strict=True))
        self.spec = self.game.obs_spec
        # (day, its human draws, its end key) that the previous day's end made
        self._drawn: tuple[int, jax.Array, jax.Array] | None = None
        self._observations = IncrementalObservations(self.spec)
        high = np.finfo(np.float32).max
        self._obs_space = gymnasium.spaces.Box(0.0, high, shape=(self.spec.size,), dtype=np.float32)
        self._act_space: gymnasium.spaces.Discrete = gymnasium.spaces.Discrete(scenario.k)
        self.day = self.task.human_learning_episodes
        self._key = jax.random.PRNGKey(env_seed)
        self.last_result: Any = None

    def _close_days(self) -> None:
        """Close the SUMO executor this env made (one given to it stays open: its owner closes it)."""
        if self._owns_executor:
            self.executor.close()

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self._obs_space

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        return self._act_space

    @property
    def joint(self) -> np.ndarray:
        """[N] today's choices so far (read-only): humans' draws; each CAV's action once it acted,
        the humans' model's draw for it before."""
        view = self._observations.actions.view()
        view.flags.writeable = False
        return view

    def _start_day(self, seed: int | None) -> None:
        """Today's human draws: those yesterday's end drew for today under the same key, else drawn now."""
        if seed is not None:
            self._key, self._drawn = jax.random.PRNGKey(seed), None
        self.day += 1
        if self._drawn is not None and self._drawn[0] == self.day:
            _, drawn, self._k_end = self._drawn
        else:
            k_act, self._k_end = _day_keys(self._key, self.day)
            drawn = act_jit(k_act, self.humans, self.hp, self.fft)
        self.human_choices = np.asarray(drawn)
        self._observations.reset(self.human_choices)

    def _rows(self, agents: list[str]) -> np.ndarray:
        """[len(agents)] rows of the agent axis."""
        return self.cav_index[[self._pos[a] for a in agents]]

    def _act(self, agents: list[str], actions: list[Any]) -> None:
        self._observations.set(self._rows(agents), np.asarray([int(a) for a in actions], dtype=np.int64))

    def _observe(self, agents: list[str]) -> dict[str, np.ndarray]:
        obs = self._observations.observe(self._rows(agents))  # [len(agents), D]
        return dict(zip(agents, obs, strict=True))

    def _end_day(self) -> tuple[dict[str, float], dict[str, dict]]:
        """Simulate today's joint choices; (reward, info) per CAV; the game's day transition (called
        eagerly: jitted, XLA may sum the group means in another order, a last-bit change)."""
        joint = self._observations.actions.copy()
        res = one_day(self.executor, self.scenario, joint.copy(), self.env_seed, self.is_cav)
        self.last_result = res
        times = np.asarray(res.travel_time, dtype=np.float32)
        # yesterday's CAV routes and times are not read by the day's end
        today = EnvState(self.humans, jnp.asarray(self.human_choices, jnp.int32), jnp.zeros(0, jnp.int32),
                         jnp.zeros(0, jnp.float32), jnp.asarray(self.day - 1, jnp.int32))
        k_act_next, k_end_next = _day_keys(self._key, self.day + 1)
        keys = DayKeys(self._k_end, k_act_next)
        cav_actions = jnp.asarray(joint[self.cav_index])
        _, tomorrow, rewards, _, _ = self.game.step_with_times(keys, today, cav_actions, jnp.asarray(times))
        self.humans, self._drawn = tomorrow.humans, (self.day + 1, tomorrow.human_actions, k_end_next)
        rewards_c, times_c = np.asarray(rewards).tolist(), times[self.cav_index].tolist()
        return (dict(zip(self.possible_agents, rewards_c, strict=True)),
                {a: {"travel_time": t, "day": self.day} for a, t in zip(self.possible_agents, times_c,
                                                                         strict=True)})


class UrbAECEnv(_SumoDays, AECEnv):
    """CAVs act one at a time in departure order; `observe(agent)` is O(K), `step` O(N) at most.

    Not parallelizable through PettingZoo's `aec_to_parallel` (every CAV would act on its
    day-start observation); use `UrbParallelEnv`."""

    metadata: ClassVar[dict] = {"name": "urb_jax_v0", "render_modes": [], "is_parallelizable": False}

    def __init__(self, scenario: Scenario, task: TaskConfig | None = None,
                 env_config: EnvConfig | None = None, *, env_seed: int = 42,
                 executor: DayExecutor | None = None, humans: HumanState | None = None,
                 is_cav: np.ndarray | None = None) -> None:
        super().__init__()
        self._setup(scenario, task, env_config, env_seed, executor, humans, is_cav)

    def reset(self, seed: int | None = None, options: dict | None = None) -> None:
        self._start_day(seed)
        self.agents = list(self.possible_agents)
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos: dict[str, dict[str, Any]] = {a: {} for a in self.agents}
        self._agent_selector = AgentSelector(self.agents)
        self.agent_selection = self._agent_selector.reset() if self.agents else None
        self._rewards_shown = False

    def observe(self, agent: str) -> np.ndarray:
        return self._observations.observe_one(int(self.cav_index[self._pos[agent]]))

    def step(self, action: int | None) -> None:
        agent = cast(str, self.agent_selection)  # None only once every agent has left
        if self.terminations[agent] or self.truncations[agent]:
            self._dead_step(action)
            return
        self._cumulative_rewards[agent] = 0.0
        self._act([agent], [action])
        day_over = self._agent_selector.is_last()
        self.agent_selection = self._agent_selector.next()
        if day_over:  # rewards stay 0 until the last CAV acted: nothing to clear or accumulate before
            rewards, infos = self._end_day()
            self.rewards.update(rewards)
            self.infos.update(infos)
            self.terminations = dict.fromkeys(self.agents, True)
            self._accumulate_rewards()
            self._rewards_shown = True

    def _dead_step(self, action: int | None) -> None:
        """PettingZoo's `_was_dead_step` for this env's one way to die, in O(1) rather than O(C):
        every CAV terminates at once and leaves in turn order, so the next to step is the first
        left; the first dead step clears `rewards` (cumulative rewards stay until each leaves)."""
        if action is not None:
            raise ValueError("when an agent is dead, the only valid action is None")
        agent = cast(str, self.agent_selection)
        for table in (self.terminations, self.truncations, self.rewards, self._cumulative_rewards,
                      self.infos):
            del table[agent]
        self.agents.remove(agent)  # the first of the list
        self.agent_selection = self.agents[0] if self.agents else None
        if self._rewards_shown:
            self._clear_rewards()
            self._rewards_shown = False

    def render(self) -> None:
        return None

    def close(self) -> None:
        self._close_days()


class UrbParallelEnv(_SumoDays, ParallelEnv):
    """CAVs act one dependency level per step; the day has `num_levels` steps.

    Every CAV is an agent from `reset` until the day ends (its reward comes with the last step).
    `infos[agent]["acting"]` says who acts at the next step: those CAVs' observations are exactly
    their AEC observations (every earlier-departing CAV of their group has acted). `step` reads
    the acting CAVs' actions and ignores the others' (which may be left out)."""

    metadata: ClassVar[dict] = {"name": "urb_jax_parallel_v0", "render_modes": []}

    def __init__(self, scenario: Scenario, task: TaskConfig | None = None,
                 env_config: EnvConfig | None = None, *, env_seed: int = 42,
                 executor: DayExecutor | None = None, humans: HumanState | None = None,
                 is_cav: np.ndarray | None = None) -> None:
        self._setup(scenario, task, env_config, env_seed, executor, humans, is_cav)
        levels = cav_levels(self.spec, self.cav_index)  # CAV-axis indices per level
        self.levels: tuple[list[str], ...] = tuple([self.possible_agents[c] for c in lv] for lv in levels)
        self.num_levels = len(self.levels)
        self.agents: list[str] = []
        self.level = 0

    def reset(self, seed: int | None = None,
              options: dict | None = None) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        self._start_day(seed)
        self.agents = list(self.possible_agents)
        self.level = 0
        return self._observe(self.agents), self._acting_infos()

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            return {}, {}, {}, {}, {}
        acting = self.levels[self.level]
        missing = [a for a in acting if a not in actions]
        if missing:
            more = " ..." if len(missing) > 5 else ""
            raise ValueError(f"step(actions) lacks the actions of CAVs acting at level {self.level}: "
                             f"{missing[:5]}{more}. Fix: give an action to every agent whose "
                             "infos[agent]['acting'] is True.")
        self._act(acting, [actions[a] for a in acting])
        self.level += 1
        agents = self.agents
        if self.level < self.num_levels:
            return (self._observe(agents), dict.fromkeys(agents, 0.0), dict.fromkeys(agents, False),
                    dict.fromkeys(agents, False), self._acting_infos())
        obs = self._observe(agents)
        rewards, infos = self._end_day()
        for info in infos.values():
            info["acting"] = False
        self.agents = []
        return obs, rewards, dict.fromkeys(agents, True), dict.fromkeys(agents, False), infos

    def _acting_infos(self) -> dict[str, dict]:
        acting = set(self.levels[self.level]) if self.level < self.num_levels else set()
        return {a: {"acting": a in acting} for a in self.agents}

    def render(self) -> None:
        return None

    def close(self) -> None:
        self._close_days()
