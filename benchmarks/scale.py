"""How urb-jax scales over the nine real URB networks: build, SUMO, surrogate and training costs.

    python benchmarks/scale.py [--networks saint_arnoult provins] [--out /tmp/urb-jax-scale] \
        [--networks-dir ../shared/networks] [--skip-first-build] [--no-fidelity] [--force]

Every network is measured in its own processes (this script re-invoked with `--one NETWORK --part
PART --json FILE`), one part at a time: `build` (the first scenario build), `main` (everything
else in the first table) and `fidelity`. Each part's result is merged into `--out/<network>.json`
(written atomically) as soon as it ends, so a rerun resumes: it runs only the parts a network's JSON
lacks (all of them with `--force`) and prints the tables over every network in `--out`. Agents whose
OD pair has no route are dropped everywhere (`drop_unroutable=True`; mantes_la_jolie has some).

Main table, one row per network, sorted by agents:
  agents, dropped      agents simulated, and agents left out as unroutable
  edges, K             network edges (`scn.n_edges`) and routes per agent
  first build s        `load_scenario` with an empty cache ($URB_JAX_CACHE pointed at a fresh folder
                       in a child process; the built entry is then copied into the real cache)
  cached load s        `load_scenario` again from the real cache
  SUMO day s           one in-process day (warm `Simulator`, urb-jax's default stuck rule), every
                       driver on its free-flow fastest route (`scn.fft.argmin(1)`); median of
                       `--sumo-reps` days, after one warm-up day
  same-rule s, CLI s   the same day with SUMO's own teleport-and-remove stuck rule, in process and as
                       a one-shot `sumo` CLI run (benchmarks/sumo_speed.py: the CLI cannot run ours)
  mean tt, removed     that default-rule day's mean travel time (min) and vehicles removed as stuck
  surr. days/s B=1, B=1024   `predict_jit` days per second (uncalibrated parameters: the cost does
                       not depend on their values; random route choices)
  surr. compile s      the first `predict_jit` call at B=1024: tracing, compiling and one batch
  IQL* compile s       `jax.jit(train).lower(key).compile()` of IQL* (config1, B=64 environments,
                       40% CAVs, selfish) on the BPR stand-in (benchmarks/train_speed.py `measure`)
  IQL* days/s (B=64)   its training days per second (>= `--min-days` days, updates included)
  peak RSS MiB         max resident set of the `main` process at its end (`ru_maxrss`; the CLI
                       SUMO run, a separate process, is not in it; nor is the build, whose peak,
                       route-generation workers left out, is `build_peak_rss_mib` in the JSON)
No persistent JAX compilation cache is used, so compile columns are cold compiles.

Fidelity table (networks with <= `--fidelity-max-agents` agents): `urb-jax validate-surrogate`
with its defaults (40 calibration SUMO days, 10 held-out, single-route deviations of 30 agents):
held-out mean-travel-time error, per agent-day MAPE and R², and better-route agreement (for one
agent switching route, does the surrogate say which of the two is faster, as SUMO does?) next to
the free-flow predictor's and SUMO's own seed-to-seed floor; "clear pairs": only pairs whose SUMO
times differ by at least 15 s; "argmin": the agent's fastest of its K routes agrees. SUMO days
come from (and go to) the day cache, $URB_JAX_CACHE/sumo_days, so "wall s" is that of this run,
not of a cold one. Reports go to `--out/validation/<network>/`.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from urb_jax.core.atomic import atomic_path, write_json
from urb_jax.core.paths import CACHE_ENV, cache_dir

PARTS = ("build", "main", "fidelity")
SURROGATE_BATCHES = (1, 1024)
IQL_ENVS = 64
NETWORKS_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "networks"  # as the other benchmarks


def progress(net: str, step: str, since: float) -> None:
    """A plain line with the seconds since the network's first part began (`time.time()`: the parts
    are separate processes)."""
    print(f"{net:22s} {step:66s} elapsed {time.time() - since:7.1f} s", flush=True)


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def stamp() -> dict[str, Any]:
    """When and under what load a part ran (rows of different runs share a table)."""
    return {"measured_at": datetime.datetime.now().isoformat(timespec="seconds"),
            "load_avg": os.getloadavg()[0], "cpus": os.cpu_count()}


# --- the parts, each run in a child process ---------------------------------------------------------

def part_build(net: str, args: argparse.Namespace) -> dict[str, Any]:
    """First build: run with $URB_JAX_CACHE at a fresh folder (the parent set it), so nothing is cached."""
    from urb_jax.city.scenario import load_scenario

    t0 = time.perf_counter()
    scn = load_scenario(net, networks_dir=args.networks_dir, drop_unroutable=True)
    build_s = time.perf_counter() - t0
    progress(net, f"build: first build {build_s:.1f} s", args.started)
    return {"first_build_s": build_s, "agents": scn.n_agents,
            "dropped": int(scn.dropped_unroutable.size), "build_peak_rss_mib": peak_rss_mib()}


def part_main(net: str, args: argparse.Namespace) -> dict[str, Any]:
    """Cached load, SUMO days, surrogate speed and the IQL* compile, in one process for its peak RSS."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    import sumo
    from standin import make_env
    from sumo_speed import cli_day, timed_days, write_day_rou
    from surrogate_speed import rate
    from train_speed import measure

    from urb_jax.city.scenario import load_scenario
    from urb_jax.sumo_bridge import SumoConfig
    from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict_jit

    since = args.started
    r: dict[str, Any] = {"jax": jax.__version__, "device": jax.devices()[0].device_kind,
                         "compile_cache": jax.config.jax_compilation_cache_dir}
    load_scenario(net, networks_dir=args.networks_dir, drop_unroutable=True)  # built here if not cached
    t = time.perf_counter()
    scn = load_scenario(net, networks_dir=args.networks_dir, drop_unroutable=True)
    r |= {"cached_load_s": time.perf_counter() - t, "agents": scn.n_agents,
          "dropped": int(scn.dropped_unroutable.size), "edges": scn.n_edges, "k": scn.k}
    progress(net, f"main: {scn.n_agents} agents, cached load {r['cached_load_s']:.2f} s", since)

    choices = scn.fft.argmin(1)
    binary = os.path.join(sumo.SUMO_HOME, "bin", "sumo")
    same_rule = SumoConfig(stuck_rule="sumo")
    shm = "/dev/shm" if os.path.isdir("/dev/shm") else None
    with tempfile.TemporaryDirectory(prefix="urb-jax-scale-", dir=shm) as d:
        (lib_t,), day = timed_days(scn, choices, [SumoConfig()], Path(d) / "day.log", args.sumo_reps)
        r |= {"sumo_day_s": statistics.median(lib_t), "mean_tt_min": float(day.travel_time.mean()),
              "removed": int(day.n_removed)}
        progress(net, f"main: in-process SUMO day {r['sumo_day_s']:.2f} s", since)
        rou, trip = Path(d) / "day.rou.xml", Path(d) / "day.trip.xml"
        write_day_rou(rou, scn, choices)
        (same_t, cli_t), same_day = timed_days(
            scn, choices, [same_rule], Path(d) / "same.log", args.sumo_reps,
            cli=lambda: cli_day(binary, scn, rou, trip, same_rule, 42))
    r |= {"same_rule_day_s": statistics.median(same_t), "cli_day_s": statistics.median(cli_t),
          "same_rule_mean_tt_min": float(same_day.travel_time.mean()),
          "same_rule_removed": int(same_day.n_removed)}
    progress(net, f"main: same-rule day {r['same_rule_day_s']:.2f} s, CLI {r['cli_day_s']:.2f} s", since)

    static = build_static(scn, SurrogateConfig())
    params = init_params(static)
    rng = np.random.default_rng(0)
    batches = {b: jnp.asarray(rng.integers(0, scn.k, (b, scn.n_agents)), jnp.int32)
               for b in SURROGATE_BATCHES}

    def surrogate(c: jax.Array) -> jax.Array:
        return predict_jit(params, static, c)

    t = time.perf_counter()
    jax.block_until_ready(surrogate(batches[max(SURROGATE_BATCHES)]))
    r["surrogate_compile_s"] = time.perf_counter() - t
    r["surrogate_days_per_s"] = {str(b): rate(surrogate, c, b, args.seconds) for b, c in batches.items()}
    progress(net, f"main: surrogate compile {r['surrogate_compile_s']:.2f} s, days/s "
             + ", ".join(f"B={b} {v:,.0f}" for b, v in r["surrogate_days_per_s"].items()), since)

    iql = measure("iql_star", make_env(scn), IQL_ENVS, "config1", args.min_days)
    r |= {"iql_star_compile_s": iql["compile_s"], "iql_star_days_per_s": iql["days_per_s"],
          "iql_star_days": iql["days"], "iql_star_run_s": iql["run_s"]}
    progress(net, f"main: IQL* compile {iql['compile_s']:.1f} s, {iql['days_per_s']:.1f} days/s", since)
    r["peak_rss_mib"] = peak_rss_mib()
    return r


