"""results/<exp_id>/: exp_config.json, per-day records, metrics and plots.

Records are written incrementally as Parquet parts under `records.parts/` (each part written to a
temporary name and renamed, so a reader never sees half a part); `close()` compacts them into
one `records.parquet` (again via rename); the parts are removed only once the run is marked done.
A crashed run leaves readable complete parts; `read_records` reads either form.

Every part carries the sha256 of its bytes (`part-NNNNN.sha256`, written atomically before the part
is renamed into place), and the merged file its own (`records.parquet.sha256`). A resume checks
every part it keeps when it starts (`damaged_parts`), the merge checks them again before it writes,
and the metric files are computed only from a merged file that matches its digest: damaged records
are named and refused, never turned into metrics.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from urb_jax.core.atomic import atomic_path, checked_json, file_sha256, write_bytes, write_json_digested
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.paths import absolute_dir
from urb_jax.reporting.comparable import comparable_metrics, is_hybrid
from urb_jax.reporting.metrics import (
    EMISSION_SOCIAL_COLUMNS,
    SOCIAL_COLUMNS,
    compute_metrics,
    emission_days,
    emission_metrics,
    fleet_metrics,
    has_emissions,
    social_metrics,
    vector_metrics,
)
from urb_jax.sumo_bridge.types import DayResult


@dataclass(frozen=True)
class DayRecord:
    """One simulated day, in the Scenario's agent order."""

    day: int  # 1-based, URB's episode number
    phase: str
    choices: np.ndarray  # [N]
    is_cav: np.ndarray  # [N] bool
    result: DayResult
    rewards: np.ndarray  # [N] CAV reward for CAVs, -travel time for humans
    observations: np.ndarray | None  # [N, D], NaN rows for humans; None before mutation
    sumo: bool = True


RECORDS_FILE = "records.parquet"
PARTS_DIR = "records.parts"
DIGEST_SUFFIX = ".sha256"  # beside a part (part-NNNNN.sha256) and the merged file


class DamagedRecordsError(UrbJaxError):
    """Record files that do not match their digests (or are missing)."""


def part_path(parts: Path, i: int) -> Path:
    return parts / f"part-{i:05d}.parquet"


def digest_path(path: Path) -> Path:
    """Where the sha256 of a records file is kept: part-NNNNN.sha256, records.parquet.sha256."""
    return path.with_suffix(DIGEST_SUFFIX) if path.name.startswith("part-") else \
        path.with_name(path.name + DIGEST_SUFFIX)


def write_with_digest(path: Path, write: Any) -> None:
    """`write(tmp)` to a temporary name, its sha256 written (atomically) beside `path`, then the file
    renamed into place: a visible records file always has its digest."""
    with atomic_path(path) as tmp:
        write(tmp)
        write_bytes(digest_path(path), (file_sha256(tmp) + "\n").encode())


def damage_of(path: Path) -> str | None:
    """Why the records file `path` cannot be trusted (missing, no digest, another sha256), or None.
    A file written before digests (no digest file beside a merged records.parquet) is trusted."""
    if not path.is_file():
        return "missing"
    dp = digest_path(path)
    if not dp.is_file():
        return "its digest file is missing" if path.name.startswith("part-") else None
    want = dp.read_text().strip()
    return None if file_sha256(path) == want else "does not match its digest"


def adopt_undigested_parts(folder: str | os.PathLike) -> int:
    """A run started before record digests (parts, none with a digest): write each part's digest now,
    trusting the parts as a resume did then, so that the checks from here on cover them. Returns how
    many were adopted (0: the run has digests, or no parts)."""
    parts = Path(folder) / PARTS_DIR
    found = sorted(parts.glob("part-*.parquet"))
    if not found or any(parts.glob(f"part-*{DIGEST_SUFFIX}")):
        return 0
    for p in found:
        write_bytes(digest_path(p), (file_sha256(p) + "\n").encode())
    return len(found)


