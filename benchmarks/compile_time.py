"""Compilation paid once: compiles and compile seconds of a short `urb-jax train` run with a cold
and a warm persistent compilation cache, and against the number of departure levels.

Each measured run is its own process (a warm cache only helps a new process). Per network
(saint_arnoult when ../shared/networks is there, and the embedded urb_grid) and observations
(URB's env config1, a few departure levels; `global_previous_agents`, one level per distinct
CAV departure second), a fresh compile cache is filled by the cold run and read by the warm
one. The human phase is simulated once per network beforehand and reused (`human_phase_from`),
so the wall column is the training: calibration, the rounds, the test days.
`--unrolled` adds a cold row with the replaced one-step-per-level loop, for the levels scaling.

    python benchmarks/compile_time.py --out /tmp/compile_time [--unrolled] [--networks urb_grid] \
        [--networks-dir ../shared/networks]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

NETWORKS_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "networks"
OBSERVATIONS = {"default": "config1", "many levels": "global_previous_agents"}
BACKEND = "/jax/core/compile/backend_compile_duration"
TRACE = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration")
HIT = "/jax/compilation_cache/cache_hits"
HEADER = ("network", "observations", "levels", "act loop", "cache", "compiles", "hits", "compile s",
          "trace s", "wall s")
ROW = "{:14s} {:12s} {:>6} {:9s} {:5s} {:>8} {:>5} {:>9} {:>7} {:>7}"


def child(spec: dict) -> None:
    """One train run in this process; prints its compile counts and times as JSON (last line)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from urb_jax.runs.request import TrainRequest
    from urb_jax.runs.train import run_train

    counts: Counter = Counter()
    secs: Counter = Counter()

    def on_duration(event: str, duration: float, **_: object) -> None:
        counts[event] += 1
        secs[event] += duration

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    jax.monitoring.register_event_listener(lambda event, **_: counts.update([event]))
    if spec["unrolled"]:
        _use_unrolled_levels(jax, jnp, np)
    t0 = time.perf_counter()
    run_train(TrainRequest(alg=spec["alg"], net=spec["net"], networks_dir=spec["networks_dir"],
                           env_conf=spec["env_conf"], train_days=spec["train_days"],
                           results_dir=spec["results"], exp_id=spec["id"], human_phase_from=spec["human"],
                           progress=False))
    wall = time.perf_counter() - t0
    print(json.dumps({"compiles": counts[BACKEND] - counts[HIT], "hits": counts[HIT],
                      "compile_s": secs[BACKEND], "trace_s": sum(secs[e] for e in TRACE), "wall_s": wall}))


def _use_unrolled_levels(jax, jnp, np) -> None:
    """act_by_levels unrolled (one traced step per level), for the comparison with the scan blocks."""
    from urb_jax.algorithms import learner
    from urb_jax.game.rollout import dependency_levels
    from urb_jax.training.hybrid import fns

    def unrolled(env, key, state, policy, levels=None):
        levels = dependency_levels(env) if levels is None else levels
        actions = state.cav_actions
        for lv, idx in enumerate(levels):
            obs = env.observe(state, actions)
            chosen = policy(jax.random.fold_in(key, lv), obs[idx], jnp.asarray(idx))
            actions = actions.at[idx].set(chosen.astype(jnp.int32))
        return env.observe(state, actions), actions

    learner.act_by_levels = unrolled
    fns.act_by_levels = unrolled


def run_child(spec: dict, compile_cache: Path | str) -> dict:
    env = {**os.environ, "URB_JAX_COMPILE_CACHE": str(compile_cache)}
    proc = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], env=env,
                          capture_output=True, text=True)
    if proc.returncode:
        sys.exit(f"child failed ({spec['id']}):\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def levels_of(net: str, networks_dir: str | None, env_conf: str) -> int:
    """Departure levels of the run's CAVs (URB's mutation, task config1)."""
    import numpy as np

    from urb_jax.city.scenario import load_scenario
    from urb_jax.game.config import load_env_config, load_task_config
    from urb_jax.game.env import RoutingEnv
    from urb_jax.game.mutation import draw_cavs
    from urb_jax.game.rollout import dependency_levels

    scn = load_scenario(net, networks_dir=networks_dir)
    task, _ = load_task_config("config1")
    env_cfg, _ = load_env_config(env_conf)
    is_cav = draw_cavs(42, scn.n_agents, task.ratio_machines, agent_id=scn.agent_id)
    env = RoutingEnv(scn, np.asarray(is_cav), lambda c: c * 0.0, observation_type=env_cfg.observations)
    return len(dependency_levels(env))


def env_configs(out: Path) -> dict[str, str]:
    """Observation variant -> env config id or path (the many-level one written next to the runs)."""
    from urb_jax.core.configio import find_config

    base = json.loads(find_config("env", "config1").read_text())
    path = out / "env_global.json"
    path.write_text(json.dumps(base | {"desc": "config1 with global_previous_agents observations",
                                       "observations": OBSERVATIONS["many levels"]}))
    return {"default": "config1", "many levels": str(path)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--networks", nargs="+", default=None)
    ap.add_argument("--networks-dir", default=str(NETWORKS_DIR), help="where saint_arnoult is (URB networks)")
    ap.add_argument("--alg", default="iql_star")
    ap.add_argument("--train-days", type=int, default=700, help="one round of the default hybrid config")
    ap.add_argument("--unrolled", action="store_true", help="also the replaced unrolled loop (cold)")
    ap.add_argument("--unrolled-max-levels", type=int, default=100,
                    help="no unrolled row above this many levels (urb_grid's 141 take tens of minutes)")
    ap.add_argument("--out", default="/tmp/compile_time")
    a = ap.parse_args()
    if a.child:
        child(json.loads(a.child))
        return
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    real = ["saint_arnoult"] if (Path(a.networks_dir) / "saint_arnoult").is_dir() else []
    nets = a.networks or [*real, "urb_grid"]
    confs = env_configs(out)
    print(f"{a.alg}, --train-days {a.train_days}, human phase reused; {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)
    print(ROW.format(*HEADER), flush=True)
    for net in nets:
        ndir = None if net == "urb_grid" else a.networks_dir
        base = {"alg": a.alg, "net": net, "networks_dir": ndir, "train_days": a.train_days,
                "results": str(out / "results"), "unrolled": False}
        human = f"{net}_human"
        if not (out / "results" / human / "exp_config.json").is_file():
            run_child(base | {"env_conf": "config1", "id": human, "human": None, "train_days": 1},
                      out / "cache_human")
        for label, conf in confs.items():
            cache = out / f"jax_{net}_{label.replace(' ', '_')}_{time.time_ns()}"
            rows = [("blocks", "cold", cache), ("blocks", "warm", cache)]
            levels = levels_of(net, ndir, conf)
            if a.unrolled and levels <= a.unrolled_max_levels:
                rows.append(("unrolled", "cold", "off"))
            for loop, kind, where in rows:
                spec = base | {"env_conf": conf, "human": human, "unrolled": loop == "unrolled",
                               "id": f"{net}_{label.replace(' ', '_')}_{loop}_{kind}_{time.time_ns()}"}
                r = run_child(spec, where)
                times = (f"{r[k]:.1f}" for k in ("compile_s", "trace_s", "wall_s"))
                print(ROW.format(net, label, levels, loop, kind, r["compiles"], r["hits"], *times),
                      flush=True)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
