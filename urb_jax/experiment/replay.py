"""Reuse the human learning phase of an earlier run instead of re-simulating it.

The human phase depends only on the network, routes, env seed, human model and demand — not on
the CAV policy — so baselines on the same network and seed share it. `ReplayHumanPhase` wraps a
day function: its first `days` calls return the SUMO days recorded by the earlier run, after
checking that today's human choices are exactly the recorded ones (so a replay can never
silently differ from a fresh simulation); later calls go to the wrapped day function.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from urb_jax.core.errors import UrbJaxError
from urb_jax.results.records import read_records
from urb_jax.sumo_bridge.types import ARRIVED, DayResult

# exp_config keys that must agree for the human phase to be the same.
MUST_MATCH = ("network", "env_seed", "human_model", "human_alpha", "human_beta", "human_beta_randomness",
              "human_deterministic", "gamma_c", "gamma_u", "epsilon", "delta", "routerl_literal",
              "demand_scale", "demand_mode", "demand_jitter_s", "number_of_paths", "path_gen_beta",
              "num_samples", "num_agents")

_FIELDS = ("action", "travel_time", "route_length", "speed", "duration", "time_loss", "depart_delay",
           "status")


class ReplayHumanPhase:
    def __init__(self, records: pd.DataFrame, agent_id: np.ndarray, days: int, day_fn: Any) -> None:
        self.days = days
        self.day_fn = day_fn
        self.calls = 0
        rec = records[records["day"] <= days]
        have = sorted(rec["day"].unique())
        if have != list(range(1, days + 1)):
            raise UrbJaxError(f"human phase replay needs days 1..{days}; the source run has {len(have)}.")
        self._wide = {f: rec.pivot(index="day", columns="agent", values=f).reindex(columns=agent_id)
                      for f in _FIELDS}
        if self._wide["action"].isna().any().any():
            raise UrbJaxError("human phase replay: the source run's agents differ from this scenario's.")

    def __call__(self, scenario: Any, choices: np.ndarray, *, seed: int,
                 is_cav: np.ndarray | None = None) -> Any:
        self.calls += 1
        if self.calls > self.days:
            return self.day_fn(scenario, choices, seed=seed, is_cav=is_cav)
        d = self.calls
        if is_cav is not None and np.asarray(is_cav).any():
            raise UrbJaxError(f"human phase replay: day {d} has CAVs.")
        row = {f: self._wide[f].loc[d].to_numpy() for f in _FIELDS}
        recorded = row["action"].astype(np.int64)
        if not np.array_equal(np.asarray(choices, np.int64), recorded):
            bad = int((np.asarray(choices) != recorded).sum())
            raise UrbJaxError(f"human phase replay: on day {d}, {bad} human choices differ from the source.")
        arrived = row["status"] == ARRIVED
        f64 = {f: row[f].astype(np.float64) for f in _FIELDS if f not in ("action", "status")}
        return DayResult(
            travel_time=f64["travel_time"], duration=f64["duration"], route_length=f64["route_length"],
            mean_speed=f64["speed"], time_loss=f64["time_loss"], depart_delay=f64["depart_delay"],
            status=row["status"].astype(np.int8), seed=seed,
            stat_mean_speed=_mean(f64["speed"], arrived),
            stat_mean_route_length=_mean(f64["route_length"], arrived),
            stat_mean_duration=_mean(f64["duration"], arrived),
            teleports=0, n_removed=int((~arrived).sum()), sim_end_time=float("nan"), wall_time=0.0,
        )


def _mean(x: np.ndarray, mask: np.ndarray) -> float:
    return float(np.nanmean(x[mask])) if mask.any() else float("nan")


def load_replay(source: Path, config: dict, agent_id: np.ndarray, days: int, day_fn: Any) -> ReplayHumanPhase:
    """A replay of `source`'s first `days` days, after checking it ran the same human phase."""
    cfg_path = source / "exp_config.json"
    if not cfg_path.is_file():
        raise UrbJaxError(
            f"{cfg_path}: not found. Fix: --human-phase-from takes an experiment id in --results-dir."
        )
    src = json.loads(cfg_path.read_text())
    diff = [k for k in MUST_MATCH if src.get(k) != config.get(k)]
    if diff:
        raise UrbJaxError(f"{cfg_path}: its human phase differs from this run's ({', '.join(diff)}).")
    if int(src.get("human_learning_episodes", -1)) < days:
        raise UrbJaxError(f"{cfg_path}: it has fewer than {days} human days.")
    records = read_records(source, columns=["day", "agent", *_FIELDS])
    return ReplayHumanPhase(records, agent_id, days, day_fn)
