"""Bring your own algorithm: independent bandit learners on urb-jax's PettingZoo Parallel env.

Every CAV keeps a running mean reward per route and picks the best with probability 1 - epsilon
(a bandit: it ignores its observation; a real learner conditions on it). The Parallel env steps
one dependency level of CAVs at a time; only the CAVs with `infos[agent]["acting"]` act at a step
(their observation is exactly what the AEC env would show them), and every CAV's reward arrives
with the day's last step (docs/pettingzoo.md).

    python examples/pettingzoo_parallel.py [--network urb_grid] [--days 5] [--human-days 3]

Every day is a SUMO day; the human learning phase (`--human-days`) runs in the constructor.
"""

from __future__ import annotations

import argparse

import numpy as np

from urb_jax.city.scenario import load_scenario
from urb_jax.game.config import TaskConfig
from urb_jax.interop.pettingzoo import UrbParallelEnv


class BanditCav:
    """One CAV's epsilon-greedy running mean reward per route (untried routes first)."""

    def __init__(self, n_routes: int, rng: np.random.Generator, epsilon: float = 0.1) -> None:
        self.value = np.zeros(n_routes)
        self.count = np.zeros(n_routes)
        self.rng, self.epsilon = rng, epsilon

    def act(self, obs: np.ndarray) -> int:
        if self.rng.random() < self.epsilon:
            return int(self.rng.integers(len(self.value)))
        return int(np.argmax(np.where(self.count == 0, np.inf, self.value)))

    def learn(self, obs: np.ndarray, action: int, reward: float) -> None:
        self.count[action] += 1
        self.value[action] += (reward - self.value[action]) / self.count[action]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--network", default="urb_grid")
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--days", type=int, default=5)
    ap.add_argument("--human-days", type=int, default=3)
    args = ap.parse_args()
    scenario = load_scenario(args.network, networks_dir=args.networks_dir)
    task = TaskConfig(ratio_machines=0.1, human_learning_episodes=args.human_days)
    env = UrbParallelEnv(scenario, task, env_seed=42)
    rng = np.random.default_rng(0)
    cavs = {a: BanditCav(scenario.k, rng) for a in env.possible_agents}
    print(f"{args.network}: {len(env.possible_agents)} CAVs acting in {env.num_levels} levels a day")
    for _ in range(args.days):
        obs, infos = env.reset()
        chosen = {}  # agent -> (observation it acted on, action)
        while env.agents:
            actions = {a: cavs[a].act(obs[a]) for a in env.agents if infos[a]["acting"]}
            chosen.update({a: (obs[a], act) for a, act in actions.items()})
            obs, rewards, _terms, _truncs, infos = env.step(actions)
        for a, (o, act) in chosen.items():
            cavs[a].learn(o, act, rewards[a])
        t_cav = np.mean([infos[a]["travel_time"] for a in env.possible_agents])
        times = np.asarray(env.last_result.travel_time)
        print(f"day {env.day}: t_CAV {t_cav:.3f} min, t_HDV {times[~env.is_cav].mean():.3f} min")


if __name__ == "__main__":
    main()