def damaged_parts(folder: str | os.PathLike, n_parts: int) -> list[tuple[int, str]]:
    """(index, 'path: why') of each of the first `n_parts` record parts of `folder` that is missing
    or does not match its digest, in order."""
    parts = Path(folder) / PARTS_DIR
    bad = []
    for i in range(n_parts):
        p = part_path(parts, i)
        if (why := damage_of(p)) is not None:
            bad.append((i, f"{p}: {why}"))
    return bad


def damaged_records(folder: str | os.PathLike) -> list[str]:
    """'path: why' of each records file of `folder` that does not match its digest: records.parquet
    where the run merged its records, else each part (parts of a run from before digests, none with
    one: trusted, as a resume adopts them)."""
    folder = Path(folder)
    if (folder / RECORDS_FILE).is_file():
        why = damage_of(folder / RECORDS_FILE)
        return [] if why is None else [f"{folder / RECORDS_FILE}: {why}"]
    parts = folder / PARTS_DIR
    if not any(parts.glob(f"part-*{DIGEST_SUFFIX}")):
        return []
    return [f"{p}: {why}" for p in sorted(parts.glob("part-*.parquet")) if (why := damage_of(p)) is not None]


SCHEMA = pa.schema([
    ("day", pa.int32()), ("phase", pa.string()), ("agent", pa.int64()), ("kind", pa.string()),
    ("od", pa.int32()), ("start_time", pa.int32()), ("action", pa.int8()),
    ("travel_time", pa.float32()), ("route_length", pa.float32()), ("speed", pa.float32()),
    ("duration", pa.float32()), ("time_loss", pa.float32()), ("depart_delay", pa.float32()),
    ("status", pa.int8()), ("reward", pa.float32()), ("observation", pa.list_(pa.float32())),
    ("sumo", pa.bool_()),
])
# SumoConfig.emissions runs only: appended after URB's columns, so a run without keeps its bytes.
EMISSION_COLUMNS = ("co2_g", "fuel_mg")  # DayResult fields of the same names: g, mg (SUMO's unit)
EMISSION_SCHEMA = pa.schema([*SCHEMA, *(pa.field(c, pa.float32()) for c in EMISSION_COLUMNS)])


