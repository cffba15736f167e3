"""How urb-jax's costs grow with the number of agents, on synthetic cities (networks/synthetic.py).

    python benchmarks/synthetic_scale.py --out /tmp/urb-jax-synth [--sizes 1000 2500 5000 10000 50000]

Each size N is the city `city_for_agents(N)` (about 12 agents per lane-km), generated into
`--out/networks/synth_<N>/` unless there. Every measurement runs in its own child process (this
script re-invoked with `--part`), so its peak RSS is its own; a watchdog kills a child whose
resident set passes `--max-rss-gb` (the machine is shared) or that runs past `--timeout`. Each
part's result is merged into `--out/synth_<N>.json` as it ends, so a rerun resumes (`--force`:
again). Parts:
  gen        netconvert and the demand (wall s; CPU s of netconvert)
  build      first `load_scenario` with an empty cache (route sampling, one process), then copied
             into the cache
  surrogate  `build_static`, then per B in --batches: first `predict_jit` call (compile + one batch)
             and days/s (`surrogate_speed.rate`); uncalibrated parameters (same cost as calibrated);
             a B whose chunk working set (entries x min(B, chunk) x 4 bytes x 3) would pass
             --max-rss-gb is skipped with that estimate
  train      IQL* (URB config1, B=64 envs, 40% selfish CAVs) on the uncalibrated surrogate:
             compile s and training days/s (`train_speed.measure`, updates included)
  sumo       one in-process SUMO day (a fresh `Simulator`: network load included), every driver on
             its free-flow fastest route; skipped where the previous size's day, scaled by the
             agents, exceeds --sumo-max-s
Every part records wall and CPU seconds (the machine is shared: CPU seconds are the load-robust
number), its peak RSS and the load average. Prints a markdown table; writes `--out/synthetic_scale.png`
(log-log cost against agents).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from scale import copy_new_scenarios, fmt, peak_rss_mib, stamp

from urb_jax.core.atomic import write_json
from urb_jax.core.paths import CACHE_ENV, cache_dir

PARTS = ("gen", "build", "surrogate", "train", "sumo")
IQL_ENVS = 64


def cpu_s() -> float:
    """CPU seconds of this process and its waited-for children (netconvert, route workers)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


class Clock:
    """Wall and CPU seconds since creation."""

    def __init__(self) -> None:
        self.wall, self.cpu = time.perf_counter(), cpu_s()

    def read(self) -> tuple[float, float]:
        return time.perf_counter() - self.wall, cpu_s() - self.cpu


def name_of(n: int) -> str:
    return f"synth_{n}"


def nets_dir(args: argparse.Namespace) -> Path:
    return Path(args.out) / "networks"


# --- the parts, each run in a child process ---------------------------------------------------------

def part_gen(n: int, args: argparse.Namespace) -> dict[str, Any]:
    from urb_jax.networks.synthetic import city_for_agents, generate, lane_km, zones

    cfg = city_for_agents(n, name_of(n))
    clock = Clock()
    generate(cfg, nets_dir(args))
    wall, cpu = clock.read()
    return {"gen_s": wall, "gen_cpu_s": cpu, "cols": cfg.cols, "rows": cfg.rows, "lane_km": lane_km(cfg),
            "zones": len(zones(cfg))}


def part_build(n: int, args: argparse.Namespace) -> dict[str, Any]:
    """$URB_JAX_CACHE points at a fresh folder (the parent set it), so routes are sampled here, in
    this process (`workers=1`: the default pool's forkserver workers are not our children, so their
    CPU seconds would go uncounted; a pool of w workers divides the CPU seconds by up to w)."""
    import numpy as np

    from urb_jax.city.scenario import load_scenario

    clock = Clock()
    scn = load_scenario(name_of(n), networks_dir=nets_dir(args), workers=1)
    wall, cpu = clock.read()
    lengths = (scn.routes >= 0).sum(-1)  # [N, K] edges per route
    return {"first_build_s": wall, "first_build_cpu_s": cpu, "agents": scn.n_agents, "od_pairs": scn.n_od,
            "edges": scn.n_edges, "k": scn.k, "route_edges_mean": float(lengths.mean()),
            "route_edges_max": int(lengths.max()), "invalid_routes": int((~scn.od_route_valid).sum()),
            "fft_mean_min": float(np.min(scn.fft, axis=1).mean())}


