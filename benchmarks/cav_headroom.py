"""How much room did a finished run's CAVs have? SUMO days around its test day; prints a table.

Usage: python benchmarks/cav_headroom.py RUN_FOLDER [--networks-dir DIR] [--sumo-binary BIN ...]

Humans are deterministic and frozen after mutation, so every test day has the same human routes
and the CAVs' t_CAV is one SUMO day. Rows (all SUMO, same seed):
  policy             the run's test day replayed
  AON                CAVs on their minimum free-flow route, same humans (URB's AON baseline)
  CAVs pre-mutation  the CAV agents' own mean time over the last 50 human days (they were humans)
  CAVs only: ...     the humans removed from the day: what the CAVs' routes cost with no human
                     traffic at all, a rough floor for any routing of the CAVs among the humans
  --sumo-binary      the test day exported (urb_jax.day_export) and run by another SUMO build's
                     CLI, e.g. an older eclipse-sumo wheel unpacked with `pip install --target`
  --deviations N     N random CAVs each try every other route alone (one SUMO day each, a pool
                     of --workers): is the test day a Nash equilibrium of the selfish reward in
                     SUMO? Prints how many CAVs could gain by switching, and how much.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from urb_jax.game.humans import aon_routes
from urb_jax.reporting.day_export import (
    cli_travel_times,
    day_routes_xml,
    recorded_day,
    run_config,
    scenario_of_run,
)
from urb_jax.reporting.records import read_records
from urb_jax.sumo_bridge import run_day


def unilateral_deviations(scn, choices, is_cav, base_times, seed: int, n: int, workers: int) -> str:
    """One SUMO day per (sampled CAV, other valid route), everyone else as on the test day."""
    from urb_jax.sumo_bridge import SumoPool

    rng = np.random.default_rng(0)
    cavs = rng.choice(np.flatnonzero(is_cav), size=min(n, int(is_cav.sum())), replace=False)
    days, who = [], []
    for i in cavs:
        for k in np.flatnonzero(scn.route_valid[i]):
            if k != choices[i]:
                d = choices.copy()
                d[i] = k
                days.append(d)
                who.append(i)
    pool = SumoPool(workers)
    try:
        res = pool.run_days(scn, np.stack(days), [seed] * len(days), is_cav=is_cav)
    finally:
        pool.close()
    best = {i: base_times[i] for i in cavs}
    team = []  # the CAV mean of each deviation day
    for i, r in zip(who, res, strict=True):
        best[i] = min(best[i], r.travel_time[i])
        team.append(r.travel_time[is_cav].mean())
    gain = np.array([base_times[i] - best[i] for i in cavs])
    up = gain > 1e-9
    team_gain = base_times[is_cav].mean() - np.array(team)
    return (f"unilateral deviations, {len(cavs)} CAVs, {len(days)} SUMO days:\n"
            f"  selfish: {int(up.sum())} CAVs could cut their own time by switching "
            f"(mean gain {gain[up].mean() if up.any() else 0.0:.3f} min, max {gain.max():.3f})\n"
            f"  team: {int((team_gain > 1e-9).sum())} of the switches lower the CAV mean "
            f"(best by {max(team_gain.max(), 0.0):.4f} min)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--sumo-binary", nargs="*", default=[])
    ap.add_argument("--deviations", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    cfg = run_config(args.run)
    seed, H = int(cfg["env_seed"]), int(cfg["human_learning_episodes"])
    scn = scenario_of_run(args.run, args.networks_dir)
    day, choices, is_cav, recorded = recorded_day(args.run, scn)
    rec = read_records(args.run, columns=["day", "agent", "travel_time"])
    pre = rec[(rec["day"] > H - 50) & (rec["day"] <= H)].pivot(index="day", columns="agent",
                                                                  values="travel_time")[scn.agent_id]
    pre = pre.to_numpy()
    aon = aon_routes(scn.fft, scn.route_valid)
    idx = np.flatnonzero(is_cav)
    sub = scn.with_agents(idx)  # the CAVs alone: every human removed from the day
    rows = [("t_pre (all agents, last 50 human days)", pre.mean(), None)]
    rows.append(("CAVs pre-mutation (same agents as humans)", pre[:, is_cav].mean(), None))
    pol = run_day(scn, choices, seed=seed, is_cav=is_cav)
    assert np.allclose(pol.travel_time, recorded, rtol=1e-6), "replay differs from the records"
    rows.append((f"policy (test day {day} replayed)", pol.travel_time[is_cav].mean(),
                 pol.travel_time[~is_cav].mean()))
    a = run_day(scn, np.where(is_cav, aon, choices), seed=seed, is_cav=is_cav)
    rows.append(("AON, same humans", a.travel_time[is_cav].mean(), a.travel_time[~is_cav].mean()))
    for name, ch in (("policy", choices[idx]), ("AON", aon[idx])):
        r = run_day(sub, ch, seed=seed, is_cav=np.ones(len(idx), bool))
        rows.append((f"CAVs only, {name} routes (no humans)", r.travel_time.mean(), None))
    for b in args.sumo_binary:
        with tempfile.TemporaryDirectory() as tmp:
            rou = Path(tmp) / "day.rou.xml"
            rou.write_text(day_routes_xml(scn, choices, is_cav))
            t = cli_travel_times(scn, rou, seed, b)
        rows.append((f"policy on {b}", t[is_cav].mean(), t[~is_cav].mean()))
    if args.deviations:
        print(unilateral_deviations(scn, choices, is_cav, pol.travel_time, seed, args.deviations,
                                    args.workers))
    print(f"{scn.name}: {scn.n_agents} agents, {len(idx)} CAVs, run {args.run}")
    print(f"| {'SUMO day':<52} | t_CAV  | t_HDV  |")
    print(f"|{'-' * 54}|--------|--------|")
    for name, c, h in rows:
        print(f"| {name:<52} | {c:.4f} | {'' if h is None else f'{h:.4f}':<6} |")


if __name__ == "__main__":
    main()
