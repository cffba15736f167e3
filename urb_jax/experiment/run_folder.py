"""A run's results folder, results/<exp_id>/: created once, exp_config.json written at the start and
marked done at the end, and the finishing step that turns records into metric files and plots."""

from __future__ import annotations

import os
import platform
import shutil
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import pandas as pd

from urb_jax.core.atomic import write_bytes, write_json
from urb_jax.core.errors import UrbJaxError
from urb_jax.results.records import write_plots, write_run_metrics

CONFIG_FILE = "exp_config.json"


class ResultsExistError(UrbJaxError):
    """The experiment id is taken."""


def create_results_dir(root: str | os.PathLike, exp_id: str, overwrite: bool = False) -> Path:
    """A fresh results/<exp_id>/; refuses an existing one unless `overwrite`."""
    path = Path(root) / exp_id
    if path.exists():
        if not overwrite:
            raise ResultsExistError(
                f"{path}: results for experiment id '{exp_id}' already exist. "
                "Fix: pass another --id, or --overwrite to replace them."
            )
        shutil.rmtree(path)
    path.mkdir(parents=True)
    return path


def versions() -> dict[str, str]:
    """Installed versions (from package metadata: importing libsumo just to ask is costly)."""
    out = {"python": platform.python_version()}
    for dist in ("urb-jax", "jax", "numpy", "pandas", "pyarrow", "eclipse-sumo", "libsumo", "janux"):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = "absent"
    return out


def write_config(folder: Path, config: dict[str, Any]) -> None:
    write_json(folder / CONFIG_FILE, config)


def write_outputs(folder: Path, human_days: int, training_days: int) -> dict[str, float]:
    """The metric files and plots of a finished run, from its records; returns the metrics."""
    metrics, records = write_run_metrics(folder, human_days, training_days)
    write_plots(folder, records, human_days, training_days, smooth_by=1)
    return metrics


def mark_done(folder: Path, config: dict[str, Any], **updates: Any) -> None:
    """exp_config.json with status done and `updates`: a run's last write (without it, unfinished)."""
    config.update(status="done", **updates)
    write_config(folder, config)


def write_rounds(folder: Path, rounds: list[dict[str, float]]) -> None:
    """rounds.csv (per round: surrogate and SUMO days, times, surrogate error) and its plot."""
    df = pd.DataFrame(rounds)
    write_bytes(folder / "rounds.csv", df.to_csv(index=False).encode())
    if "surrogate_mean_error" not in df:
        return
    import matplotlib  # imported by the runs that plot; the Agg backend is chosen before pyplot loads

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(df["round"], 100 * df["surrogate_mean_error"], label="error of the day mean (%)")
    ax.plot(df["round"], 100 * df["surrogate_mape"], label="per agent-day MAPE (%)")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_xlabel("round")
    ax.set_ylabel("surrogate vs SUMO (before refit)")
    ax.legend()
    fig.tight_layout()
    (folder / "plots").mkdir(exist_ok=True)
    fig.savefig(folder / "plots" / "surrogate_error.png", dpi=110)
    plt.close(fig)