def part_surrogate(n: int, args: argparse.Namespace) -> dict[str, Any]:
    import jax
    import jax.numpy as jnp
    import numpy as np
    from surrogate_speed import rate

    from urb_jax.city.scenario import load_scenario
    from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict_jit

    scn = load_scenario(name_of(n), networks_dir=nets_dir(args))
    config = SurrogateConfig()
    clock = Clock()
    static = jax.block_until_ready(build_static(scn, config))
    wall, cpu = clock.read()
    entries = int(static.flow_row.shape[0])
    r: dict[str, Any] = {"static_s": wall, "static_cpu_s": cpu, "entries": entries, "cells": static.n_cells,
                         "device": jax.devices()[0].device_kind, "compile_s": {}, "compile_cpu_s": {},
                         "days_per_s": {}, "days_per_cpu_s": {}, "skipped": {}}
    params = init_params(static)
    rng = np.random.default_rng(0)
    for b in args.batches:
        need_gb = entries * min(b, config.chunk) * 4 * 3 / 2**30
        if need_gb > args.max_rss_gb:
            r["skipped"][str(b)] = f"chunk working set ~{need_gb:.0f} GB > --max-rss-gb {args.max_rss_gb:g}"
            continue
        c = jnp.asarray(rng.integers(0, scn.k, (b, scn.n_agents)), jnp.int32)
        clock = Clock()
        jax.block_until_ready(predict_jit(params, static, c))
        r["compile_s"][str(b)], r["compile_cpu_s"][str(b)] = clock.read()
        clock = Clock()
        r["days_per_s"][str(b)] = rate(lambda x: predict_jit(params, static, x), c, b, args.seconds)
        r["days_per_cpu_s"][str(b)] = r["days_per_s"][str(b)] * clock.read()[0] / clock.read()[1]
        print(f"{name_of(n)} surrogate B={b}: compile {r['compile_s'][str(b)]:.1f} s, "
              f"{r['days_per_s'][str(b)]:,.1f} days/s", flush=True)
    r["peak_rss_mib"] = peak_rss_mib()
    return r


def part_train(n: int, args: argparse.Namespace) -> dict[str, Any]:
    from real_surrogate import surrogate_travel_fn
    from train_speed import measure

    from urb_jax.city.scenario import load_scenario
    from urb_jax.game.env import RoutingEnv
    from urb_jax.game.mutation import draw_cavs
    from urb_jax.game.rewards import behaviour_coefficients

    scn = load_scenario(name_of(n), networks_dir=nets_dir(args))
    is_cav = draw_cavs(42, scn.n_agents, 0.4, agent_id=scn.agent_id)
    env = RoutingEnv(scn, is_cav, surrogate_travel_fn(scn, n_days=0, verbose=False),
                     reward_coefficients=behaviour_coefficients("selfish"))
    clock = Clock()
    m = measure("iql_star", env, IQL_ENVS, "config1", args.min_days)
    wall, cpu = clock.read()
    return {"compile_s": m["compile_s"], "days": m["days"], "run_s": m["run_s"],
            "days_per_s": m["days_per_s"], "wall_s": wall, "cpu_s": cpu,
            "cavs": int(env.n_cavs), "peak_rss_mib": peak_rss_mib()}