def part_fidelity(net: str, args: argparse.Namespace) -> dict[str, Any]:
    """`urb-jax validate-surrogate` through its own parser, so its defaults are the command's."""
    from urb_jax.commands import validate_surrogate

    t0 = time.perf_counter()
    out = Path(args.out) / "validation" / net
    parser = argparse.ArgumentParser(prog="urb-jax")
    validate_surrogate.register(parser.add_subparsers())
    argv = ["validate-surrogate", "--net", net, "--drop-unroutable", "--out", str(out)]
    if args.networks_dir:
        argv += ["--networks-dir", str(args.networks_dir)]
    if args.fidelity_days is not None:
        argv += ["--days", str(args.fidelity_days)]
    if args.fidelity_train_days is not None:
        argv += ["--train-days", str(args.fidelity_train_days)]
    cmd = parser.parse_args(argv)
    if cmd.func(cmd) != 0:
        raise RuntimeError(f"validate-surrogate on {net} failed")
    m = json.loads((out / "metrics.json").read_text())
    progress(net, "fidelity: validate-surrogate done", args.started)
    return {"agents": m["setup"]["agents"], "train_days": cmd.train_days, "test_days": cmd.days,
            "deviation_days": m["setup"]["deviation_days"], "held_out": m["held_out"],
            "uncalibrated": m["uncalibrated"], "route_agreement": m["route_agreement"],
            "seed_to_seed_mape_base": m.get("seed_to_seed_mape_base"), "timing_s": m["timing_s"],
            "report": str(out / "report.md"), "wall_s": time.perf_counter() - t0}


