"""Per-day overhead of the PettingZoo envs over a bare SUMO day: AEC before (another checkout's
env, e.g. main's) vs AEC and Parallel now.

A day = reset, every CAV acting (the free-flow fastest route, looked up: no policy cost) through
the env's own loop (AEC: `agent_iter`/`last`/`step`; Parallel: one `step` per dependency level),
the day's end. Overhead = the day's wall time minus its SUMO day (`run_day`, timed inside the
env's day executor: the bare SUMO day on the same choices). Humans start from their free-flow
knowledge (no human phase: it does not change the env's cost), CAVs are URB's draw under the task.

Each variant runs in its own process (two checkouts cannot share one), one warm-up day, then
`--days` days; rounds interleave the variants (before, AEC, Parallel, before, ...) so that
machine load hits them alike. The table reports medians over all measured days, and the load
average (`uptime`) before and after.

    python benchmarks/pettingzoo_overhead.py --before ../main --networks-dir ../shared/networks \\
        [--networks urb_grid saint_arnoult provins] [--task config1] [--days 5] [--rounds 3]
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
VARIANTS = ("aec_before", "aec", "parallel")


def worker(network: str, networks_dir: str | None, task_name: str, variant: str, days: int) -> dict:
    """Runs in the variant's checkout: per-day (wall, SUMO) seconds."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from urb_jax.city.scenario import load_scenario
    from urb_jax.game.config import load_task_config
    from urb_jax.game.humans import init_humans_jit
    from urb_jax.interop import pettingzoo as pettingzoo_env
    from urb_jax.sumo_bridge import run_day

    scn = load_scenario(network, networks_dir=networks_dir)
    task, _ = load_task_config(task_name)
    sumo_s: list[float] = []

    class TimedDays:
        """The env's days (an executor; called, a day function, as older envs take them), timed."""

        def __call__(self, scenario, choices, *, seed, is_cav=None):
            t0 = time.perf_counter()
            res = run_day(scenario, choices, seed=seed, is_cav=is_cav)
            sumo_s.append(time.perf_counter() - t0)
            return res

        def run_days(self, scenario, choices, seeds, is_cav=None):
            masks = [None] * len(choices) if is_cav is None else list(np.broadcast_to(is_cav, choices.shape))
            return [self(scenario, c, seed=int(s), is_cav=m)
                    for c, s, m in zip(choices, seeds, masks, strict=True)]

        def close(self):
            pass

    humans = init_humans_jit(jax.random.fold_in(jax.random.PRNGKey(42), 1), jnp.asarray(scn.fft, jnp.float32),
                             jnp.asarray(scn.route_valid), task.human_params())
    cls = pettingzoo_env.UrbParallelEnv if variant == "parallel" else pettingzoo_env.UrbAECEnv
    takes = "executor" if "executor" in inspect.signature(cls.__init__).parameters else "day_fn"
    env = cls(scn, task, env_seed=42, humans=humans, **{takes: TimedDays()})
    pick = {a: int(np.argmin(scn.fft[i])) for a, i in zip(env.possible_agents, env.cav_index, strict=True)}

    def aec_day() -> None:
        env.reset()
        for agent in env.agent_iter():
            _obs, _rew, term, trunc, _info = env.last()
            env.step(None if term or trunc else pick[agent])

    def parallel_day() -> None:
        _obs, infos = env.reset()
        while env.agents:
            actions = {a: pick[a] for a in env.agents if infos[a]["acting"]}
            _obs, _rew, _term, _trunc, infos = env.step(actions)

    day = parallel_day if variant == "parallel" else aec_day
    walls = []
    for _ in range(days + 1):  # the first: warm-up (jit compiles, SUMO loads the network)
        t0 = time.perf_counter()
        day()
        walls.append(time.perf_counter() - t0)
    return {"wall": walls[1:], "sumo": sumo_s[1:], "cavs": len(env.possible_agents),
            "levels": getattr(env, "num_levels", None), "module": pettingzoo_env.__file__}


def run_variant(args: argparse.Namespace, network: str, variant: str) -> dict:
    root = Path(args.before).resolve() if variant == "aec_before" else REPO
    env = {**os.environ, "PYTHONPATH": str(root)}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", variant, "--networks", network,
           "--task", args.task, "--days", str(args.days)]
    if args.networks_dir:
        cmd += ["--networks-dir", str(Path(args.networks_dir).resolve())]
    out = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env, cwd=root)
    if out.returncode != 0:
        raise SystemExit(f"{variant} on {network} failed:\n{out.stderr[-3000:]}")
    result = json.loads(out.stdout.strip().splitlines()[-1])
    if not result["module"].startswith(str(root)):
        raise SystemExit(f"{variant} imported {result['module']}, not from {root}")
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", help="checkout whose UrbAECEnv is 'AEC before' (required)")
    ap.add_argument("--networks", nargs="+", default=["urb_grid", "saint_arnoult", "provins"])
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--task", default="config1")
    ap.add_argument("--days", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--worker", choices=VARIANTS, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args.networks[0], args.networks_dir, args.task, args.worker, args.days)))
        return
    if not args.before:
        ap.error("--before CHECKOUT is required (the checkout whose UrbAECEnv is 'AEC before')")
    print(f"load average before: {os.getloadavg()}  ({os.cpu_count()} CPUs)")
    rows = []
    for network in args.networks:
        runs: dict[str, list[dict]] = {v: [] for v in VARIANTS}
        for _ in range(args.rounds):
            for v in VARIANTS:
                runs[v].append(run_variant(args, network, v))
        for v in VARIANTS:
            wall = [w for r in runs[v] for w in r["wall"]]
            sumo = [s for r in runs[v] for s in r["sumo"]]
            over = [w - s for w, s in zip(wall, sumo, strict=True)]
            rows.append((network, runs[v][0]["cavs"], v, runs[v][0]["levels"], statistics.median(sumo),
                         statistics.median(over), len(wall)))
    print(f"load average after:  {os.getloadavg()}")
    print(f"\ntask {args.task}; medians over the measured days (seconds per day)\n")
    print(f"{'network':<15}{'CAVs':>5}  {'env':<11}{'steps/day':>10}{'SUMO day':>10}{'overhead':>10}"
          f"{'overhead/SUMO':>14}{'days':>6}")
    for network, cavs, v, levels, sumo, over, n in rows:
        steps = cavs if levels is None else levels
        print(f"{network:<15}{cavs:>5}  {v:<11}{steps:>10}{sumo:>10.3f}{over:>10.4f}{over / sumo:>13.1%}"
              f"{n:>6}")


if __name__ == "__main__":
    main()