def part_sumo(n: int, args: argparse.Namespace) -> dict[str, Any]:
    from urb_jax.city.scenario import load_scenario
    from urb_jax.sumo_bridge import SumoConfig
    from urb_jax.sumo_bridge.sim import Simulator

    scn = load_scenario(name_of(n), networks_dir=nets_dir(args))
    shm = "/dev/shm" if os.path.isdir("/dev/shm") else None
    with tempfile.TemporaryDirectory(prefix="urb-jax-synth-", dir=shm) as d:
        clock = Clock()
        sim = Simulator(SumoConfig(), log_file=Path(d) / "day.log")
        day = sim.run_day(scn, scn.fft.argmin(1), seed=42)
        wall, cpu = clock.read()
        sim.close()
    return {"sumo_day_s": wall, "sumo_day_cpu_s": cpu, "mean_tt_min": float(day.travel_time.mean()),
            "removed": int(day.n_removed), "peak_rss_mib": peak_rss_mib()}


FNS = {"gen": part_gen, "build": part_build, "surrogate": part_surrogate, "train": part_train,
       "sumo": part_sumo}


def child(args: argparse.Namespace) -> None:
    write_json(args.json, {**FNS[args.part](args.one, args), **stamp()})


# --- the parent ---------------------------------------------------------------------------------------

def rss_mib(pid: int) -> float:
    """Resident set of a process and its children (route workers, SUMO) from /proc, MiB."""
    total = 0.0
    pids = [pid]
    while pids:
        p = pids.pop()
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1]) / 1024
            children = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        pids += [int(c) for c in children]
    return total


def run_part(n: int, part: str, args: argparse.Namespace) -> dict[str, Any]:
    """One part in a child process under the RSS and time watchdog; {"failed": why} when it did not end."""
    forward = ["--out", str(args.out), "--seconds", str(args.seconds), "--min-days", str(args.min_days),
               "--max-rss-gb", str(args.max_rss_gb), "--batches", *map(str, args.batches)]
    env = dict(os.environ)
    with tempfile.TemporaryDirectory(prefix="urb-jax-synth-") as d:
        if part == "build":
            env[CACHE_ENV] = str(Path(d) / "cache")
        out = Path(d) / "result.json"
        cmd = [sys.executable, __file__, "--one", str(n), "--part", part, "--json", str(out), *forward]
        proc = subprocess.Popen(cmd, env=env, start_new_session=True)
        t0, peak, why = time.time(), 0.0, None
        while proc.poll() is None:
            time.sleep(1.0)
            peak = max(peak, rss_mib(proc.pid))
            if peak > args.max_rss_gb * 1024:
                why = f"killed: resident set {peak / 1024:.1f} GB > --max-rss-gb {args.max_rss_gb:g}"
            elif time.time() - t0 > args.timeout:
                why = f"killed: still running after --timeout {args.timeout:g} s"
            if why:
                os.killpg(proc.pid, 9)  # the child's own session: it and the workers it started
                proc.wait()
        if why is None and (proc.returncode != 0 or not out.is_file()):
            why = f"failed: exit {proc.returncode}"
        if why:
            print(f"{name_of(n)} part {part}: {why}", flush=True)
            return {"failed": why, "wall_s": time.time() - t0, **stamp()}
        if part == "build":
            copy_new_scenarios(Path(d) / "cache" / "scenarios", cache_dir() / "scenarios")
        return json.loads(out.read_text())


def sumo_skip_reason(n: int, results: dict[int, dict[str, Any]], limit_s: float) -> str | None:
    """Skip the SUMO day where the largest smaller size's day, scaled linearly by agents (a lower
    bound: days grow faster than linearly once streets congest), passes `limit_s`."""
    done = [(m, r["sumo"]) for m, r in results.items() if m < n and "sumo_day_cpu_s" in r.get("sumo", {})]
    if not done:
        return None
    m, s = max(done, key=lambda x: x[0])
    est = s["sumo_day_cpu_s"] * n / m
    if est <= limit_s:
        return None
    return f"est. >= {est:.0f} CPU s (synth_{m}: {s['sumo_day_cpu_s']:.0f} s) > --sumo-max-s"