def child(args: argparse.Namespace) -> None:
    args.started = args.started or time.time()
    fn = {"build": part_build, "main": part_main, "fidelity": part_fidelity}[args.part]
    write_json(args.json, {**fn(args.one, args), **stamp()})


# --- the parent: which parts to run, merging, tables ------------------------------------------------

def run_part(net: str, part: str, args: argparse.Namespace, started: float) -> dict[str, Any] | None:
    """One part in a child process (a fresh cache for `build`, whose entry then joins the real one);
    None when the child failed."""
    forward = ["--started", str(started), "--out", str(args.out), "--seconds", str(args.seconds),
               "--sumo-reps", str(args.sumo_reps), "--min-days", str(args.min_days)]
    if args.networks_dir:
        forward += ["--networks-dir", str(args.networks_dir)]
    for flag, value in (("--fidelity-days", args.fidelity_days),
                        ("--fidelity-train-days", args.fidelity_train_days)):
        if value is not None:
            forward += [flag, str(value)]
    env = dict(os.environ)
    with tempfile.TemporaryDirectory(prefix="urb-jax-scale-") as d:
        if part == "build":
            env[CACHE_ENV] = str(Path(d) / "cache")
        out = Path(d) / "result.json"
        cmd = [sys.executable, __file__, "--one", net, "--part", part, "--json", str(out), *forward]
        proc = subprocess.run(cmd, env=env)
        if proc.returncode != 0 or not out.is_file():
            print(f"{net:22s} part {part} FAILED (exit {proc.returncode})", flush=True)
            return None
        if part == "build":
            copy_new_scenarios(Path(d) / "cache" / "scenarios", cache_dir() / "scenarios")
        return json.loads(out.read_text())


