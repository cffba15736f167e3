"""A finished run in URB's results layout, so URB's own tools run on it unmodified.

URB's analysis/metrics.py reads `episodes/ep{d}.csv` (RouteRL's per-agent day log),
`SUMO_output/detailed_sumo_stats_{d}.xml` (tripinfo: the `vType` of the last day makes the CAV and
human groups) and `SUMO_output/sumo_stats_{d}.xml` (statistic output: mean speed, route length,
duration, time loss, depart delay), and slices the days by exp_config.json's
human_learning_episodes, experience_collecting_episodes and training_eps. Its leaderboard generator
reads exp_config.json and metrics/BenchmarkMetrics.csv. This writes all of them from the run's
records (SUMO days only), one file set per recorded day (every `save_every`-th day, as URB's env
config `save_every` would), under OUT/<exp_id>/, as a whole (a temporary folder renamed at the end).

What the records do not hold is written as `nan` (tripinfo waitingTime and speedFactor, the
statistic's waitingTime) and RouteRL's `cost_table` column is left out: no URB metric reads them.
Every agent has a tripinfo line, removed ones too (duration `nan`), so URB's groups are ours.

A hybrid run's t_train, costs of learning and time lost cover its SUMO training days only: the
export's BenchmarkMetrics.csv leaves those URB columns empty and keeps the values as
`<column>_sumo_days` (docs/metrics.md, "Comparable columns"). URB's analysis/metrics.py, run on the
export, recomputes them from the exported days, which are the SUMO days only: they are not URB's
either, whatever the file then says.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from urb_jax.city.routes_io import write_routes_csv
from urb_jax.city.scenario import Scenario
from urb_jax.core.atomic import umask
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.version import __version__
from urb_jax.reporting.comparable import comparable_metrics, is_hybrid
from urb_jax.reporting.day_export import run_config, scenario_of_run
from urb_jax.reporting.metrics import day_stats
from urb_jax.reporting.records import read_records
from urb_jax.reporting.urb_names import names_of, phase_keys

EXPORT_KEY = "exported_from"  # exp_config.json of an export: the run it came from (and --overwrite's proof)
OUR_COPY = "_urb_jax"  # metrics/BenchmarkMetrics_urb_jax.csv: ours, which URB's script leaves alone
EPISODE_COLUMNS = ["travel_time", "id", "kind", "action", "origin", "destination", "start_time",
                   "observation", "reward"]


def export_urb(run: str | os.PathLike, out_root: str | os.PathLike, *, networks_dir: str | None = None,
               overwrite: bool = False, save_every: int = 1) -> dict[str, Any]:
    """Write OUT_ROOT/<exp_id>/ in URB's layout from the finished run RUN; returns what
    `urb-jax export-urb` prints (folder, days, phases, the URB commands to run on it)."""
    run, out_root = Path(run), Path(out_root)
    cfg = run_config(run)
    if cfg.get("status") != "done":
        raise UrbJaxError(f"{run / 'exp_config.json'}: status {cfg.get('status')!r}, not a finished run. "
                          "Fix: export it once it has finished.")
    if save_every < 1:
        raise UrbJaxError(f"--save-every {save_every}: Fix: pass 1 (every day) or more.")
    target = out_root / run.name
    _check_target(target, run, overwrite)
    records = read_records(run)
    scn = scenario_of_run(run, networks_dir)
    phases = phase_keys(records, int(cfg.get("human_days", cfg["human_learning_episodes"])))
    config = {**cfg, **names_of(cfg), **phases, EXPORT_KEY: str(run.resolve()),
              "export_save_every": save_every, "exported_by": f"urb-jax {__version__} export-urb"}
    days = _write_folder(target, run, records, scn, config, save_every)
    return {"folder": str(target), "days": len(days), "first_day": days[0] if days else None,
            "last_day": days[-1] if days else None, **{k: config[k] for k in
            ("algorithm", "alg", "script", "alg_config", "human_learning_episodes", "training_eps",
             "test_eps", "phase_days")},
            "urb_metrics": f"python URB/analysis/metrics.py --id {run.name} --results-folder {out_root}",
            "urb_leaderboard": f"python URB/leaderboard/generate_leaderboard.py --results-dir {out_root}"}


def _check_target(target: Path, run: Path, overwrite: bool) -> None:
    if target.resolve() == run.resolve():
        raise UrbJaxError(f"{target}: is the run itself. Fix: pass another --out (an export is a "
                          "separate folder, e.g. urb_results).")
    if not target.exists():
        return
    if not overwrite:
        raise UrbJaxError(f"{target}: exists. Fix: pass --overwrite to replace that export, or another "
                          "--out.")
    config = target / "exp_config.json"
    if not (config.is_file() and EXPORT_KEY in json.loads(config.read_text() or "{}")):
        raise UrbJaxError(f"{target}: exists and is not a urb-jax export (no '{EXPORT_KEY}' in its "
                          "exp_config.json), so --overwrite will not remove it. Fix: pass another --out.")


def _write_folder(target: Path, run: Path, records: pd.DataFrame, scn: Scenario, config: dict[str, Any],
                  save_every: int) -> list[int]:
    """Everything into a temporary folder beside `target`, renamed onto it at the end."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.export-", dir=target.parent))
    try:
        os.chmod(tmp, 0o777 & ~umask())
        days = _write_days(tmp, records, scn, save_every)
        _copy_outputs(run, tmp, is_hybrid(config))
        pd.DataFrame({"id": scn.agent_id, "origin": scn.agent_origin, "destination": scn.agent_destination,
                      "start_time": scn.agent_depart, "kind": list(scn.agent_kind)}).to_csv(
            tmp / "agents.csv", index=False)
        write_routes_csv(scn, tmp / "routes.csv")
        (tmp / "exp_config.json").write_text(json.dumps(config, indent=2, default=str))
        if target.exists():  # an earlier export (checked): out of the way first, removed after
            old = target.parent / f".{target.name}.old-{os.getpid()}"
            target.rename(old)
            tmp.rename(target)
            shutil.rmtree(old)
        else:
            tmp.rename(target)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return days


