"""A train run's learning curve in SUMO: each kept round checkpoint's policies tested as the run
tests its final ones.

A run with `hybrid.keep_checkpoints_at` keeps the checkpoints after those training days (besides
the newest two). `run_snapshots` restores each, runs the run's own test phase on it (the same test
days, keys and AON reference day; with frozen deterministic humans every test day of a seed is
one SUMO day, run once) and measures it with the run's metric code, so the last snapshot of a
finished run gives exactly the run's own test metrics. The rows (a seed and snapshot each) go to
snapshots.csv in the run's folder: t_CAV against the SUMO training days and the wall time the run
had spent, i.e. the sample-efficiency curve of a SUMO-only run.
"""

from __future__ import annotations

import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from urb_jax.core.atomic import write_text
from urb_jax.core.errors import UrbJaxError
from urb_jax.reporting.metrics import compute_metrics
from urb_jax.reporting.records import RecordsWriter, networks_dir_of, read_records
from urb_jax.runs.folder import check_exp_id, read_run_config, read_train_config
from urb_jax.runs.setup import recorded_setup
from urb_jax.sumo_bridge import DayExecutor, InProcessExecutor
from urb_jax.training.checkpoints import kept_checkpoints
from urb_jax.training.hybrid.trainer import Group, checkpoint_test_phase, setup_group

SNAPSHOTS_FILE = "snapshots.csv"
# the test metrics a snapshot reports (BenchmarkMetrics names; *_duration: the published tables' measure)
SNAPSHOT_METRICS = ("t_CAV", "t_HDV_test", "t_CAV_duration", "t_HDV_test_duration")


@dataclass(frozen=True)
class SnapshotRequest:
    """Which run's snapshots to test: `exp_id` (any seed's folder of the run's group) in
    `results_dir`; `rounds` (empty: every kept checkpoint); `networks_dir` where the network is now."""

    exp_id: str
    results_dir: str = "results"
    rounds: tuple[int, ...] = ()
    networks_dir: str | None = None
    progress: bool = True


def run_snapshots(req: SnapshotRequest, *, executor: DayExecutor | None = None) -> pd.DataFrame:
    """One row per seed and kept checkpoint (rounds ascending), also written to snapshots.csv in
    the group's first folder. `executor`: the SUMO days' (default: SUMO in this process)."""
    results = Path(req.results_dir)
    folder = results / check_exp_id(req.exp_id)
    config = read_train_config(folder)
    folders = [results / name for name in config.get("group", [req.exp_id])]
    configs = [read_run_config(f) for f in folders]
    rounds = _rounds(folders[0], req.rounds)
    g = _group(folders, configs, req)
    with tempfile.TemporaryDirectory(prefix="urbjax-snapshot-") as tmp:
        # SUMO's warnings go to a log, not the terminal
        days = InProcessExecutor(log_file=Path(tmp) / "sumo.log") if executor is None else executor
        try:
            rows = [row for r in rounds for row in _snapshot_rows(g, r, days, Path(tmp), req.progress)]
        finally:
            if executor is None:
                days.close()
    table = pd.DataFrame(rows).sort_values(["round", "seed"], kind="stable").reset_index(drop=True)
    write_text(folders[0] / SNAPSHOTS_FILE, table.to_csv(index=False))
    table.attrs["folder"] = folders[0].name
    return table


def _snapshot_rows(g: Group, r: int, executor: DayExecutor, tmp: Path, progress: bool) -> list[dict]:
    """Each seed's test metrics after round `r` (its test days recorded under tmp)."""
    seed_dirs = [tmp / f"round_{r}" / f.name for f in g.folders]
    writers = [RecordsWriter(d, g.scn.agent_id, g.scn.agent_od, g.scn.agent_depart) for d in seed_dirs]
    meta, aon = checkpoint_test_phase(g, r, executor, writers, progress)
    for writer in writers:
        writer.close()
    rows = []
    for seed, d in zip(g.seeds, seed_dirs, strict=True):
        with warnings.catch_warnings():  # no pre-CAV or training days here: their means are empty
            warnings.simplefilter("ignore", RuntimeWarning)
            metrics = compute_metrics(read_records(d), 0, 0)  # every recorded day is a test day
        rows.append({"seed": seed, "round": r, "training_days": g.plan.days_through(r),
                     "sumo_training_days": meta.sumo_days,
                     "wall_s": float("nan") if meta.wall_s is None else meta.wall_s,
                     **{m: metrics[m] for m in SNAPSHOT_METRICS},
                     "aon_t_CAV_duration": aon.get("t_CAV_duration", float("nan"))})
    return rows


def _rounds(first: Path, asked: tuple[int, ...]) -> list[int]:
    """The kept checkpoints to test: all, or those asked for (each must be kept)."""
    kept = kept_checkpoints(first)
    missing = sorted(set(asked) - set(kept))
    if not kept or missing:
        raise UrbJaxError(f"{first / 'checkpoints'}: no checkpoint after round(s) {missing or 'any'}; kept: "
                          f"{kept or 'none'}. Fix: ask for kept rounds, or train with "
                          "--set hybrid.keep_checkpoints_at=[DAYS, ...] to keep the snapshots you need.")
    return sorted(set(asked)) if asked else kept


def _group(folders: list[Path], configs: list[dict], req: SnapshotRequest) -> Group:
    """The run's seed group as its resume would build it, from the request it recorded."""
    train, setup = recorded_setup(configs, results_dir=req.results_dir, progress=req.progress,
                                  networks_dir=networks_dir_of(configs[0], req.networks_dir))
    return setup_group(setup.scn, setup.task, setup.env, train.alg, setup.alg_config, setup.hyb, train.mode,
                       list(train.seeds), train.env_seed, folders, None)