def copy_new_scenarios(src: Path, dst: Path) -> None:
    """Entries of a first build join the real cache where it lacks them (never replacing one)."""
    for f in sorted(src.glob("*.npz")):
        if not (dst / f.name).exists():
            with atomic_path(dst / f.name) as tmp:
                shutil.copyfile(f, tmp)


def agents_of(res: dict[str, Any]) -> int | None:
    for part in PARTS:
        if isinstance(res.get(part), dict) and "agents" in res[part]:
            return res[part]["agents"]
    return None


def measure_network(net: str, args: argparse.Namespace) -> bool:
    """Run the parts `net`'s JSON lacks (or all asked for with --force); False when one failed."""
    path = Path(args.out) / f"{net}.json"
    res = json.loads(path.read_text()) if path.is_file() else {"network": net}
    wanted = [p for p in PARTS if not (p == "build" and args.skip_first_build)
              and not (p == "fidelity" and args.no_fidelity)]
    todo = [p for p in wanted if args.force or p not in res]
    if not todo:
        print(f"{net:22s} already in {path}, skipped (--force to measure again)", flush=True)
        return True
    t0 = time.time()
    for part in todo:
        n = agents_of(res)
        if part == "fidelity" and n is not None and n > args.fidelity_max_agents:
            progress(net, f"fidelity skipped: {n} agents > --fidelity-max-agents", t0)
            continue
        progress(net, f"part {part} starts", t0)
        r = run_part(net, part, args, t0)
        if r is None:
            return False
        res[part] = r
        write_json(path, res)
        progress(net, f"part {part} done", t0)
    return True


def fmt(value: Any, spec: str = ".2f") -> str:
    return "n/a" if value is None else format(value, spec)