class RecordsWriter:
    """Collects DayRecords and flushes Parquet parts every `flush_every` days. `emissions`: the run's
    SUMO days carry emissions (SumoConfig.emissions); the records get `EMISSION_COLUMNS` too."""

    def __init__(self, folder: str | os.PathLike, agent_id: np.ndarray, agent_od: np.ndarray,
                 agent_depart: np.ndarray, flush_every: int = 25, emissions: bool = False) -> None:
        self.folder = Path(folder)
        self.emissions = emissions
        self.schema = EMISSION_SCHEMA if emissions else SCHEMA
        self.parts = self.folder / PARTS_DIR
        self.parts.mkdir(parents=True, exist_ok=True)
        self.agent_id = np.asarray(agent_id, dtype=np.int64)
        self.agent_od = np.asarray(agent_od, dtype=np.int32)
        self.agent_depart = np.asarray(agent_depart, dtype=np.int32)
        self.flush_every = flush_every
        self._pending: list[pa.RecordBatch] = []
        self._n_parts = 0

    @property
    def n_parts(self) -> int:
        """Parts written so far (a round checkpoint records it; `truncate` goes back to it)."""
        return self._n_parts

    def truncate(self, n_parts: int) -> None:
        """Drop the parts written after the first `n_parts`: a resumed run writes those days again.
        Until a run is done its parts are the records; a merged file from a later instant (a kill
        after `close`) is derived from them and goes too, to be merged again at the end."""
        for p in [*self.parts.glob("part-*.parquet"), *self.parts.glob(f"part-*{DIGEST_SUFFIX}")]:
            if int(p.name.split("-")[1].split(".")[0]) >= n_parts:
                p.unlink()
        (self.folder / RECORDS_FILE).unlink(missing_ok=True)
        digest_path(self.folder / RECORDS_FILE).unlink(missing_ok=True)
        self._n_parts = n_parts

    def __call__(self, rec: DayRecord) -> None:
        self.add(rec)

    def add(self, rec: DayRecord) -> None:
        n = self.agent_id.shape[0]
        r = rec.result
        if rec.observations is None:
            obs = pa.nulls(n, pa.list_(pa.float32()))
        else:
            o = np.asarray(rec.observations, dtype=np.float32)
            flat = pa.array(o.reshape(-1), pa.float32())
            offsets = pa.array(np.arange(0, o.size + 1, o.shape[1], dtype=np.int32))
            mask = pa.array(~rec.is_cav)
            obs = pa.ListArray.from_arrays(offsets, flat, mask=mask)
        cols = [
            pa.array(np.full(n, rec.day, np.int32)), pa.array([rec.phase] * n, pa.string()),
            pa.array(self.agent_id), pa.array(np.where(rec.is_cav, "CAV", "HDV")),
            pa.array(self.agent_od), pa.array(self.agent_depart),
            pa.array(np.asarray(rec.choices, np.int8)),
            *(pa.array(np.asarray(getattr(r, f), np.float32)) for f in
              ("travel_time", "route_length", "mean_speed", "duration", "time_loss", "depart_delay")),
            pa.array(np.asarray(r.status, np.int8)), pa.array(np.asarray(rec.rewards, np.float32)),
            obs, pa.array(np.full(n, rec.sumo)),
            *(self._emission_columns(rec) if self.emissions else ()),
        ]
        self._pending.append(pa.RecordBatch.from_arrays(cols, schema=self.schema))
        if len(self._pending) >= self.flush_every:
            self.flush()

    @staticmethod
    def _emission_columns(rec: DayRecord) -> list[pa.Array]:
        """co2_g, fuel_mg [N]; a day without them in a run with them is a bug, not a NaN column."""
        r = rec.result
        if r.co2_g is None or r.fuel_mg is None:
            raise ValueError(f"day {rec.day} has no emissions, but the run records them")
        return [pa.array(np.asarray(r.co2_g, np.float32)), pa.array(np.asarray(r.fuel_mg, np.float32))]

    def flush(self) -> None:
        if not self._pending:
            return
        table = pa.Table.from_batches(self._pending, schema=self.schema)
        write_with_digest(part_path(self.parts, self._n_parts),
                          lambda tmp: pq.write_table(table, tmp, compression="zstd"))
        self._n_parts += 1
        self._pending = []

    def close(self) -> Path:
        """Flush and compact every part into one records.parquet (atomic, fsynced). The parts stay
        until the run is marked done (`remove_parts`), so a kill at any instant of the finish
        leaves either the parts or the parts and a complete merged file. Every part is checked against
        its digest first: a damaged or missing one is a DamagedRecordsError naming it, and nothing
        is merged."""
        self.flush()
        target = self.folder / RECORDS_FILE
        found = sorted(self.parts.glob("part-*.parquet"))
        n = max(self._n_parts, len(found))
        if bad := damaged_parts(self.folder, n):
            raise DamagedRecordsError(
                f"{self.folder}: record parts damaged before the merge ({'; '.join(b for _, b in bad)}); "
                f"no {RECORDS_FILE} or metric files were written. {RESUME_FIX}")
        parts = [part_path(self.parts, i) for i in range(n)]

        def merge(tmp: Path) -> None:
            with pq.ParquetWriter(tmp, self.schema, compression="zstd") as writer:
                for p in parts:
                    writer.write_table(pq.read_table(p, schema=self.schema))

        write_with_digest(target, merge)
        return target


RESUME_FIX = ("Fix: continue the run with `urb-jax train --resume <id>` (it goes back to a checkpoint whose "
              "records are intact), or start it again with the same command and --overwrite.")


def remove_parts(folder: str | os.PathLike) -> None:
    """The last step of a finished run: the parts, now merged into records.parquet, go."""
    if (Path(folder) / RECORDS_FILE).is_file():
        shutil.rmtree(Path(folder) / PARTS_DIR, ignore_errors=True)


def _checked_records(folder: str | os.PathLike) -> pd.DataFrame:
    """The records metrics are computed from: the merged file, checked (`verified_records`), or the
    parts of a run that has none (a baseline's, read as `read_records` does)."""
    return verified_records(folder) if (Path(folder) / RECORDS_FILE).is_file() else read_records(folder)