def measure_size(n: int, args: argparse.Namespace, results: dict[int, dict[str, Any]]) -> None:
    path = Path(args.out) / f"{name_of(n)}.json"
    res = results.setdefault(n, json.loads(path.read_text()) if path.is_file() else {"agents": n})
    for part in args.parts:
        if part in res and not args.force and "failed" not in res[part]:
            continue
        if part != "gen" and "failed" in res.get("gen", {"failed": "missing"}):
            break
        if part == "sumo" and (why := sumo_skip_reason(n, results, args.sumo_max_s)):
            res[part] = {"skipped": why, **stamp()}
        else:
            print(f"{name_of(n)}: part {part} starts (load {os.getloadavg()[0]:.1f})", flush=True)
            res[part] = run_part(n, part, args)
        write_json(path, res)
        print(f"{name_of(n)}: part {part} done", flush=True)


def load_results(out: Path) -> dict[int, dict[str, Any]]:
    rows = {}
    for p in sorted(out.glob("synth_*.json")):
        r = json.loads(p.read_text())
        rows[int(r["agents"])] = r
    return dict(sorted(rows.items()))


def cell(part: dict[str, Any], value: Any, spec: str) -> str:
    if "failed" in part:
        return "failed"
    if "skipped" in part and not isinstance(part["skipped"], dict):
        return "skipped"
    return fmt(value, spec)


