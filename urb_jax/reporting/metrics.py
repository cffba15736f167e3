"""URB KPIs from a per-day records table (URB_REFERENCE §10), with the paper's definitions.

Input: one row per (day, agent) with columns day (1-based), agent, kind ('HDV'/'CAV' that day),
action, travel_time (min), route_length (m), speed (m/s, NaN if removed), duration (s),
time_loss (s), depart_delay (s), status (0 = arrived). Slices: pre = days in (H-50, H] (every
day, not every 5th), train = (H, H+T], test = > H+T, post = > H. Groups are the kinds on the
last day. Differences from URB's code (the paper wins; see docs/metrics.md):

* cost of learning c_X = mean over agents i in X and train days d of (t_i,d - mean_pre t_i)
  (URB code: mean over agents of max - min over train days);
* every day of a slice is counted; speeds and mileages are per-day means over arrived trips
  (SUMO's statistic output definition) computed from the per-agent rows;
* delta_V / delta_L (paper) are added as columns;
* the `*_duration` columns repeat the travel-time means with SUMO's own trip duration, the measure
  of the URB metric code that the published tables fit (see `DURATION_COLUMNS`).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from urb_jax.city.demand import ABSENT

PRE_WINDOW = 50

BENCHMARK_COLUMNS = [
    "t_pre", "t_test", "t_train", "t_CAV", "t_HDV_pre", "t_HDV_test",
    "CAV_advantage", "Effect_of_change", "Effect_of_remaining",
    "avg_speed_pre", "avg_speed_test", "avg_mileage_pre", "avg_mileage_test",
    "winrate", "cost_of_learning", "cost_of_learning_humans", "cost_of_learning_CAVs",
    "avg_time_lost", "avg_human_time_lost", "avg_CAV_time_lost", "diff_sumo_routerl",
    "delta_V", "delta_L", "instability_humans_test", "instability_CAVs_test",
    "t_pre_duration", "t_test_duration", "t_CAV_duration", "t_HDV_pre_duration", "t_HDV_test_duration",
]
# The published tables (URB README / paper: t_pre 3.15, 2.80, 4.21; AON t_CAV 3.01, 2.76, 4.37)
# fit an earlier analysis/metrics.py, which averaged SUMO's tripinfo `duration` (arrival - actual
# departure, s): per agent over the slice's days, then over agents, removed vehicles skipped
# (docs/metrics.md has the numbers). Today's URB code (and `t_pre` etc. above) uses RouteRL's
# travel_time, which adds the insertion delay and RouteRL's 2 s recording lag, 2-3.5 s per trip.
# Compare with published numbers in this measure.
DURATION_COLUMNS = {"t_pre_duration": ("pre", "every"), "t_test_duration": ("test", "every"),
                    "t_CAV_duration": ("test", "cav"), "t_HDV_pre_duration": ("pre", "hdv"),
                    "t_HDV_test_duration": ("test", "hdv")}


def _nan() -> float:
    return float("nan")


def _ratio(a: float, b: float) -> float:
    return a / b if (not math.isnan(a) and not math.isnan(b) and b != 0) else _nan()


def _wide(records: pd.DataFrame, column: str) -> pd.DataFrame:
    return records.pivot(index="day", columns="agent", values=column).sort_index()


def _slice_mean(wide: pd.DataFrame, days: np.ndarray, agents: np.ndarray) -> float:
    """Mean over days of the mean over `agents` (URB's mean over a set in a slice)."""
    if len(days) == 0 or len(agents) == 0:
        return _nan()
    return float(wide.loc[days, agents].mean(axis=1).mean())


def _agent_mean(wide: pd.DataFrame, days: np.ndarray, agents: np.ndarray) -> float:
    """Mean over `agents` of each agent's mean over `days`, NaN cells (removed trips) skipped:
    the earlier URB metric code's `df[cols].mean(axis=0).mean()`."""
    if len(days) == 0 or len(agents) == 0:
        return _nan()
    return float(wide.loc[days, agents].mean(axis=0).mean())


def slices(days: np.ndarray, human_days: int, training_days: int) -> dict[str, np.ndarray]:
    H, T = human_days, training_days
    return {
        "pre": days[(days > H - PRE_WINDOW) & (days <= H)],
        "train": days[(days > H) & (days <= H + T)],
        "test": days[days > H + T],
        "post": days[days > H],
    }


def groups(records: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(HDV agents, CAV agents) by their kind on the last day."""
    last = records[records["day"] == records["day"].max()]
    cav = np.sort(last.loc[last["kind"] == "CAV", "agent"].to_numpy())
    hdv = np.sort(last.loc[last["kind"] != "CAV", "agent"].to_numpy())
    return hdv, cav


def day_stats(records: pd.DataFrame) -> pd.DataFrame:
    """Per-day SUMO statistics over arrived trips: speed m/s, route length m, duration s,
    time loss s, depart delay s (means, as SUMO's statistic output)."""
    arrived = records[records["status"] == 0]
    g = arrived.groupby("day")
    return pd.DataFrame({
        "speed": g["speed"].mean(),
        "route_length": g["route_length"].mean(),
        "duration": g["duration"].mean(),
        "time_loss": g["time_loss"].mean(),
        "depart_delay": g["depart_delay"].mean(),
    }).reindex(np.sort(records["day"].unique()))


def compute_metrics(records: pd.DataFrame, human_days: int, training_days: int) -> dict[str, float]:
    """BenchmarkMetrics (URB column names, minutes / km/h / km) from a records table."""
    tt = _wide(records, "travel_time")
    days = tt.index.to_numpy()
    s = slices(days, human_days, training_days)
    hdv, cav = groups(records)
    every = tt.columns.to_numpy()
    m: dict[str, float] = {}
    m["t_pre"] = _slice_mean(tt, s["pre"], every)
    m["t_train"] = _slice_mean(tt, s["train"], every)
    m["t_test"] = _slice_mean(tt, s["test"], every)
    m["t_CAV"] = _slice_mean(tt, s["test"], cav)
    m["t_HDV_pre"] = _slice_mean(tt, s["pre"], hdv)
    m["t_HDV_test"] = _slice_mean(tt, s["test"], hdv)
    m["CAV_advantage"] = _ratio(m["t_HDV_test"], m["t_CAV"])
    m["Effect_of_change"] = _ratio(m["t_HDV_pre"], m["t_CAV"])
    m["Effect_of_remaining"] = _ratio(m["t_HDV_pre"], m["t_HDV_test"])

    ds = day_stats(records)

    def stat(col: str, sl: str, scale: float) -> float:
        d = s[sl]
        return float(ds.loc[d, col].mean() * scale) if len(d) else _nan()

    m["avg_speed_pre"] = stat("speed", "pre", 3.6)
    m["avg_speed_test"] = stat("speed", "test", 3.6)
    m["avg_mileage_pre"] = stat("route_length", "pre", 1e-3)
    m["avg_mileage_test"] = stat("route_length", "test", 1e-3)
    undefined = math.isnan(m["t_CAV"]) or math.isnan(m["t_pre"])
    m["winrate"] = _nan() if undefined else float(m["t_CAV"] < m["t_pre"])

    # Cost of learning (paper): mean excess over each agent's pre-CAV mean during training.
    pre_mean = tt.loc[s["pre"]].mean(axis=0) if len(s["pre"]) else pd.Series(np.nan, index=every)
    excess_train = tt.loc[s["train"]] - pre_mean
    lost_post = tt.loc[s["post"]] - pre_mean

    def cell_mean(frame: pd.DataFrame, agents: np.ndarray) -> float:
        if frame.shape[0] == 0 or len(agents) == 0:
            return _nan()
        return float(np.nanmean(frame[agents].to_numpy()))

    m["cost_of_learning"] = cell_mean(excess_train, every)
    m["cost_of_learning_humans"] = cell_mean(excess_train, hdv)
    m["cost_of_learning_CAVs"] = cell_mean(excess_train, cav)
    # URB: avg_time_lost = mean over agents of the per-agent SUM over post days; HDV/CAV: cell means.
    m["avg_time_lost"] = float(lost_post.sum(axis=0).mean()) if lost_post.shape[0] else _nan()
    m["avg_human_time_lost"] = cell_mean(lost_post, hdv)
    m["avg_CAV_time_lost"] = cell_mean(lost_post, cav)
    m["diff_sumo_routerl"] = (stat("duration", "test", 1 / 60) - m["t_test"]) if len(s["test"]) else _nan()
    m["delta_V"] = m["avg_speed_test"] - m["avg_speed_pre"]
    m["delta_L"] = m["avg_mileage_test"] - m["avg_mileage_pre"]
    dur = _wide(records, "duration") / 60.0
    who = {"every": every, "cav": cav, "hdv": hdv}
    for col, (sl, group) in DURATION_COLUMNS.items():
        m[col] = _agent_mean(dur, s[sl], who[group])
    vec = vector_metrics(records, human_days, training_days)
    test_vec = vec[vec["episode"].isin(s["test"])]
    m["instability_humans_test"] = float(test_vec["instability_humans"].mean()) if len(hdv) else _nan()
    m["instability_CAVs_test"] = float(test_vec["instability_CAVs"].mean()) if len(cav) else _nan()
    return {k: m[k] for k in BENCHMARK_COLUMNS}


def fleet_columns(name: str, hybrid: bool = False) -> list[str]:
    """BenchmarkMetrics.csv's columns of fleet `name` (a run with fleets appends them after URB's):
    its drivers' pre-CAV time, t_CAV, win rate and cost of learning (a hybrid run's under the
    `_sumo_days` name, as the all-CAV column: reporting.comparable)."""
    cost = f"cost_of_learning_CAVs_{name}" + ("_sumo_days" if hybrid else "")
    return [f"t_pre_{name}", f"t_CAV_{name}", f"winrate_{name}", cost]


def fleet_metrics(records: pd.DataFrame, human_days: int, training_days: int,
                  fleets: dict[str, list[int]], hybrid: bool = False) -> dict[str, float]:
    """Each fleet's t_pre (the mean over the pre-CAV window of the mean over the fleet's drivers,
    while they were humans), t_CAV (mean over test days of the mean over its CAVs), win rate (its
    t_CAV below its own t_pre: fleets are small samples of the CAVs, whose trips differ in length,
    so the all-agent t_pre would judge the draw, not the learning) and cost of learning (mean excess
    of its CAVs over their pre-CAV means during training), URB's all-CAV columns over the fleet's
    agents (`fleets`: name -> agent ids), in `fleet_columns` order."""
    tt = _wide(records, "travel_time")
    s = slices(tt.index.to_numpy(), human_days, training_days)
    pre_mean = tt.loc[s["pre"]].mean(axis=0) if len(s["pre"]) else pd.Series(np.nan, index=tt.columns)
    excess_train = tt.loc[s["train"]] - pre_mean
    out: dict[str, float] = {}
    for name, agents in fleets.items():
        members = np.sort(np.asarray(agents, dtype=tt.columns.dtype))
        t_pre = _slice_mean(tt, s["pre"], members)
        t_cav = _slice_mean(tt, s["test"], members)
        undefined = math.isnan(t_cav) or math.isnan(t_pre)
        cost = (float(np.nanmean(excess_train[members].to_numpy()))
                if excess_train.shape[0] and len(members) else _nan())
        winrate = _nan() if undefined else float(t_cav < t_pre)
        out |= dict(zip(fleet_columns(name, hybrid), (t_pre, t_cav, winrate, cost), strict=True))
    return out


def vector_metrics(records: pd.DataFrame, human_days: int, training_days: int) -> pd.DataFrame:
    """One row per post-mutation day: action changes vs the previous day per group (URB's
    instability, every day instead of every 5th), SUMO mean timeLoss + departDelay (s), and the
    summed excess over each agent's pre mean (min)."""
    act = _wide(records, "action")
    tt = _wide(records, "travel_time")
    days = act.index.to_numpy()
    s = slices(days, human_days, training_days)
    hdv, cav = groups(records)
    if (act == ABSENT).to_numpy().any():  # stayed home (day_participation): no route, no change
        act = act.where(act != ABSENT)
    changed = act.ne(act.shift(1)) & act.shift(1).notna() & act.notna()
    pre_mean = tt.loc[s["pre"]].mean(axis=0) if len(s["pre"]) else pd.Series(np.nan, index=tt.columns)
    ds = day_stats(records)
    post = s["post"]
    return pd.DataFrame({
        "episode": post.astype(int),
        "instability_humans": changed.loc[post, hdv].sum(axis=1).to_numpy().astype(int),
        "instability_CAVs": changed.loc[post, cav].sum(axis=1).to_numpy().astype(int),
        "avg_time_lost": (ds.loc[post, "time_loss"] + ds.loc[post, "depart_delay"]).to_numpy(),
        "time_excess": (tt.loc[post] - pre_mean).sum(axis=1).to_numpy(),
    })


# ---- equity: what the CAVs did to each human (not a URB column; metrics/SocialMetrics.csv)

SOCIAL_COLUMNS = ["humans_worse_off_share", "human_change_mean", "human_loss_max", "human_loss_gini"]
# |change| at or below this (min; 6 ms) is a tie: the float32 records' rounding, never a real change.
# SUMO steps whole seconds, so a real change of a human's mean is at least 1 s over the windows' days
# (1 s / (50 x 100) = 0.2 ms for URB's windows, a real but meaningless change); rounding of float32
# minutes stays below 1e-5 min for trips under an hour, and made identical days differ by that.
TIE_MIN = 1e-4


def social_metrics(records: pd.DataFrame, human_days: int, training_days: int) -> dict[str, float]:
    """How the CAVs' arrival spread over the humans, from SUMO days only. Each human's change is
    their mean travel time over the test days minus their own mean over the pre-CAV window (minutes;
    removed trips skipped; |change| <= TIE_MIN is a tie, 0): the share of humans made worse off
    (change > 0), the mean change, the largest individual loss, and the Gini coefficient of the
    losses (changes below 0 count as no loss; 0: nobody lost or all lost alike, towards 1: one human
    bears all the loss)."""
    change = human_changes(records, human_days, training_days)
    if change.empty:
        return dict.fromkeys(SOCIAL_COLUMNS, _nan())
    tied = change.where(change.abs() > TIE_MIN, 0.0)
    return {"humans_worse_off_share": float((tied > 0).mean()), "human_change_mean": float(change.mean()),
            "human_loss_max": float(tied.max()), "human_loss_gini": gini(tied.clip(lower=0).to_numpy())}


def human_changes(records: pd.DataFrame, human_days: int, training_days: int) -> pd.Series:
    """[humans] each human's mean travel time over the test days minus their own mean over the
    pre-CAV window (min; humans with no arrived trip in either left out); empty without humans,
    pre-CAV or test days."""
    tt = _wide(records, "travel_time")
    s = slices(tt.index.to_numpy(), human_days, training_days)
    hdv, _ = groups(records)
    if len(s["pre"]) == 0 or len(s["test"]) == 0 or len(hdv) == 0:
        return pd.Series(dtype=np.float64)
    return (tt.loc[s["test"], hdv].mean(axis=0) - tt.loc[s["pre"], hdv].mean(axis=0)).dropna()


def gini(x: np.ndarray) -> float:
    """The Gini coefficient of non-negative values, sum_ij |x_i - x_j| / (2 n^2 mean), from the sorted
    values; 0 when they are all 0."""
    v = np.sort(np.asarray(x, dtype=np.float64))
    n, total = len(v), float(v.sum())
    if n == 0 or total == 0.0:
        return 0.0
    return float(2.0 * np.sum(np.arange(1, n + 1) * v) / (n * total) - (n + 1) / n)


# ---- emissions (runs with SUMO's emission device: records columns co2_g, fuel_mg)

EMISSION_DAY_COLUMNS = ["episode", "co2_g", "co2_human_g", "co2_cav_g", "fuel_mg", "fuel_human_mg",
                        "fuel_cav_mg"]
EMISSION_SOCIAL_COLUMNS = ["co2_test_g", "co2_test_human_g", "co2_test_cav_g", "fuel_test_mg",
                           "fuel_test_human_mg", "fuel_test_cav_mg", "co2_pre_day_g", "co2_test_day_g"]


def has_emissions(records: pd.DataFrame) -> bool:
    """Whether the run recorded SUMO's emissions (SumoConfig.emissions)."""
    return "co2_g" in records.columns and "fuel_mg" in records.columns


def emission_days(records: pd.DataFrame) -> pd.DataFrame:
    """One row per recorded day (metrics/EmissionMetrics.csv): the day's totals over every vehicle,
    the humans and the CAV fleet by their kind that day; CO2 in g, fuel in mg (SUMO's unit). A
    vehicle SUMO never inserted has no value and adds nothing; a group without vehicles totals 0."""
    rec = records.assign(co2_g=records["co2_g"].astype(np.float64),
                         fuel_mg=records["fuel_mg"].astype(np.float64))
    days = np.sort(rec["day"].unique())

    def total(column: str, kind: str | None) -> np.ndarray:  # [days]
        part = rec if kind is None else rec[rec["kind"] == kind]
        return part.groupby("day")[column].sum().reindex(days, fill_value=0.0).to_numpy()

    return pd.DataFrame({
        "episode": days.astype(int),
        "co2_g": total("co2_g", None), "co2_human_g": total("co2_g", "HDV"),
        "co2_cav_g": total("co2_g", "CAV"),
        "fuel_mg": total("fuel_mg", None), "fuel_human_mg": total("fuel_mg", "HDV"),
        "fuel_cav_mg": total("fuel_mg", "CAV"),
    })[EMISSION_DAY_COLUMNS]


def emission_metrics(records: pd.DataFrame, human_days: int, training_days: int) -> dict[str, float]:
    """The test phase's emission totals (sums over the test days of `emission_days`) by group, and the
    mean daily CO2 of every vehicle over the pre-CAV window and over the test days (the CAVs' effect
    on the day's emissions); NaN where the slice has no day."""
    per_day = emission_days(records).set_index("episode")
    s = slices(per_day.index.to_numpy(), human_days, training_days)
    test, pre = per_day.loc[s["test"]], per_day.loc[s["pre"]]

    def test_total(column: str) -> float:
        return float(test[column].sum()) if len(test) else _nan()

    return {
        "co2_test_g": test_total("co2_g"), "co2_test_human_g": test_total("co2_human_g"),
        "co2_test_cav_g": test_total("co2_cav_g"), "fuel_test_mg": test_total("fuel_mg"),
        "fuel_test_human_mg": test_total("fuel_human_mg"), "fuel_test_cav_mg": test_total("fuel_cav_mg"),
        "co2_pre_day_g": float(pre["co2_g"].mean()) if len(pre) else _nan(),
        "co2_test_day_g": float(test["co2_g"].mean()) if len(test) else _nan(),
    }