def _copy_outputs(run: Path, folder: Path, hybrid: bool) -> None:
    """Our metric files (also as *_urb_jax.csv, which URB's script leaves alone) and plots; a
    `hybrid` run's BenchmarkMetrics with URB's SUMO-days-only columns empty, their values under their
    own names (`comparable`: a run written before the split is split here)."""
    (folder / "metrics").mkdir()
    for name in ("BenchmarkMetrics", "VectorMetrics"):
        src = run / "metrics" / f"{name}.csv"
        if src.is_file():
            shutil.copyfile(src, folder / "metrics" / f"{name}.csv")
            if hybrid and name == "BenchmarkMetrics":
                row = comparable_metrics(pd.read_csv(src).iloc[0].to_dict())
                pd.DataFrame([row]).to_csv(folder / "metrics" / f"{name}.csv", index=False)
            shutil.copyfile(folder / "metrics" / f"{name}.csv", folder / "metrics" / f"{name}{OUR_COPY}.csv")
    if (run / "plots").is_dir():
        shutil.copytree(run / "plots", folder / "plots")


def _write_days(folder: Path, records: pd.DataFrame, scn: Scenario, save_every: int) -> list[int]:
    """episodes/ep{d}.csv and SUMO_output/{detailed_,}sumo_stats_{d}.xml for every saved day."""
    (folder / "episodes").mkdir()
    (folder / "SUMO_output").mkdir()
    agents = set(scn.agent_id.tolist())
    if set(records["agent"].unique().tolist()) != agents:
        raise UrbJaxError(f"the records' agents differ from the rebuilt scenario's ({scn.name}). Fix: pass "
                          "the --networks-dir the run used.")
    stats = day_stats(records)
    days = [int(d) for d in sorted(records["day"].unique()) if int(d) % save_every == 0]
    for d, day in records[records["day"].isin(days)].groupby("day", sort=True):
        day = day.sort_values("agent")
        (folder / "episodes" / f"ep{d}.csv").write_text(_episode(day, scn).to_csv(index=False))
        (folder / "SUMO_output" / f"detailed_sumo_stats_{d}.xml").write_text(_tripinfo(day))
        (folder / "SUMO_output" / f"sumo_stats_{d}.xml").write_text(_statistics(day, stats.loc[d]))
    return days


def _episode(day: pd.DataFrame, scn: Scenario) -> pd.DataFrame:
    """RouteRL's episode log of one day (URB_REFERENCE §2): one row per agent."""
    od = day["od"].to_numpy()
    obs = [",".join(f"{x:g}" for x in o) if o is not None else "N/A" for o in day["observation"]]
    return pd.DataFrame({
        "travel_time": day["travel_time"].to_numpy(np.float64), "id": day["agent"].to_numpy(),
        "kind": np.where(day["kind"] == "CAV", "AV", "Human"), "action": day["action"].to_numpy(),
        "origin": scn.od_origin[od], "destination": scn.od_destination[od],
        "start_time": day["start_time"].to_numpy(), "observation": obs,
        "reward": day["reward"].to_numpy(np.float64),
    }, columns=EPISODE_COLUMNS)


def _num(x: float) -> str:
    return "nan" if x != x else repr(float(x))


def _tripinfo(day: pd.DataFrame) -> str:
    """SUMO's tripinfo output of one day: the attributes URB's loader requires, from the records."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<!-- written by urb-jax export-urb from a run's "
             "records; waitingTime and speedFactor are not recorded -->", "<tripinfos>"]
    for r in day.itertuples(index=False):
        depart = r.start_time + float(r.depart_delay)
        lines.append(
            f'    <tripinfo id="{r.agent}" depart="{_num(depart)}" departDelay="{_num(r.depart_delay)}" '
            f'arrival="{_num(depart + float(r.duration))}" duration="{_num(r.duration)}" '
            f'routeLength="{_num(r.route_length)}" waitingTime="nan" timeLoss="{_num(r.time_loss)}" '
            f'speedFactor="nan" vType="{"AV" if r.kind == "CAV" else "Human"}"/>')
    lines.append("</tripinfos>\n")
    return "\n".join(lines)


def _statistics(day: pd.DataFrame, stats: pd.Series) -> str:
    """SUMO's statistic output of one day: means over arrived trips (`metrics.day_stats`, the
    definition our metrics use), no teleports (SUMO teleporting is off, as in URB)."""
    arrived = day[day["status"] == 0]
    n = len(day)
    return "\n".join([
        '<?xml version="1.0" encoding="UTF-8"?>',
        "<!-- written by urb-jax export-urb from a run's records -->",
        "<statistics>",
        f'    <vehicles loaded="{n}" inserted="{n}" running="0" waiting="0"/>',
        '    <teleports total="0" jam="0" yield="0" wrongLane="0"/>',
        f'    <vehicleTripStatistics count="{len(arrived)}" routeLength="{_num(stats["route_length"])}" '
        f'speed="{_num(stats["speed"])}" duration="{_num(stats["duration"])}" waitingTime="nan" '
        f'timeLoss="{_num(stats["time_loss"])}" departDelay="{_num(stats["depart_delay"])}" '
        f'totalTravelTime="{_num(float(arrived["duration"].sum()))}" '
        f'totalDepartDelay="{_num(float(arrived["depart_delay"].sum()))}"/>',
        "</statistics>\n",
    ])