def verified_records(folder: str | os.PathLike) -> pd.DataFrame:
    """records.parquet of `folder`, checked against its digest first (a file from before digests:
    as it is); a mismatch is a DamagedRecordsError: no metric is computed from damaged records."""
    path = Path(folder) / RECORDS_FILE
    if (why := damage_of(path)) is not None:
        raise DamagedRecordsError(f"{path}: {why}; no metric files were written from it. Fix: if the "
                                  f"run's {PARTS_DIR}/ is still there, `urb-jax train --resume <id>` merges "
                                  "them again; otherwise restore the file from a backup or run again.")
    return pq.read_table(path).to_pandas()


def read_records(folder: str | os.PathLike, columns: Sequence[str] | None = None) -> pd.DataFrame:
    """The records of a run: records.parquet, or the complete parts of an unfinished run."""
    folder = Path(folder)
    cols = list(columns) if columns else None
    if (folder / RECORDS_FILE).is_file():
        return pq.read_table(folder / RECORDS_FILE, columns=cols).to_pandas()
    parts = sorted((folder / PARTS_DIR).glob("part-*.parquet"))
    if not parts:
        raise UrbJaxError(f"{folder}: no {RECORDS_FILE} and no complete record parts.")
    return pa.concat_tables([pq.read_table(p, columns=cols) for p in parts]).to_pandas()


CONFIG_FILE = "exp_config.json"
_RECORD_FIX = "restore the file from a backup, or start the run again with the same command and --overwrite."


def run_config(folder: str | os.PathLike) -> dict[str, Any]:
    """A run's exp_config.json, checked against the sha256 it carries (a record from before digests:
    as it is). Missing, unreadable, not a JSON object or not its digest: a UrbJaxError naming the file
    and the fix (a run is never resumed, reused or measured from a record that changed)."""
    path = Path(folder) / CONFIG_FILE
    if not path.is_file():
        raise UrbJaxError(f"{path}: not found. Fix: pass a run folder (results/<exp_id>) of a "
                          "`urb-jax train` or `urb-jax baseline` run.")
    try:
        config = json.loads(path.read_text())
    except (OSError, ValueError) as exc:  # ValueError: bad JSON or UTF-8
        raise UrbJaxError(f"{path}: the run's record cannot be read ({exc}); it was damaged (truncated, "
                          f"or edited by hand), so the run cannot be resumed or reused. Fix: {_RECORD_FIX}"
                          ) from None
    if not isinstance(config, dict):
        raise UrbJaxError(f"{path}: the run's record is not a JSON object. Fix: {_RECORD_FIX}")
    return checked_json(path, config, f"undo the edit or {_RECORD_FIX}")


def write_run_config(folder: str | os.PathLike, config: dict[str, Any]) -> None:
    """A run's exp_config.json, carrying the sha256 of its content (`core.atomic.write_json_digested`)."""
    write_json_digested(Path(folder) / CONFIG_FILE, config)


def networks_dir_of(config: dict[str, Any], given: str | None = None) -> str | None:
    """Where a run's network is looked for again (a resume, an export): `given` (the network moved),
    else the folder holding the network file the run used (older runs recorded
    --networks-dir as typed, relative to the folder they were started from), else the recorded one."""
    if given:
        return absolute_dir(given)
    net_file = Path(config.get("net_file") or "")
    if net_file.is_file() and net_file.parent.name == config.get("network"):
        return str(net_file.parent.parent)
    return config.get("train_args", {}).get("networks_dir")


def check_run_network(config_file: Path, config: dict[str, Any], n_agents: int, net_file: str) -> None:
    """The network found again must be the run's own: its checkpoints and records have its agents."""
    if n_agents != int(config.get("num_agents", n_agents)):
        raise UrbJaxError(f"{config_file}: the network found at {net_file} has {n_agents} agents; the run "
                          f"used {config['num_agents']} ({config.get('net_file')}). Fix: pass the "
                          "--networks-dir that holds the run's own network.")


