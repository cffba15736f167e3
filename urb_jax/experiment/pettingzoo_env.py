"""A PettingZoo AEC environment over authoritative (SUMO) days, as RouteRL offers.

One episode = one day. Agents are the CAVs (names `str(agent_id)`), acting once per day in
departure order; humans are not agents — their choices for the day are drawn at `reset` from
their learned model. A CAV observes its own start time and, per route, how many agents of its
OD with a strictly earlier departure took that route today (humans' today choices and earlier
CAVs' actions). After the last CAV acts, the day is simulated by `day_fn` (SUMO by default),
every CAV gets its behaviour reward (minutes), all CAVs terminate, and humans learn if the task
lets them adapt. The human learning phase runs in the constructor unless `humans` is given.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from pettingzoo import AECEnv
from pettingzoo.utils import AgentSelector

from urb_jax.city.scenario import Scenario
from urb_jax.experiment.protocol import DayFn, train_humans
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.game.humans import HumanState, act_jit, end_day_jit
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.observations import make_observation_spec, observe
from urb_jax.game.rewards import cav_rewards
from urb_jax.sumo_bridge import run_day


class UrbAECEnv(AECEnv):
    metadata: ClassVar[dict] = {"name": "urb_jax_v0", "render_modes": [], "is_parallelizable": False}

    def __init__(self, scenario: Scenario, task: TaskConfig | None = None,
                 env_config: EnvConfig | None = None, *, env_seed: int = 42, day_fn: DayFn | None = None,
                 humans: HumanState | None = None,
                 is_cav: np.ndarray | None = None) -> None:
        super().__init__()
        self.scenario = scenario
        self.task = task or TaskConfig()
        self.env_config = env_config or EnvConfig()
        self.env_seed = env_seed
        self.day_fn = day_fn or run_day
        self.hp = self.task.human_params()
        self.coefficients = self.task.reward_coefficients
        n = scenario.n_agents
        self.fft = jnp.asarray(scenario.fft, dtype=jnp.float32)
        if humans is None:
            def simulate(day: int, phase: str, choices: np.ndarray, mask: np.ndarray) -> Any:
                return self.day_fn(scenario, choices, seed=env_seed, is_cav=mask)

            humans = train_humans(scenario, self.hp, self.task.human_learning_episodes, env_seed=env_seed,
                                  simulate=simulate)
        self.humans = humans
        self.is_cav = (draw_cavs(env_seed, n, self.task.ratio_machines, agent_id=scenario.agent_id)
                       if is_cav is None else np.asarray(is_cav, dtype=bool))
        self.cav_index = np.flatnonzero(self.is_cav)  # departure order (the Scenario is sorted)
        self.possible_agents = [str(int(scenario.agent_id[i])) for i in self.cav_index]
        self._pos = dict(zip(self.possible_agents, range(len(self.possible_agents)), strict=True))
        self.spec = make_observation_spec(self.env_config.observations, scenario.agent_od,
                                          scenario.agent_depart, scenario.k)
        high = np.finfo(np.float32).max
        self._obs_space = gymnasium.spaces.Box(0.0, high, shape=(self.spec.size,), dtype=np.float32)
        self._act_space = gymnasium.spaces.Discrete(scenario.k)
        self.day = self.task.human_learning_episodes
        self._key = jax.random.PRNGKey(env_seed)
        self.last_result: Any = None

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self._obs_space

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        return self._act_space

    def reset(self, seed: int | None = None, options: dict | None = None) -> None:
        if seed is not None:
            self._key = jax.random.PRNGKey(seed)
        self.day += 1
        self._day_key = jax.random.fold_in(self._key, self.day)
        self.human_choices = np.asarray(act_jit(jax.random.fold_in(self._day_key, 1), self.humans, self.hp,
                                                self.fft))
        self.joint = self.human_choices.copy()
        self.agents = list(self.possible_agents)
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos = {a: {} for a in self.agents}
        self._agent_selector = AgentSelector(self.agents)
        self.agent_selection = self._agent_selector.reset() if self.agents else None
        self._obs_cache: np.ndarray | None = None

    def observe(self, agent: str) -> np.ndarray:
        if self._obs_cache is None:
            self._obs_cache = np.asarray(observe(self.spec, jnp.asarray(self.joint)), dtype=np.float32)
        return self._obs_cache[self.cav_index[self._pos[agent]]].copy()

    def step(self, action: int | None) -> None:
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            self._was_dead_step(action)
            return
        self._cumulative_rewards[agent] = 0.0
        self.joint[self.cav_index[self._pos[agent]]] = int(action)
        self._obs_cache = None
        if self._agent_selector.is_last():
            self._end_day()
        else:
            self._clear_rewards()
        self.agent_selection = self._agent_selector.next()
        self._accumulate_rewards()

    def _end_day(self) -> None:
        res = self.day_fn(self.scenario, self.joint.copy(), seed=self.env_seed, is_cav=self.is_cav)
        self.last_result = res
        times = np.asarray(res.travel_time, dtype=np.float32)
        rewards = np.asarray(cav_rewards(jnp.asarray(times), jnp.asarray(self.is_cav), self.coefficients))
        for a in self.agents:
            i = self.cav_index[self._pos[a]]
            self.rewards[a] = float(rewards[i])
            self.terminations[a] = True
            self.infos[a] = {"travel_time": float(times[i]), "day": self.day}
        # As the SUMO protocol: humans learn only when the task lets them adapt.
        self.humans = end_day_jit(jax.random.fold_in(self._day_key, 2), self.humans, jnp.asarray(self.joint),
                                  jnp.asarray(times), self.hp, self.is_cav,
                                  learn_today=self.task.should_humans_adapt)

    def render(self) -> None:
        return None

    def close(self) -> None:
        return None
