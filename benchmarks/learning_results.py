"""Learning results: each algorithm's CAVs (40%) vs the random and AON baselines.

Protocol (URB scenario 1, shortened): humans learn alone for `--human-days` days (Gawron, on the
travel-time model: the surrogate calibrated on 40 cached SUMO days, or `--standin` for the BPR
stand-in), 40% of them become CAVs (mutation from the env seed) and keep the humans'
learned knowledge frozen; each algorithm trains with URB's config (selfish reward for IQL, IPPO,
IQL*, IPPO*; cooperative for MAPPO, QMIX, VDN) for the config's training days, then its test
policy (greedy / argmax) is evaluated for `--test-days` days. Baselines use the same frozen
humans. Prints final mean CAV travel times (minutes) and saves learning curves.

    python benchmarks/learning_results.py --out results/algorithms --config config1 fast
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_surrogate import surrogate_travel_fn
from standin import bpr_travel_time_fn

from urb_jax.algorithms import ippo, ippo_star, iql, iql_star, mappo, qmix, vdn
from urb_jax.algorithms.baselines import baseline_policy
from urb_jax.algorithms.ippo_star import days_per_update
from urb_jax.algorithms.learner import evaluate
from urb_jax.algorithms.registry import load_algo_config
from urb_jax.city.scenario import load_scenario
from urb_jax.game.env import RoutingEnv
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.rewards import behaviour_coefficients

MODULES = {"iql": iql, "ippo": ippo, "iql_star": iql_star, "ippo_star": ippo_star, "mappo": mappo,
           "qmix": qmix, "vdn": vdn}
BEHAVIOUR = {"mappo": "cooperative", "qmix": "cooperative", "vdn": "cooperative"}
NETWORKS_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "networks"


def human_phase(scn, travel_time_fn, days: int, key: jax.Array):
    """Humans alone for `days` days; returns their learned state and mean time on the last day."""
    env = RoutingEnv(scn, np.zeros(scn.n_agents, bool), travel_time_fn, humans_adapt=True)  # they learn
    _, state = env.reset(key)
    no_cav = jnp.zeros((0,), jnp.int32)

    def body(state, k):
        _, state, _, _, info = env.step(k, state, no_cav)
        return state, info["mean_time_human"]

    state, times = jax.lax.scan(body, state, jax.random.split(key, days))
    return state.humans, float(times[-1])


def test_policy(alg: str, config, env, params):
    module = MODULES[alg]
    if alg in ("iql", "qmix", "vdn", "iql_star"):
        return module.make_policy(config, env)(params, 0.0)
    return module.make_policy(config, env)(params, False)


def training_days(alg: str, config) -> np.ndarray:
    """Training day (per env) at the end of each iteration, for the learning curve's x axis."""
    if alg == "iql_star":
        per = config.update_every
        n = config.num_episodes // per
    elif alg == "ippo_star":
        per = days_per_update(config)
        n = max(1, config.num_episodes // per)
    else:
        per, n = config.agent_frames_per_batch, config.n_iters
    return per * (np.arange(n) + 1)


def train_one(alg: str, conf: str, env, args, num_envs: dict[str, int], key: jax.Array):
    """Train one algorithm with one config on `env`; (result row, learning curve)."""
    config = load_algo_config(alg, conf)
    if args.days is not None:
        if alg in ("iql_star", "ippo_star"):
            config = dataclasses.replace(config, num_episodes=args.days)
        else:
            config = dataclasses.replace(config, n_iters=max(1, args.days // config.agent_frames_per_batch))
    if alg in num_envs:
        config = dataclasses.replace(config, num_envs=num_envs[alg])
    t0 = time.perf_counter()
    result = jax.block_until_ready(jax.jit(MODULES[alg].make_train(config, env))(key))
    train_s = time.perf_counter() - t0
    m = evaluate(env, test_policy(alg, config, env, result["runner_state"].params), key, args.test_days)
    x = training_days(alg, config)
    row = {"algorithm": alg, "config": Path(conf).stem, "time_cav": float(m["time_cav"]),
           "time_human": float(m["time_human"]), "train_s": train_s, "days": int(x[-1]) * config.num_envs,
           "num_envs": config.num_envs}
    return row, (x * config.num_envs, np.asarray(result["metrics"]["time_cav"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--networks", nargs="+", default=["saint_arnoult", "provins"])
    parser.add_argument("--algs", nargs="+", default=list(MODULES))
    parser.add_argument("--config", nargs="+", default=["config1"], help="algo config name(s) or paths")
    parser.add_argument("--days", type=int, default=None, help="override training days (per env)")
    parser.add_argument("--num-envs", nargs="*", default=[], metavar="ALG=B",
                        help="train ALG with B parallel environments (default: the config's num_envs)")
    parser.add_argument("--standin", action="store_true", help="BPR stand-in instead of the surrogate")
    parser.add_argument("--skip", nargs="*", default=[], help="NETWORK:ALG:CONFIG runs to leave out")
    parser.add_argument("--human-days", type=int, default=200)
    parser.add_argument("--test-days", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cav-draw", default="urb", choices=["urb", "numpy"],
                        help="URB's exact CAV draw (default) or the earlier numpy draw")
    parser.add_argument("--out", default="results/algorithms")
    parser.add_argument("--networks-dir", default=str(NETWORKS_DIR) if NETWORKS_DIR.is_dir() else None)
    args = parser.parse_args()
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    key = jax.random.PRNGKey(args.seed)
    num_envs = {k: int(v) for k, v in (item.split("=") for item in args.num_envs)}
    rows, curves = [], {}
    for net in args.networks:
        scn = load_scenario(net, networks_dir=args.networks_dir)
        tt = bpr_travel_time_fn(scn) if args.standin else surrogate_travel_fn(scn)
        humans, t_pre = human_phase(scn, tt, args.human_days, key)
        is_cav = draw_cavs(42, scn.n_agents, 0.4, agent_id=scn.agent_id, method=args.cav_draw)
        envs = {b: RoutingEnv(scn, is_cav, tt, reward_coefficients=behaviour_coefficients(b),
                              human_init=humans) for b in ("selfish", "cooperative")}
        base = {}
        for name in ("random", "aon"):
            m = evaluate(envs["selfish"], baseline_policy(name, envs["selfish"]), key, args.test_days)
            base[name] = float(m["time_cav"])
            rows.append({"network": net, "algorithm": name, "config": "", "time_cav": base[name],
                         "time_human": float(m["time_human"]), "train_s": 0.0, "days": 0})
        print(f"{net}: {scn.n_agents} agents, {int(is_cav.sum())} CAVs; humans before mutation "
              f"{t_pre:.3f} min; random {base['random']:.3f}, AON {base['aon']:.3f}", flush=True)
        for alg in args.algs:
            for conf in args.config:
                if f"{net}:{alg}:{conf}" in args.skip:
                    print(f"  {alg:10s} {conf:8s} skipped", flush=True)
                    continue
                row, curve = train_one(alg, conf, envs[BEHAVIOUR.get(alg, "selfish")], args, num_envs, key)
                rows.append(row | {"network": net})
                curves[(net, f"{alg} {row['config']}")] = curve
                t_cav = row["time_cav"]
                beh = BEHAVIOUR.get(alg, "selfish")
                print(f"  {alg:10s} {row['config']:8s} {beh:12s} CAV {t_cav:.3f} min "
                      f"({100 * (t_cav / base['aon'] - 1):+.2f}% vs AON), humans {row['time_human']:.3f}, "
                      f"{row['days']} days (B={row['num_envs']}) in {row['train_s']:.0f} s (incl. compile)",
                      flush=True)
        curves[(net, "_base")] = base
    (out / "learning_results.json").write_text(json.dumps(rows, indent=1))
    plot(curves, args.networks, out / "learning_curves.png")
    print_table(rows)


def print_table(rows: list[dict]) -> None:
    print("\n| network | algorithm | config | mean CAV time (min) | vs AON | mean human time | days "
          "| train s |")
    print("|---|---|---|---|---|---|---|---|")
    aon = {r["network"]: r["time_cav"] for r in rows if r["algorithm"] == "aon"}
    for r in rows:
        rel = 100 * (r["time_cav"] / aon[r["network"]] - 1)
        print(f"| {r['network']} | {r['algorithm']} | {r['config']} | {r['time_cav']:.3f} | {rel:+.2f}% | "
              f"{r['time_human']:.3f} | {r['days']} | {r['train_s']:.0f} |")


def plot(curves: dict, networks: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(networks), figsize=(7 * len(networks), 4.5), squeeze=False)
    colours = {alg: f"C{i}" for i, alg in enumerate(MODULES)}
    for ax, net in zip(axes[0], networks, strict=True):
        for (n, label), value in curves.items():
            if n != net or label == "_base":
                continue
            x, y = value
            alg, conf = label.split(" ", 1)  # colour per algorithm, dashed for non-URB configs
            style = "-" if conf.startswith("config") else "--"
            ax.plot(x, y, label=label, lw=1, color=colours.get(alg), ls=style)
        base = curves.get((net, "_base"), {})
        for name, style in (("random", ":"), ("aon", "--")):
            if name in base:
                ax.axhline(base[name], color="k", ls=style, lw=1, label=name)
        ax.set_title(f"{net} (training, exploring policies)")
        ax.set_xscale("log")
        ax.set_xlabel("training days (all environments, log scale)")
        ax.set_ylabel("mean CAV travel time (min)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"learning curves: {path}")


if __name__ == "__main__":
    main()