def finished_run_config(folder: str | os.PathLike) -> dict[str, Any]:
    """The exp_config.json of a finished run (the only kind whose records make whole metrics)."""
    cfg = run_config(folder)
    if cfg.get("status") != "done" or "training_days" not in cfg:
        fix = ("re-run the baseline" if "baseline_model" in cfg
               else f"finish it first (`urb-jax train --resume {Path(folder).name}`)")
        raise UrbJaxError(f"{folder}/exp_config.json: status {cfg.get('status')!r}, not a finished run. "
                          f"Fix: {fix}.")
    return cfg


def run_metrics(folder: str | os.PathLike) -> dict[str, float]:
    """A finished run's BenchmarkMetrics row (URB's column names), computed from its records and
    the phase lengths in its exp_config.json; writes nothing (`write_run_metrics` writes the files)."""
    cfg = finished_run_config(folder)
    metrics = compute_metrics(_checked_records(folder), int(cfg["human_days"]), int(cfg["training_days"]))
    return comparable_metrics(metrics) if is_hybrid(cfg) else metrics


def check_scheduled_departures(folder: str | os.PathLike, config: dict[str, Any], needs: str) -> None:
    """Refuse a tool that re-simulates a run's days (`needs`: why it needs the schedule) for a run whose
    SUMO days moved the departures (task key day_departure_jitter_s in its exp_config.json `config`)."""
    jitter = int(config.get("day_departure_jitter_s", 0))
    if jitter > 0:
        raise UrbJaxError(f"{Path(folder) / 'exp_config.json'}: key 'day_departure_jitter_s' = {jitter}: the "
                          f"run's SUMO days moved every departure, and {needs}. Fix: use a run with "
                          "day_departure_jitter_s 0.")


FLEETS_KEY = "fleet_agents"  # exp_config.json: each fleet's name -> its CAVs' agent ids (runs with fleets)


def run_fleets(folder: Path) -> dict[str, list[int]]:
    """The run's fleets (name -> agent ids, exp_config.json's FLEETS_KEY); empty: one fleet."""
    if not (Path(folder) / "exp_config.json").is_file():
        return {}
    return {str(k): [int(a) for a in v] for k, v in (run_config(Path(folder)).get(FLEETS_KEY) or {}).items()}


def write_run_metrics(folder: Path, human_days: int, training_days: int,
                      hybrid: bool = False) -> tuple[dict[str, float], pd.DataFrame]:
    """A run's metric files (metrics/BenchmarkMetrics.csv, VectorMetrics.csv, and SocialMetrics.csv
    beside URB's: equity over the humans, with the emission totals and EmissionMetrics.csv where the
    run recorded emissions; atomically) from its records: every run's last step, and
    what `urb-jax metrics` redoes. A `hybrid` run's columns that cover its SUMO training days only
    go under their own names (`comparable.comparable_metrics`). Returns the metrics and the records."""
    records = _checked_records(folder)
    metrics = compute_metrics(records, human_days, training_days)
    metrics = comparable_metrics(metrics) if hybrid else metrics
    fleets = run_fleets(folder)
    if fleets:  # competing fleets: each fleet's columns after URB's (a run without keeps its bytes)
        metrics |= fleet_metrics(records, human_days, training_days, fleets, hybrid)
    out = Path(folder) / "metrics"
    # every file computed before any is written: a failure leaves the metric files as they were
    vector = vector_metrics(records, human_days, training_days)
    social_row = social_metrics(records, human_days, training_days)
    social_columns = list(SOCIAL_COLUMNS)
    files = {"BenchmarkMetrics.csv": pd.DataFrame([metrics]).to_csv(index=False).encode(),
             "VectorMetrics.csv": vector.to_csv(index=False).encode()}
    if has_emissions(records):  # a run without keeps exactly its files
        social_row |= emission_metrics(records, human_days, training_days)
        social_columns += EMISSION_SOCIAL_COLUMNS
        files["EmissionMetrics.csv"] = emission_days(records).to_csv(index=False).encode()
    social = pd.DataFrame([social_row])[social_columns]
    files["SocialMetrics.csv"] = social.to_csv(index=False).encode()
    out.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        write_bytes(out / name, data)
    return metrics, records