def table(results: dict[int, dict[str, Any]], batches: list[int]) -> str:
    head = ["agents", "grid", "lane-km", "OD pairs", "edges", "route edges", "gen s", "first build s (CPU s)",
            *(f"surr. days/s B={b}" for b in batches), "surr. compile s (B=64)", "surr. peak RSS MiB",
            "IQL* compile s", "IQL* days/s (B=64)", "IQL* peak RSS MiB", "SUMO day s (CPU s)",
            "SUMO mean tt / free-flow min", "removed", "load"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    notes = []
    for n, r in results.items():
        g, b, s, t, d = (r.get(p, {}) for p in PARTS)
        per_s = s.get("days_per_s", {})
        surr = [fmt(per_s.get(str(x)), ",.1f") if str(x) in per_s else
                ("skipped" if str(x) in s.get("skipped", {}) else cell(s, None, "")) for x in batches]
        for x, why in s.get("skipped", {}).items():
            notes.append(f"synth_{n} surrogate B={x}: {why}")
        for name, part in zip(PARTS, (g, b, s, t, d), strict=True):
            if "failed" in part:
                notes.append(f"synth_{n} {name}: {part['failed']}")
        if isinstance(d.get("skipped"), str):
            notes.append(f"synth_{n} SUMO day skipped: {d['skipped']}")
        loads = [p["load_avg"] for p in (g, b, s, t, d) if "load_avg" in p]
        cells = [f"{n:,}", f"{g.get('cols', '?')}x{g.get('rows', '?')}", fmt(g.get("lane_km"), ",.0f"),
                 fmt(b.get("od_pairs"), ",d"), fmt(b.get("edges"), ",d"),
                 fmt(b.get("route_edges_mean"), ".1f"),
                 cell(g, g.get("gen_s"), ",.0f"),
                 f"{cell(b, b.get('first_build_s'), ',.0f')} ({fmt(b.get('first_build_cpu_s'), ',.0f')})",
                 *surr, cell(s, s.get("compile_s", {}).get("64"), ".1f"),
                 cell(s, s.get("peak_rss_mib"), ",.0f"),
                 cell(t, t.get("compile_s"), ",.0f"), cell(t, t.get("days_per_s"), ",.2f"),
                 cell(t, t.get("peak_rss_mib"), ",.0f"),
                 f"{cell(d, d.get('sumo_day_s'), ',.0f')} ({fmt(d.get('sumo_day_cpu_s'), ',.0f')})",
                 f"{cell(d, d.get('mean_tt_min'), '.2f')} / {fmt(b.get('fft_mean_min'), '.2f')}",
                 cell(d, d.get("removed"), "d"),
                 f"{min(loads):.0f}-{max(loads):.0f}" if loads else "n/a"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines + ([""] + [f"* {x}" for x in notes] if notes else []))


def plot(results: dict[int, dict[str, Any]], batches: list[int], path: Path) -> None:
    """Log-log cost against agents: seconds per day (surrogate per B, IQL*, SUMO), compile and build
    seconds, and peak RSS."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def series(get):
        pts = [(n, v) for n, r in results.items() if (v := get(r)) is not None]
        return [p[0] for p in pts], [p[1] for p in pts]

    def inv(v):
        return None if not v else 1.0 / v

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.5))
    for b in batches:
        ax.plot(*series(lambda r, b=b: inv(r.get("surrogate", {}).get("days_per_s", {}).get(str(b)))),
                "o-", label=f"surrogate s/day, B={b}")
    ax.plot(*series(lambda r: inv(r.get("train", {}).get("days_per_s"))), "s-",
            label="IQL* s/training day (B=64)")
    ax.plot(*series(lambda r: r.get("sumo", {}).get("sumo_day_s")), "^-", label="SUMO s/day (wall)")
    ax.plot(*series(lambda r: r.get("sumo", {}).get("sumo_day_cpu_s")), "^--", label="SUMO CPU s/day")
    ax.plot(*series(lambda r: r.get("build", {}).get("first_build_cpu_s")), "x:", label="first build CPU s")
    ax.plot(*series(lambda r: r.get("surrogate", {}).get("compile_s", {}).get("64")), "d:",
            label="surrogate compile s (B=64)")
    ax.plot(*series(lambda r: r.get("train", {}).get("compile_s")), "d-.", label="IQL* compile s")
    ax.set(xscale="log", yscale="log", xlabel="agents", ylabel="seconds", title="time")
    ax.legend(fontsize=7)
    for name, part in (("surrogate", "surrogate"), ("IQL* training", "train"), ("SUMO day", "sumo")):
        bx.plot(*series(lambda r, p=part: r.get(p, {}).get("peak_rss_mib")), "o-", label=name)
    bx.set(xscale="log", yscale="log", xlabel="agents", ylabel="peak RSS MiB", title="memory")
    bx.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", type=int, default=[1000, 2500, 5000, 10000, 20000, 50000])
    ap.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS))
    ap.add_argument("--out", default="/tmp/urb-jax-synth")
    ap.add_argument("--force", action="store_true", help="measure again the parts already in --out")
    ap.add_argument("--batches", nargs="+", type=int, default=[1, 64, 1024])
    ap.add_argument("--seconds", type=float, default=2.0, help="timing window per surrogate days/s")
    ap.add_argument("--min-days", type=int, default=64, help="IQL* training days timed (at least)")
    ap.add_argument("--max-rss-gb", type=float, default=12.0, help="kill a part whose resident set passes it")
    ap.add_argument("--timeout", type=float, default=3600.0, help="kill a part running longer (s)")
    ap.add_argument("--sumo-max-s", type=float, default=300.0, help="skip SUMO days estimated longer (CPU s)")
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--part", choices=PARTS, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--json", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        child(args)
        return
    Path(args.out).mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()
    print(f"sizes {args.sizes}; results in {args.out}; {os.cpu_count()} CPUs, load {load0[0]:.1f}",
          flush=True)
    results = load_results(Path(args.out))
    for n in sorted(args.sizes):
        measure_size(n, args, results)
    results = load_results(Path(args.out))
    print(f"\nload average at start {load0[0]:.1f}, at end {os.getloadavg()[0]:.1f}; {os.cpu_count()} CPUs\n")
    print(table(results, args.batches))
    png = Path(args.out) / "synthetic_scale.png"
    plot(results, args.batches, png)
    print(f"\nplot: {png}")


if __name__ == "__main__":
    main()