def tables(out: Path) -> str:
    """Markdown tables over every network JSON in `out`, sorted by agents."""
    rows = [json.loads(p.read_text()) for p in sorted(out.glob("*.json"))]
    rows = sorted((r for r in rows if "network" in r), key=lambda r: agents_of(r) or 0)
    head = ["network", "agents", "dropped", "edges", "K", "first build s", "cached load s", "SUMO day s",
            "same-rule day s", "CLI same-rule s", "mean tt min", "removed", "surr. days/s B=1",
            "surr. days/s B=1024", "surr. compile s", "IQL* compile s", "IQL* days/s (B=64)", "peak RSS MiB"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        b, m = r.get("build", {}), r.get("main", {})
        per_s = m.get("surrogate_days_per_s", {})
        cells = [r["network"], fmt(agents_of(r), "d"), fmt(m.get("dropped", b.get("dropped")), "d"),
                 fmt(m.get("edges"), "d"), fmt(m.get("k"), "d"), fmt(b.get("first_build_s"), ".1f"),
                 fmt(m.get("cached_load_s"), ".3f"), fmt(m.get("sumo_day_s")), fmt(m.get("same_rule_day_s")),
                 fmt(m.get("cli_day_s")), fmt(m.get("mean_tt_min")), fmt(m.get("removed"), "d"),
                 fmt(per_s.get("1"), ",.0f"), fmt(per_s.get("1024"), ",.0f"),
                 fmt(m.get("surrogate_compile_s")), fmt(m.get("iql_star_compile_s"), ".1f"),
                 fmt(m.get("iql_star_days_per_s"), ",.1f"), fmt(m.get("peak_rss_mib"), ",.0f")]
        lines.append("| " + " | ".join(cells) + " |")
    head = ["network", "agents", "calib./held-out days", "mean tt error", "MAPE", "R²",
            "pair agreement: surrogate", "free-flow", "SUMO seed vs seed", "surrogate, clear pairs",
            "argmin agreement", "wall s"]
    fid = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        f = r.get("fidelity")
        if not f:
            continue
        h, ag = f["held_out"], f["route_agreement"]
        seed = ag.get("sumo_seed_vs_seed", {}).get("pair_agreement")
        cells = [r["network"], fmt(f["agents"], "d"), f"{f['train_days']}/{f['test_days']}",
                 fmt(h["mean_tt_error"], ".1%"), fmt(h["mape"], ".1%"), fmt(h["r2"], ".3f"),
                 fmt(ag["surrogate"]["pair_agreement"], ".1%"), fmt(ag["free_flow"]["pair_agreement"], ".1%"),
                 fmt(seed, ".1%"), fmt(ag["surrogate"]["pair_agreement_clear"], ".1%"),
                 fmt(ag["surrogate"]["argmin_agreement"], ".1%"), fmt(f["wall_s"], ".0f")]
        fid.append("| " + " | ".join(cells) + " |")
    return "\n".join([*lines, *(["", *fid] if len(fid) > 2 else [])])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--networks", nargs="+", default=None,
                    help="default: every folder of --networks-dir that holds a network")
    ap.add_argument("--networks-dir", default=str(NETWORKS_DIR) if NETWORKS_DIR.is_dir() else None)
    ap.add_argument("--out", default="/tmp/urb-jax-scale", help="one <network>.json per network")
    ap.add_argument("--force", action="store_true", help="measure again the parts already in --out")
    ap.add_argument("--skip-first-build", action="store_true",
                    help="no fresh first build (mantes_la_jolie's takes ~8 minutes); the cached one is used")
    ap.add_argument("--no-fidelity", action="store_true", help="no validate-surrogate (many SUMO days)")
    ap.add_argument("--fidelity-max-agents", type=int, default=1500)
    ap.add_argument("--fidelity-days", type=int, default=None, help="held-out SUMO days (command default)")
    ap.add_argument("--fidelity-train-days", type=int, default=None,
                    help="calibration SUMO days (command default)")
    ap.add_argument("--sumo-reps", type=int, default=1, help="timed SUMO days per kind (median)")
    ap.add_argument("--seconds", type=float, default=2.0, help="timing window per surrogate days/s")
    ap.add_argument("--min-days", type=int, default=200, help="IQL* training days timed (at least)")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # child: this network ...
    ap.add_argument("--part", choices=PARTS, default=None, help=argparse.SUPPRESS)  # ... this part ...
    ap.add_argument("--json", default=None, help=argparse.SUPPRESS)  # ... result written here
    ap.add_argument("--started", type=float, default=None, help=argparse.SUPPRESS)  # for progress lines
    args = ap.parse_args()
    if args.one:
        child(args)
        return
    from urb_jax.city.network import available_networks

    if args.networks is None:
        root = Path(args.networks_dir).resolve() if args.networks_dir else None
        args.networks = [f.name for f in available_networks(args.networks_dir) if f.folder.parent == root]
    load0 = os.getloadavg()
    print(f"{len(args.networks)} network(s): {' '.join(args.networks)}; results in {args.out}; "
          f"cache {cache_dir()}; {os.cpu_count()} CPUs, load average {load0[0]:.1f}", flush=True)
    failed = [net for net in args.networks if not measure_network(net, args)]
    load1 = os.getloadavg()
    print(f"\nload average at start {load0[0]:.1f} ({load0[1]:.1f} over 5 min), at end {load1[0]:.1f} "
          f"({load1[1]:.1f} over 5 min); {os.cpu_count()} CPUs\n")
    print(tables(Path(args.out)))
    if failed:
        print(f"\nfailed (rerun to retry): {' '.join(failed)}")
        sys.exit(1)


if __name__ == "__main__":
    main()