def plot_phases(ax, per_day: pd.DataFrame, H: int, T: int, last_day: int, suffix: str = "") -> None:
    """Group means per day (columns all/HDV/CAV) over the phases as background patches."""
    for start, end, label, color in ((0.5, H + 0.5, "human learning", "#e8f0fe"),
                                     (H + 0.5, H + T + 0.5, "CAV training", "#fff4e0"),
                                     (H + T + 0.5, last_day + 0.5, "test", "#e6f4ea")):
        if end > start:
            ax.axvspan(start, end, color=color, label=label, zorder=0)
    for col, color in (("all", "black"), ("HDV", "tab:blue"), ("CAV", "tab:red")):
        if col in per_day:
            ax.plot(per_day.index, per_day[col], color=color, lw=1.2, label=f"{col}{suffix}")


def write_plots(folder: Path, records: pd.DataFrame, human_days: int, training_days: int,
                smooth_by: int = 1) -> list[Path]:
    """Mean travel time per day by group with phase backgrounds; CAV vs HDV test distributions."""
    import matplotlib  # imported by the runs that plot; the Agg backend is chosen before pyplot loads

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = folder / "plots"
    out.mkdir(parents=True, exist_ok=True)
    H, T = human_days, training_days
    last_day = int(records["day"].max())
    final_kind = records[records["day"] == last_day].set_index("agent")["kind"]
    rec = records.assign(group=records["agent"].map(final_kind))
    per_day = rec.groupby(["day", "group"])["travel_time"].mean().unstack()
    per_day["all"] = rec.groupby("day")["travel_time"].mean()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    plot_phases(ax, per_day.rolling(max(smooth_by, 1), min_periods=1).mean(), H, T, last_day,
                " (agents by final kind)")
    p1 = _save_travel_times(fig, ax, out / "travel_times.png")
    test = rec[rec["day"] > H + T]
    fig, ax = plt.subplots(figsize=(7, 4))
    if len(test):
        per_agent = test.groupby(["agent", "group"])["travel_time"].mean().reset_index()
        # Any: an array, which matplotlib's stubs leave out of hist's bins (Sequence[float])
        bins: Any = np.linspace(per_agent["travel_time"].min(), per_agent["travel_time"].max() + 1e-6, 40)
        for g, color in (("HDV", "tab:blue"), ("CAV", "tab:red")):
            vals = per_agent.loc[per_agent["group"] == g, "travel_time"]
            if len(vals):
                ax.hist(vals, bins=bins, alpha=0.55, color=color, label=f"{g} (n={len(vals)})")
        ax.legend()
    ax.set_xlabel("mean travel time over test days (min)")
    ax.set_ylabel("agents")
    fig.tight_layout()
    p2 = out / "test_distributions.png"
    fig.savefig(p2, dpi=110)
    plt.close(fig)
    fleets = run_fleets(folder)
    if not fleets:
        return [p1, p2]
    # competing fleets: each fleet's mean per day beside the humans' (a run without keeps its plots)
    fleet_of = {agent: name for name, agents in fleets.items() for agent in agents}
    by_fleet = rec.assign(group=rec["agent"].map(fleet_of).fillna(rec["group"]))
    per_fleet = by_fleet.groupby(["day", "group"])["travel_time"].mean().unstack()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    plot_phases(ax, pd.DataFrame(index=per_fleet.index), H, T, last_day)
    smooth = per_fleet.rolling(max(smooth_by, 1), min_periods=1).mean()
    for col in ["HDV", *fleets]:
        if col in smooth:
            ax.plot(smooth.index, smooth[col], lw=1.2, label=col if col != "HDV" else "humans")
    p3 = _save_travel_times(fig, ax, out / "fleets_travel_times.png")
    return [p1, p2, p3]


def _save_travel_times(fig: Any, ax: Any, path: Path) -> Path:
    """A travel-times-over-days figure's axes labelled, written to `path` and closed."""
    import matplotlib.pyplot as plt

    ax.set_xlabel("day")
    ax.set_ylabel("mean travel time (min)")
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
