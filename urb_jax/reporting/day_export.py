"""A recorded day as a plain SUMO routes file, to replay with `sumo`/`sumo-gui` outside urb-jax.

Researchers want to *look* at what a policy does (sumo-gui), or to check a number on another SUMO
version. The file holds every vehicle with the attributes RouteRL's `vehicle.add` uses, in its
insertion order, so `sumo -n NET -r FILE --seed S --time-to-teleport -1` reproduces the day's
arrivals exactly whenever no vehicle was removed as stuck (tests/test_sumo_bridge.py checks it).
"""

from __future__ import annotations

import os
import re
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import sumo

from urb_jax.city.demand import scale_demand
from urb_jax.city.routes import RouteParams
from urb_jax.city.scenario import Scenario, load_scenario
from urb_jax.core.atomic import write_text
from urb_jax.core.errors import UrbJaxError
from urb_jax.reporting.records import (
    check_run_network,
    check_scheduled_departures,
    networks_dir_of,
    read_records,
    run_config,
)
from urb_jax.sumo_bridge.tripinfo import insertion_order

VEHICLE_ATTRS = ('departLane="first" departPos="base" departSpeed="0" '
                 'arrivalLane="current" arrivalPos="max" arrivalSpeed="current"')


def day_routes_xml(scn: Scenario, choices: np.ndarray, is_cav: np.ndarray) -> str:
    """The routes file text: vTypes Human/AV, the routes driven, one vehicle per agent."""
    choices = np.asarray(choices, dtype=np.int64)
    is_cav = np.asarray(is_cav, dtype=bool)
    order = insertion_order(np.asarray(scn.agent_depart, np.int64), is_cav)
    lines = ["<routes>", '    <vType id="Human"/>', '    <vType id="AV"/>']
    for od, k in sorted({(int(scn.agent_od[i]), int(choices[i])) for i in order}):
        lines.append(f'    <route id="r{od}_{k}" edges="{" ".join(scn.route_edge_ids(od, k))}"/>')
    for i in order:
        lines.append(
            f'    <vehicle id="{scn.agent_id[i]}" type="{"AV" if is_cav[i] else "Human"}" '
            f'route="r{scn.agent_od[i]}_{choices[i]}" depart="{scn.agent_depart[i]}" {VEHICLE_ATTRS}/>'
        )
    lines.append("</routes>\n")
    return "\n".join(lines)


def scenario_of_run(folder: str | os.PathLike, networks_dir: str | None = None) -> Scenario:
    """The Scenario a run used, rebuilt from its exp_config.json (network, env seed, routes, demand)."""
    cfg = run_config(folder)
    nets = networks_dir_of(cfg, networks_dir)
    params = RouteParams(number_of_paths=int(cfg["number_of_paths"]), beta=float(cfg["path_gen_beta"]),
                         num_samples=int(cfg["num_samples"]))
    scn = load_scenario(cfg["network"], networks_dir=nets, env_seed=int(cfg["env_seed"]), route_params=params,
                        drop_unroutable=bool(cfg.get("drop_unroutable", False)))
    scn = scale_demand(scn, float(cfg.get("demand_scale", 1.0)), seed=int(cfg["env_seed"]),
                       mode=cfg.get("demand_mode", "auto"), jitter_s=int(cfg.get("demand_jitter_s", 60)))
    check_run_network(Path(folder) / "exp_config.json", cfg, scn.n_agents, scn.net_file)
    return scn


def recorded_day(folder: str | os.PathLike, scn: Scenario, day: int | None = None
                 ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """(day, choices [N], is_cav [N], travel_time [N]) of a recorded SUMO day, in Scenario order;
    `day=None` is the last one."""
    rec = read_records(folder, columns=["day", "agent", "kind", "action", "travel_time", "sumo"])
    rec = rec[rec["sumo"]]
    days = rec["day"].unique()
    d = int(days.max()) if day is None else int(day)
    if d not in set(days.tolist()):
        raise UrbJaxError(f"{folder}: no SUMO day {d} in the records (SUMO days {int(days.min())}.."
                          f"{int(days.max())}). Fix: pick one of them with --day.")
    one = rec[rec["day"] == d].set_index("agent").reindex(scn.agent_id)
    if one["action"].isna().any():
        raise UrbJaxError(f"{folder}: day {d}'s agents differ from the rebuilt scenario's. "
                          "Fix: pass the --networks-dir the run used.")
    return (d, one["action"].to_numpy(np.int64), (one["kind"] == "CAV").to_numpy(),
            one["travel_time"].to_numpy(np.float64))


def export_day(folder: str | os.PathLike, out: str | os.PathLike, day: int | None = None,
               networks_dir: str | None = None) -> dict[str, Any]:
    """Write a recorded day's routes file atomically; returns what `urb-jax export-day` prints."""
    config = run_config(folder)
    check_scheduled_departures(folder, config, "the exported file would carry the scheduled ones")
    scn = scenario_of_run(folder, networks_dir)
    d, choices, is_cav, times = recorded_day(folder, scn, day)
    out = Path(out)
    write_text(out, day_routes_xml(scn, choices, is_cav))
    seed = int(config["env_seed"])
    return {"day": d, "file": str(out), "net_file": scn.net_file, "vehicles": scn.n_agents,
            "cavs": int(is_cav.sum()), "mean_travel_time_min": round(float(times.mean()), 4),
            "replay": f"sumo -n {scn.net_file} -r {out} --seed {seed} --time-to-teleport -1"}


def sumo_binary() -> str:
    """The `sumo` binary of the installed eclipse-sumo wheel."""
    return os.path.join(sumo.SUMO_HOME, "bin", "sumo")


def cli_travel_times(scn: Scenario, routes_file: str | os.PathLike, seed: int, binary: str | None = None
                     ) -> np.ndarray:
    """[N] URB travel times (min) of a routes file run by a `sumo` binary's CLI, in Scenario order
    (arrival + 2 s - departure, as RouteRL records them)."""
    with tempfile.TemporaryDirectory() as tmp:
        trip = Path(tmp) / "trip.xml"
        subprocess.run([binary or sumo_binary(), "-n", scn.net_file, "-r", str(routes_file),
                        "--seed", str(seed), "--time-to-teleport", "-1", "--no-step-log", "true",
                        "--no-warnings", "true", "--tripinfo-output", str(trip)],
                       check=True, timeout=3600, capture_output=True)
        text = trip.read_text()
    arrival = {m[1]: float(m[2]) for m in re.finditer(r'<tripinfo id="([^"]+)".*?arrival="([^"]+)"', text)}
    return np.array([(arrival[str(a)] + 2 - d) / 60
                     for a, d in zip(scn.agent_id, scn.agent_depart, strict=True)])
