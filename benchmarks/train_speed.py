"""Training days per second of every algorithm (URB config1 and the urb-jax fast configs), B = 1 and
B = 64 environments, 40% CAVs, on the calibrated surrogate (`--standin`: the BPR stand-in).

A "training day" is one simulated day of one environment including the updates that go with it
(collection + learning, whole jitted train function; compile time reported separately).

    python benchmarks/train_speed.py                       # saint_arnoult and ingolstadt_custom
    python benchmarks/train_speed.py --networks saint_arnoult --config config1 fast
    python benchmarks/train_speed.py --networks saint_arnoult --algs iql ippo --envs 64

Configs and B are measured side by side in one run (rows of one run compare; the machine's load
average is printed before and after).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_surrogate import surrogate_travel_fn
from standin import bpr_travel_time_fn

from urb_jax.algorithms import ippo, ippo_star, iql, iql_star, mappo, qmix, vdn
from urb_jax.algorithms.ippo_star import days_per_update
from urb_jax.algorithms.registry import load_algo_config
from urb_jax.city.scenario import load_scenario
from urb_jax.game.env import RoutingEnv
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.rewards import behaviour_coefficients
from urb_jax.game.rollout import dependency_levels

MODULES = {"iql": iql, "ippo": ippo, "mappo": mappo, "qmix": qmix, "vdn": vdn, "iql_star": iql_star,
           "ippo_star": ippo_star}
BEHAVIOUR = {"mappo": "cooperative", "qmix": "cooperative", "vdn": "cooperative"}
NETWORKS_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "networks"  # else $URB_JAX_NETWORKS


def sized_config(alg: str, config, n_envs: int, min_days: int):
    """The config with num_envs = B and just enough iterations for >= min_days training days."""
    if alg == "iql_star":
        per_iter = config.update_every * n_envs
        iters = max(1, math.ceil(min_days / per_iter))
        config = dataclasses.replace(config, num_envs=n_envs, num_episodes=iters * config.update_every)
        return config, iters * per_iter
    if alg == "ippo_star":
        config = dataclasses.replace(config, num_envs=n_envs)
        per_iter = days_per_update(config) * n_envs
        iters = max(1, math.ceil(min_days / per_iter))
        return dataclasses.replace(config, num_episodes=iters * days_per_update(config)), iters * per_iter
    per_iter = config.agent_frames_per_batch * n_envs
    iters = max(1, math.ceil(min_days / per_iter))
    return dataclasses.replace(config, num_envs=n_envs, n_iters=iters), iters * per_iter


def with_network(alg: str, config, net: str | None):
    """Override every network size with DEPTHxCELLS (e.g. 2x64) for a reduced-size comparison."""
    if net is None:
        return config
    depth, cells = (int(v) for v in net.lower().split("x"))
    if alg in ("iql_star", "ippo_star"):
        return dataclasses.replace(config, widths=(cells,) * depth)
    sizes = {"mlp_depth": depth, "mlp_cells": cells}
    if alg in ("ippo", "mappo"):
        sizes |= {"critic_depth": depth, "critic_cells": cells}
    if alg == "qmix":
        sizes |= {"mixing_embed_dim": cells}
    return dataclasses.replace(config, **sizes)


def measure(alg: str, env, n_envs: int, config_name: str, min_days: int, net: str | None = None
            ) -> dict[str, float]:
    config = with_network(alg, load_algo_config(alg, config_name), net)
    config, days = sized_config(alg, config, n_envs, min_days)
    train = MODULES[alg].make_train(config, env)
    key = jax.random.PRNGKey(0)
    t0 = time.perf_counter()
    compiled = jax.jit(train).lower(key).compile()
    t1 = time.perf_counter()
    jax.block_until_ready(compiled(key))
    t2 = time.perf_counter()
    return {"compile_s": t1 - t0, "days": days, "run_s": t2 - t1, "days_per_s": days / (t2 - t1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--networks", nargs="+", default=["saint_arnoult", "ingolstadt_custom"])
    parser.add_argument("--algs", nargs="+", default=list(MODULES))
    parser.add_argument("--envs", nargs="+", type=int, default=[1, 64])
    parser.add_argument("--config", nargs="+", default=["config1", "fast"])
    parser.add_argument("--cav-draw", default="urb", choices=["urb", "numpy"],
                        help="URB's exact CAV draw (default) or the earlier numpy draw")
    parser.add_argument("--standin", action="store_true", help="BPR stand-in instead of the surrogate")
    parser.add_argument("--min-days", type=int, default=200, help="training days per measurement (at least)")
    parser.add_argument("--net", default=None, help="override network sizes, DEPTHxCELLS (e.g. 2x64)")
    parser.add_argument("--skip", nargs="*", default=[],
                        help="NETWORK:ALG:B or NETWORK:ALG:CONFIG:B combinations to leave out")
    parser.add_argument("--networks-dir", default=str(NETWORKS_DIR) if NETWORKS_DIR.is_dir() else None)
    parser.add_argument("--calib-days", type=int, default=40,
                        help="SUMO days the surrogate is fitted on (0: uncalibrated, same cost; for timing "
                             "networks whose SUMO days are slow)")
    parser.add_argument("--surrogate-params", default=None,
                        help="folder of fitted surrogate parameters (<network>.npz): read when there, "
                             "else fitted and written (to time the same surrogate on a machine without SUMO)")
    parser.add_argument("--drop-unroutable", action="store_true",
                        help="leave out agents without a route where there are any (mantes_la_jolie)")
    args = parser.parse_args()
    print(f"jax {jax.__version__} on {jax.devices()[0].platform} {jax.devices()[0].device_kind} "
          f"({os.cpu_count()} CPUs); configs "
          f"{' '.join(args.config)}{'' if args.net is None else ' with networks ' + args.net}; "
          f"{'BPR stand-in' if args.standin else 'calibrated surrogate'}; 40% CAVs; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'network':18s} {'alg':10s} {'config':8s} {'B':>3s} {'CAVs':>5s} {'depth':>5s} {'compile s':>9s} "
          f"{'days':>6s} {'run s':>7s} {'days/s':>8s}")
    for net in args.networks:
        scn = load_scenario(net, networks_dir=None if net == "urb_grid" else args.networks_dir,
                            drop_unroutable=args.drop_unroutable)
        params_file = None if args.surrogate_params is None else Path(args.surrogate_params) / f"{net}.npz"
        tt = bpr_travel_time_fn(scn) if args.standin else surrogate_travel_fn(
            scn, n_days=args.calib_days, params_file=params_file)
        is_cav = draw_cavs(42, scn.n_agents, 0.4, agent_id=scn.agent_id, method=args.cav_draw)
        envs = {b: RoutingEnv(scn, is_cav, tt, reward_coefficients=behaviour_coefficients(b))
                for b in ("selfish", "cooperative")}
        for alg in args.algs:
            env = envs[BEHAVIOUR.get(alg, "selfish")]
            for conf in args.config:
                for n_envs in args.envs:
                    if f"{net}:{alg}:{n_envs}" in args.skip or f"{net}:{alg}:{conf}:{n_envs}" in args.skip:
                        print(f"{net:18s} {alg:10s} {conf:8s} {n_envs:3d}  skipped", flush=True)
                        continue
                    r = measure(alg, env, n_envs, conf, args.min_days, args.net)
                    depth = len(dependency_levels(env))
                    print(f"{net:18s} {alg:10s} {conf:8s} {n_envs:3d} {env.n_cavs:5d} {depth:5d} "
                          f"{r['compile_s']:9.1f} {r['days']:6d} {r['run_s']:7.2f} {r['days_per_s']:8.1f}",
                          flush=True)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
