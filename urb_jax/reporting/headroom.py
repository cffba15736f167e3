"""How much room did a finished run's CAVs have? SUMO days around its test day (`urb-jax headroom`).

Humans are deterministic and frozen after mutation, so every test day has the same human routes
and the CAVs' t_CAV is one SUMO day. Rows (all SUMO, the run's env seed):
  t_pre              all agents' mean time over the last 50 human days (from the records)
  CAVs pre-mutation  the CAV agents' own mean time over those days (they were humans)
  policy             the run's test day (its last SUMO day) replayed; it must give the recorded times
  AON                CAVs on their minimum free-flow route, same humans (URB's AON baseline)
  CAVs only: ...     the humans removed from the day: what the CAVs' routes cost with no human
                     traffic at all, a rough floor for any routing of the CAVs among the humans
  sumo_binaries      the test day exported (`day_routes_xml`) and run by another SUMO build's CLI,
                     e.g. an older eclipse-sumo wheel unpacked with `pip install --target`
  deviations N       N random CAVs each try every other route alone (one SUMO day each, a pool of
                     `workers`): is the test day a Nash equilibrium of the selfish reward in SUMO?
                     A summary of how many CAVs could gain by switching, and how much.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.errors import UrbJaxError
from urb_jax.game.humans import aon_routes
from urb_jax.reporting.day_export import cli_travel_times, day_routes_xml, recorded_day, scenario_of_run
from urb_jax.reporting.records import check_scheduled_departures, read_records, run_config
from urb_jax.sumo_bridge import run_day

PRE_DAYS = 50  # the human days before mutation that t_pre and the CAVs' own pre-mutation time average


@dataclass(frozen=True)
class Row:
    name: str
    t_cav: float  # mean time of the row's CAVs (or of all agents, for t_pre), minutes
    t_hdv: float | None = None  # the humans' mean on that day, where the day has humans


@dataclass(frozen=True)
class Headroom:
    network: str
    agents: int
    cavs: int
    test_day: int
    rows: list[Row]
    deviations: str | None  # the unilateral-deviation summary, when asked for


def headroom(folder: str | os.PathLike, networks_dir: str | None = None, sumo_binaries: Sequence[str] = (),
             deviations: int = 0, workers: int = 2) -> Headroom:
    """The SUMO days around finished run `folder`'s test day (module docstring)."""
    cfg = run_config(folder)
    check_scheduled_departures(folder, cfg, "its AON and floor days would run the scheduled ones")
    seed, H = int(cfg["env_seed"]), int(cfg["human_learning_episodes"])
    scn = scenario_of_run(folder, networks_dir)
    day, choices, is_cav, recorded = recorded_day(folder, scn)
    if not is_cav.any():
        raise UrbJaxError(f"{folder}: test day {day} has no CAVs (a humans-only run): there is no CAV "
                          "routing to compare. Fix: pass a run with CAVs (task ratio_machines > 0).")
    rec = read_records(folder, columns=["day", "agent", "travel_time"])
    pre = rec[(rec["day"] > H - PRE_DAYS) & (rec["day"] <= H)].pivot(
        index="day", columns="agent", values="travel_time")[scn.agent_id].to_numpy()
    aon = np.asarray(aon_routes(scn.fft, scn.route_valid))  # [N] each agent's free-flow fastest route
    idx = np.flatnonzero(is_cav)
    rows = [Row(f"t_pre (all agents, last {PRE_DAYS} human days)", pre.mean()),
            Row("CAVs pre-mutation (same agents as humans)", pre[:, is_cav].mean())]
    pol = run_day(scn, choices, seed=seed, is_cav=is_cav)
    if not np.allclose(pol.travel_time, recorded, rtol=1e-6):
        raise UrbJaxError(f"{folder}: test day {day} replayed in SUMO differs from its records (mean "
                          f"{pol.travel_time.mean():.4f} against {recorded.mean():.4f} min). Fix: pass the "
                          "--networks-dir the run used, with the SUMO version it ran on.")
    rows.append(Row(f"policy (test day {day} replayed)", pol.travel_time[is_cav].mean(),
                    pol.travel_time[~is_cav].mean()))
    a = run_day(scn, np.where(is_cav, aon, choices), seed=seed, is_cav=is_cav)
    rows.append(Row("AON, same humans", a.travel_time[is_cav].mean(), a.travel_time[~is_cav].mean()))
    sub = scn.with_agents(idx)  # the CAVs alone: every human removed from the day
    for name, ch in (("policy", choices[idx]), ("AON", aon[idx])):
        r = run_day(sub, ch, seed=seed, is_cav=np.ones(len(idx), bool))
        rows.append(Row(f"CAVs only, {name} routes (no humans)", r.travel_time.mean()))
    for binary in sumo_binaries:
        with tempfile.TemporaryDirectory() as tmp:
            rou = Path(tmp) / "day.rou.xml"
            rou.write_text(day_routes_xml(scn, choices, is_cav))
            t = cli_travel_times(scn, rou, seed, binary)
        rows.append(Row(f"policy on {binary}", t[is_cav].mean(), t[~is_cav].mean()))
    dev = (unilateral_deviations(scn, choices, is_cav, pol.travel_time, seed, deviations, workers)
           if deviations else None)
    return Headroom(scn.name, scn.n_agents, len(idx), day, rows, dev)


def unilateral_deviations(scn: Scenario, choices: np.ndarray, is_cav: np.ndarray, base_times: np.ndarray,
                          seed: int, n: int, workers: int) -> str:
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
    if not days:
        return f"unilateral deviations, {len(cavs)} CAVs: none has another valid route"
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


def table(h: Headroom, run: str) -> list[str]:
    """The lines `urb-jax headroom` prints: the deviations (if any), a header line, a Markdown table."""
    lines = [h.deviations] if h.deviations else []
    lines += [f"{h.network}: {h.agents} agents, {h.cavs} CAVs, run {run}",
              f"| {'SUMO day':<52} | t_CAV  | t_HDV  |",
              f"|{'-' * 54}|--------|--------|"]
    lines += [f"| {r.name:<52} | {r.t_cav:.4f} | {'' if r.t_hdv is None else f'{r.t_hdv:.4f}':<6} |"
              for r in h.rows]
    return lines
