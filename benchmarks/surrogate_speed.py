"""Surrogate days per second vs a plain scatter-add BPR and vs one SUMO day, measured in one run.

    python benchmarks/surrogate_speed.py --networks-dir ../shared/networks

Prints, per network and batch size B: days/s of `surrogate.predict` (int choices), of its
probability input with a gradient (B=64 row), of a plain jitted scatter-add BPR day (vmap, chosen
routes, 5-min bins; the reference design), the speed-up over one SUMO day (sumo_bridge.run_day,
median of 3, same joint action), and days/s when departures move day to day (`--shift-s`): each of
the B days with its own shifts against B scheduled days, both as the training envs call the model
(vmap of the one-day model).
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import load_scenario
from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict, predict_jit

MOVING_BATCHES = (64, 1024)


def rate(fn, arg, batch: int, seconds: float) -> float:
    jax.block_until_ready(fn(arg))
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        jax.block_until_ready(fn(arg))
        n += 1
    return batch * n / (time.perf_counter() - t0)


def plain_bpr(scn, bin_s: float = 300.0):
    """The naive reference: per day, scatter-add chosen-route edge entries into (edge, bin) flows."""
    routes = jnp.asarray(np.maximum(scn.routes, 0))
    valid = jnp.asarray(scn.routes >= 0)
    t0_np = scn.edge_length / scn.edge_speed
    t0 = jnp.asarray(t0_np, jnp.float32)
    cap = jnp.asarray(scn.edge_capacity * bin_s / 3600, jnp.float32)
    t_edge = np.where(scn.routes >= 0, t0_np[np.maximum(scn.routes, 0)], 0)
    enter = scn.agent_depart[:, None, None] + np.cumsum(t_edge, axis=2) - t_edge
    bins = jnp.asarray(np.minimum(enter // bin_s, 15).astype(np.int32))
    n = scn.n_agents
    n_bins = 16

    def day(c):
        e = routes[jnp.arange(n), c]
        b = bins[jnp.arange(n), c]
        v = valid[jnp.arange(n), c]
        cell = e * n_bins + b
        flow = jnp.zeros(scn.n_edges * n_bins).at[cell.reshape(-1)].add(v.reshape(-1).astype(jnp.float32))
        x = flow[cell] / cap[e]
        return jnp.where(v, t0[e] * (1 + 0.15 * x**4), 0).sum(1) / 60

    return jax.jit(jax.vmap(day))


def sumo_seconds(scn, choices: np.ndarray) -> tuple[float, str]:
    from urb_jax.sumo_bridge import run_day

    name = "libsumo"
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        run_day(scn, choices, seed=42)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), name


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--nets", default="urb_grid,saint_arnoult,provins,ingolstadt_custom")
    ap.add_argument("--batches", default="1,64,1024")
    ap.add_argument("--seconds", type=float, default=2.0, help="timing window per measurement")
    ap.add_argument("--no-sumo", action="store_true",
                    help="skip the SUMO day (a machine without SUMO, e.g. a GPU box); its columns read n/a")
    ap.add_argument("--drop-unroutable", action="store_true",
                    help="leave out agents without a route where there are any (mantes_la_jolie)")
    ap.add_argument("--shift-s", type=int, default=300,
                    help="departures moving by up to this many seconds: the moving-departures table")
    args = ap.parse_args()
    print(f"JAX {jax.__version__} on {jax.devices()[0].platform} ({jax.devices()[0].device_kind}), "
          f"{os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f}")
    header = ("| network | agents | B | surrogate days/s | plain BPR days/s | ratio | "
              "SUMO s/day | speed-up vs SUMO |")
    rows = [header, "|---|---|---|---|---|---|---|---|"]
    grad_rows = ["| network | B | prob. input + grad days/s |", "|---|---|---|"]
    moving_rows = [f"| network | B (envs, vmapped) | scheduled days/s | departures moving ±{args.shift_s} s, "
                   "days/s | ratio |", "|---|---|---|---|---|"]
    for net in args.nets.split(","):
        scn = load_scenario(net, networks_dir=args.networks_dir, drop_unroutable=args.drop_unroutable)
        static = build_static(scn, SurrogateConfig())
        params = init_params(static)
        free = np.asarray(scn.fft).argmin(axis=1)
        sumo_s, sumo_name = (float("nan"), "n/a") if args.no_sumo else sumo_seconds(scn, free)
        base = plain_bpr(scn)
        rng = np.random.default_rng(0)
        for b in [int(x) for x in args.batches.split(",")]:
            ch = jnp.asarray(rng.integers(0, scn.k, (b, scn.n_agents)), jnp.int32)
            r_s = rate(lambda c: predict_jit(params, static, c), ch, b, args.seconds)  # noqa: B023
            r_b = rate(base, ch, b, args.seconds)
            rows.append(f"| {net} | {scn.n_agents} | {b} | {r_s:,.0f} | {r_b:,.0f} | {r_s / r_b:.1f}x | "
                        f"{sumo_s:.2f} ({sumo_name}) | {r_s * sumo_s:,.0f}x |")
            print(rows[-1], flush=True)
        logits = jnp.asarray(rng.normal(size=(64, scn.n_agents, scn.k)).astype(np.float32))
        grad = jax.jit(jax.grad(lambda lg, p=params, s=static: predict(p, s, jax.nn.softmax(lg, -1)).sum()))
        grad_rows.append(f"| {net} | 64 | {rate(grad, logits, 64, args.seconds):,.0f} |")
        moving_rows += moving(scn, params, rng, args)
    print("\n".join(["", *rows, "", *grad_rows, "", *moving_rows]))


def moving(scn, params, rng: np.random.Generator, args: argparse.Namespace) -> list[str]:
    """Rows of the moving-departures table: B days each with its own shifts against B scheduled days,
    both as the training envs call the model (one day a call, vmapped over the B envs)."""
    static = build_static(scn, SurrogateConfig(), max_shift_s=float(args.shift_s))
    fixed = build_static(scn, SurrogateConfig())  # a run whose departures never move
    per_day = jax.jit(jax.vmap(lambda c, s: predict(params, static, c, s)))
    scheduled = jax.jit(jax.vmap(lambda c: predict(params, fixed, c)))
    out = []
    for b in MOVING_BATCHES:
        ch = jnp.asarray(rng.integers(0, scn.k, (b, scn.n_agents)), jnp.int32)
        off = rng.integers(-args.shift_s, args.shift_s + 1, (b, scn.n_agents))
        shift = jnp.asarray(np.maximum(scn.agent_depart + off, 0) - scn.agent_depart, jnp.float32)
        r_s = rate(scheduled, ch, b, args.seconds)
        r_m = rate(lambda c: per_day(c, shift), ch, b, args.seconds)  # noqa: B023
        out.append(f"| {scn.name} | {b} | {r_s:,.0f} | {r_m:,.0f} | {r_m / r_s:.2f}x |")
        print(out[-1], flush=True)
    return out


if __name__ == "__main__":
    main()
