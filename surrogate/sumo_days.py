"""SUMO days for calibration and validation, cached on disk (scenario + choices + seed + backend).

Every day runs through `sumo_bridge` (the project's one SUMO runner: URB's insertion, travel
time and stuck semantics, see docs/sumo_bridge.md); this module only adds the on-disk cache.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from urb_jax import sumo_bridge
from urb_jax.city.scenario import Scenario
from urb_jax.core.paths import cache_dir
from urb_jax.sumo_bridge.types import DayResult


def backend_name() -> str:
    """Recorded in cache keys and reports."""
    return "sumo_bridge"


def run_day(scn: Scenario, choices: np.ndarray, *, seed: int = 42) -> DayResult:
    return sumo_bridge.run_day(scn, np.asarray(choices), seed=seed)


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

    if not todo:
        return [r for r in results if r is not None]
    idx = [b for b, _ in todo]
    if workers > 1:
        from urb_jax.sumo_bridge import SumoPool

        with SumoPool(min(workers, len(idx))) as pool:
            days = pool.run_days(scn, choices[idx], [int(seeds[b]) for b in idx])
    else:
        days = [run_day(scn, choices[b], seed=int(seeds[b])) for b in idx]
    for (b, path), day in zip(todo, days, strict=True):
        results[b] = day
        if use_cache:
            _to_npz(path, day)
    return [r for r in results if r is not None]
