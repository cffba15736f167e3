"""One learner iteration of a seed group: vmapped seeds against seeds mapped (`lax.map`) in the
program, per seed and environment, against one seed alone (hybrid.seed_axis, training/hybrid/fns.py).

The surrogate is the BPR stand-in (benchmarks/standin.py): the learner's cost, not the env's, is
what differs. Each program is compiled first (not timed) and run twice; the faster run counts.

    python benchmarks/seed_axis.py --networks-dir ../shared/networks
    python benchmarks/seed_axis.py --alg qmix --net provins --envs 16 --seeds 2 --networks-dir DIR

Columns:
  axis            one seed alone, the seeds vmapped, or mapped
  s / iteration   wall seconds of one iteration of the whole group
  per seed-env    that, over seeds x envs
  x alone         per seed-env against one seed alone (1.0: the group costs its seeds' sum)
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parent))
from standin import bpr_travel_time_fn

from urb_jax.algorithms.registry import algorithm, load_algo_config
from urb_jax.city.scenario import load_scenario
from urb_jax.game.env import RoutingEnv
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.rewards import behaviour_coefficients
from urb_jax.training.hybrid.fns import seeds_map
from urb_jax.training.hybrid.memory import tree_size


def seconds(over, learner, seeds: int) -> float:
    """The faster of two runs of one compiled iteration of `seeds` seeds."""
    runner = jax.jit(jax.vmap(learner.init))(jax.random.split(jax.random.PRNGKey(0), seeds))
    keys = jax.random.split(jax.random.PRNGKey(1), seeds)
    step = jax.jit(over(learner.iteration)).lower(runner, keys).compile()
    best = float("inf")
    for _ in range(2):
        t0 = time.perf_counter()
        jax.block_until_ready(step(runner, keys))
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--alg", default="qmix")
    parser.add_argument("--alg-conf", default="config1")
    parser.add_argument("--net", default="saint_arnoult")
    parser.add_argument("--ratio", type=float, default=0.4, help="share of CAVs (default 0.4)")
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--networks-dir", default=None)
    args = parser.parse_args()
    scn = load_scenario(args.net, networks_dir=args.networks_dir)
    is_cav = draw_cavs(42, scn.n_agents, args.ratio, agent_id=scn.agent_id)
    env = RoutingEnv(scn, is_cav, bpr_travel_time_fn(scn),
                     reward_coefficients=behaviour_coefficients("cooperative"))
    config = dataclasses.replace(load_algo_config(args.alg, args.alg_conf), num_envs=args.envs)
    learner = algorithm(args.alg).make_learner(config, env)
    params = tree_size(jax.eval_shape(learner.init, jax.random.PRNGKey(0)).params)
    print(f"{args.alg} {args.alg_conf} on {args.net}: {env.n_cavs} CAVs, {params / 1e6:.1f} M parameters, "
          f"{args.envs} envs, {jax.devices()[0].platform}, load average {os.getloadavg()[0]:.1f}")
    alone = seconds(jax.vmap, learner, 1) / args.envs
    print("| axis | seeds | s / iteration | per seed-env s | x alone |")
    print("|---|---|---|---|---|")
    print(f"| alone | 1 | {alone * args.envs:.2f} | {alone:.3f} | 1.00 |")
    for name, over in (("vmap", jax.vmap), ("map", seeds_map)):
        t = seconds(over, learner, args.seeds)
        per = t / (args.seeds * args.envs)
        print(f"| {name} | {args.seeds} | {t:.2f} | {per:.3f} | {per / alone:.2f} |", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
