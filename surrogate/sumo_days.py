"""SUMO days for calibration and validation, cached on disk (scenario + choices + seed + backend).

Days run through `sumo_bridge` (libsumo; `SumoPool` for several workers) when it offers
`run_day`, otherwise through the `sumo` command line, which follows URB's day: vehicles inserted
at their departure second with SUMO's default vehicle parameters, `--seed`, step 1 s; travel
time = (arrival - scheduled depart + 2 s)/60 (sumo_bridge's RouteRL offset; insertion delay
included). Vehicles waiting 600 s are removed (`--time-to-teleport 600` with `.remove`) and
charged `simulation_timesteps/60` like RouteRL's stuck rule.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
import time
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from sumo_bridge.types import ARRIVED, REMOVED_STUCK, DayResult
from urb_jax.paths import cache_dir
from urb_jax.scenario import Scenario

STUCK_S = 600


def _sumo_binary() -> str:
    try:
        import sumo  # the eclipse-sumo wheel

        path = Path(sumo.SUMO_HOME) / "bin" / "sumo"
        if path.is_file():
            return str(path)
    except (ImportError, AttributeError):
        pass
    return "sumo"


def _write_routes(scn: Scenario, choices: np.ndarray, path: Path) -> None:
    lines = ['<routes>', '  <vType id="Human"/>', '  <vType id="AV"/>']
    for i in range(scn.n_agents):
        kind = "AV" if scn.agent_kind[i] == "AV" else "Human"
        edges = " ".join(scn.route_edge_ids(int(scn.agent_od[i]), int(choices[i])))
        lines.append(f'  <vehicle id="{int(scn.agent_id[i])}" type="{kind}" '
                     f'depart="{int(scn.agent_depart[i])}"><route edges="{edges}"/></vehicle>')
    lines.append('</routes>')
    path.write_text("\n".join(lines))


def run_day_cli(scn: Scenario, choices: np.ndarray, *, seed: int = 42) -> DayResult:
    """One SUMO day via the `sumo` binary; returns the DayResult contract."""
    t_start = time.perf_counter()
    choices = np.asarray(choices, dtype=np.int64)
    with tempfile.TemporaryDirectory(prefix="urbjax-sumo-") as tmp:
        tmpd = Path(tmp)
        _write_routes(scn, choices, tmpd / "day.rou.xml")
        cmd = [
            _sumo_binary(), "-n", scn.net_file, "-r", str(tmpd / "day.rou.xml"),
            "--seed", str(seed), "--step-length", "1", "--no-step-log", "true",
            "--no-warnings", "true", "--time-to-teleport", str(STUCK_S),
            "--time-to-teleport.remove", "true",
            "--tripinfo-output", str(tmpd / "tripinfo.xml"),
        ]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        if proc.returncode != 0:
            raise RuntimeError(f"sumo failed ({proc.returncode}): {proc.stderr[-2000:]}")
        trips = {t.get("id"): t for t in ET.parse(tmpd / "tripinfo.xml").getroot().iter("tripinfo")}
        log_text = proc.stderr + proc.stdout
    n = scn.n_agents
    out = {k: np.full(n, np.nan) for k in ("tt", "dur", "len", "loss", "dd")}
    status = np.full(n, REMOVED_STUCK, dtype=np.int8)
    end = 0.0
    for i in range(n):
        t = trips.get(str(int(scn.agent_id[i])))
        if t is None or t.get("vaporized"):
            continue
        arrival = float(t.get("arrival"))
        end = max(end, arrival)
        out["tt"][i] = (arrival - float(scn.agent_depart[i]) + 2.0) / 60.0
        out["dur"][i] = float(t.get("duration"))
        out["len"][i] = float(t.get("routeLength"))
        out["loss"][i] = float(t.get("timeLoss"))
        out["dd"][i] = float(t.get("departDelay"))
        status[i] = ARRIVED
    stuck = status == REMOVED_STUCK
    out["tt"][stuck] = scn.simulation_timesteps / 60.0
    ok = ~stuck
    teleports = log_text.count("Teleporting vehicle") if log_text else int(stuck.sum())
    return DayResult(
        travel_time=out["tt"], duration=out["dur"], route_length=out["len"],
        mean_speed=out["len"] / out["dur"], time_loss=out["loss"], depart_delay=out["dd"],
        status=status, seed=seed,
        stat_mean_speed=float(np.nanmean(out["len"][ok] / out["dur"][ok])) if ok.any() else float("nan"),
        stat_mean_route_length=float(np.nanmean(out["len"][ok])) if ok.any() else float("nan"),
        stat_mean_duration=float(np.nanmean(out["dur"][ok])) if ok.any() else float("nan"),
        teleports=teleports, n_removed=int(stuck.sum()), sim_end_time=end,
        wall_time=time.perf_counter() - t_start,
    )


def _bridge_run_day():
    """sumo_bridge.run_day when the bridge provides it (branch `sumo`), else None."""
    try:
        import sumo_bridge
    except ImportError:
        return None
    return getattr(sumo_bridge, "run_day", None)


def backend_name() -> str:
    return "sumo_bridge" if _bridge_run_day() is not None else "cli"


def run_day(scn: Scenario, choices: np.ndarray, *, seed: int = 42) -> DayResult:
    fn = _bridge_run_day()
    if fn is not None:
        return fn(scn, np.asarray(choices), seed=seed)
    return run_day_cli(scn, choices, seed=seed)


def _scenario_key(scn: Scenario) -> str:
    h = hashlib.sha256()
    h.update(Path(scn.net_file).read_bytes())
    for arr in (scn.od_routes, scn.agent_od, scn.agent_depart, scn.agent_id):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()[:16]


def _day_key(scn_key: str, choices: np.ndarray, seed: int) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(choices, dtype=np.int8).tobytes())
    h.update(f"{scn_key};seed={seed};backend={backend_name()}".encode())
    return h.hexdigest()[:24]


def _to_npz(path: Path, day: DayResult) -> None:
    fields = {k: np.asarray(v) for k, v in day.__dict__.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    with os.fdopen(fd, "wb") as fh:
        np.savez(fh, **fields)
    os.replace(tmp, path)


def _from_npz(path: Path) -> DayResult:
    with np.load(path) as d:
        kw = {k: d[k] for k in d.files}
    for k in ("seed", "teleports", "n_removed"):
        kw[k] = int(kw[k])
    for k in ("stat_mean_speed", "stat_mean_route_length", "stat_mean_duration", "sim_end_time", "wall_time"):
        kw[k] = float(kw[k])
    return DayResult(**kw)


def sumo_days(
    scn: Scenario, choices: np.ndarray, seeds: np.ndarray | int = 42, *, workers: int = 2,
    use_cache: bool = True,
) -> list[DayResult]:
    """SUMO days for choices [B, N] (cached per scenario + choices + seed), run `workers` at a time."""
    choices = np.asarray(choices)
    seeds = np.broadcast_to(np.asarray(seeds), (choices.shape[0],))
    root = cache_dir() / "surrogate_days" / f"{scn.name}-{_scenario_key(scn)}"
    results: list[DayResult | None] = [None] * len(choices)
    todo = []
    for b in range(len(choices)):
        path = root / f"{_day_key('', choices[b], int(seeds[b]))}.npz"
        if use_cache and path.is_file():
            try:
                results[b] = _from_npz(path)
                continue
            except Exception:  # damaged cache entry: re-run the day
                pass
        todo.append((b, path))

    def job(item: tuple[int, Path]) -> tuple[int, DayResult]:
        b, path = item
        day = run_day(scn, choices[b], seed=int(seeds[b]))
        if use_cache:
            _to_npz(path, day)
        return b, day

    if todo and backend_name() == "sumo_bridge" and workers > 1:
        from sumo_bridge import SumoPool

        idx = [b for b, _ in todo]
        with SumoPool(min(workers, len(idx))) as pool:
            days = pool.run_days(scn, choices[idx], [int(seeds[b]) for b in idx])
        for (b, path), day in zip(todo, days, strict=True):
            results[b] = day
            if use_cache:
                _to_npz(path, day)
    elif todo and workers <= 1:
        for item in todo:
            b, day = job(item)
            results[b] = day
    elif todo:
        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            for b, day in pool.map(job, todo):
                results[b] = day
    return [r for r in results if r is not None]
