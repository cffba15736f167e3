"""How much a SUMO day's mean travel time moves when nothing a route-level model sees changes.

    python benchmarks/sumo_day_spread.py --networks-dir ../shared/networks --nets gargenville,rambouillet

For each network, on the held-out days of `urb-jax validate-surrogate` (benchmarks/surrogate_fidelity.py's):
the day mean under seeds 42-45 (same joint action, another seed), and, for chosen days, the day mean
under seed 42 with one driver switched to another of its routes (`--switches` drivers, one at a time).
Days come from the SUMO day store where they are (run here otherwise, `--workers` at a time).
"""

from __future__ import annotations

import argparse

import numpy as np

from urb_jax.city.scenario import load_scenario
from urb_jax.sumo_bridge import ARRIVED
from urb_jax.surrogate.data import make_choices
from urb_jax.surrogate.model import build_static, init_params
from urb_jax.surrogate.sumo_days import sumo_days

SEED = 42


def held_out(net: str, networks_dir: str | None, test_days: int):
    scn = load_scenario(net, networks_dir=networks_dir)
    bpr = build_static(scn)
    choices, kinds = make_choices(scn, bpr, init_params(bpr), test_days, seed=2)
    return scn, choices, kinds


def seed_spread(scn, choices: np.ndarray, seeds: int, workers: int) -> np.ndarray:
    """[seeds, D] each day's mean travel time (minutes) over the drivers who arrived under every seed."""
    days = [sumo_days(scn, choices, SEED + i, workers=workers) for i in range(seeds)]
    arrived = np.logical_and.reduce([np.stack([d.status == ARRIVED for d in ds]) for ds in days])
    return np.array([[d.travel_time[arrived[j]].mean() for j, d in enumerate(ds)] for ds in days])


def one_driver_switches(scn, base: np.ndarray, n: int, workers: int, seed: int = 7) -> np.ndarray:
    """[n + 1] the day mean under seed 42: the day itself, then with each of n random drivers
    switched to its next valid route (arrived drivers of each day)."""
    rng = np.random.default_rng(seed)
    valid = np.asarray(scn.route_valid)
    variants = [base]
    while len(variants) < n + 1:
        i = int(rng.integers(scn.n_agents))
        alts = [k for k in range(scn.k) if k != base[i] and valid[i, k]]
        if alts:
            v = base.copy()
            v[i] = alts[0]
            variants.append(v)
    days = sumo_days(scn, np.stack(variants), SEED, workers=workers)
    return np.array([d.travel_time[d.status == ARRIVED].mean() for d in days])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--nets", default="gargenville,rambouillet")
    ap.add_argument("--test-days", type=int, default=10)
    ap.add_argument("--seeds", type=int, default=4, help="seeds 42.. for the spread across seeds")
    ap.add_argument("--switch-days", default="rambouillet:3,rambouillet:7,gargenville:6",
                    help="NET:DAY pairs (held-out day index) to perturb by one driver")
    ap.add_argument("--switches", type=int, default=8)
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    nets = [n for n in args.nets.split(",") if n]
    last = SEED + args.seeds - 1
    print(f"| network | day | kind | day mean, seeds {SEED}-{last} (min) | seed {SEED} / mean of the "
          "others - 1 | coefficient of variation |")
    print("|---|---|---|---|---|---|")
    held = {net: held_out(net, args.networks_dir, args.test_days) for net in nets}
    for net in nets:
        scn, choices, kinds = held[net]
        means = seed_spread(scn, choices, args.seeds, args.workers)
        for d in range(len(kinds)):
            m = means[:, d]
            print(f"| {net} | {d} | {kinds[d]} | {' / '.join(f'{x:.2f}' for x in m)} | "
                  f"{m[0] / m[1:].mean() - 1:+.1%} | {m.std(ddof=1) / m.mean():.1%} |")
        cv = means.std(0, ddof=1) / means.mean(0)
        print(f"| {net} | all | | | | median {np.median(cv):.1%} |")
    print()
    print(f"| network | day | kind | day mean, seed {SEED} | with one driver switched ({args.switches} "
          "drivers, one at a time) | range |")
    print("|---|---|---|---|---|---|")
    for pair in [p for p in args.switch_days.split(",") if p]:
        net, day = pair.split(":")
        if net not in nets:
            continue
        scn, choices, kinds = held[net]
        m = one_driver_switches(scn, choices[int(day)], args.switches, args.workers)
        print(f"| {net} | {day} | {kinds[int(day)]} | {m[0]:.2f} | {', '.join(f'{x:.2f}' for x in m[1:])} | "
              f"{m[1:].min():.2f}-{m[1:].max():.2f} |", flush=True)


if __name__ == "__main__":
    main()
