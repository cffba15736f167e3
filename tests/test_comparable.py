"""URB's column names only where the value means what URB's means: a hybrid run's t_train, costs of
learning and time lost cover its SUMO training days only, so they go under `<column>_sumo_days` and
URB's columns stay empty in the URB-facing outputs (BenchmarkMetrics.csv, leaderboard, export-urb,
the paper page); a `--mode sumo` run and a baseline keep URB's. And urb-jax rows on URB's
leaderboard never merge runs that differ in `--set` overrides, and carry their seed."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pandas as pd
import pytest
from test_metrics import H, T, _records

from urb_jax.reporting.comparable import SUMO_DAYS, comparable_metrics, hybrid_note, is_hybrid
from urb_jax.reporting.leaderboard import aggregate, collect_folders
from urb_jax.reporting.metrics import BENCHMARK_COLUMNS, compute_metrics
from urb_jax.reporting.paper import EntryResults, load_paper_numbers, paper_markdown, read_ledger
from urb_jax.reporting.urb_names import names_of, train_names

URB_LEADERBOARD = Path(__file__).resolve().parents[1].parent / "shared" / "urb" / "leaderboard" / \
    "generate_leaderboard.py"
HYBRID_DAYS = {"sumo_training_days": 160, "surrogate_training_days": 6400}


def test_a_hybrid_runs_sumo_day_columns_move_and_nothing_else_changes():
    m = compute_metrics(_records(), H, T)
    moved = comparable_metrics(m)
    assert list(moved) == [*BENCHMARK_COLUMNS, *SUMO_DAYS.values()]  # URB's order, then ours
    for urb, ours in SUMO_DAYS.items():
        assert math.isnan(moved[urb]) and moved[ours] == m[urb]
    assert {k: v for k, v in moved.items() if k in BENCHMARK_COLUMNS and k not in SUMO_DAYS} == \
        {k: v for k, v in m.items() if k not in SUMO_DAYS}
    assert comparable_metrics(moved) == pytest.approx(moved, nan_ok=True)  # idempotent


@pytest.mark.parametrize("cfg, hybrid", [
    ({"surrogate_training_days": 6400}, True),
    ({"surrogate_training_days": 0, "script": "urb-jax train --mode sumo"}, False),  # every day in SUMO
    ({"script": "urb-jax baseline"}, False),
    ({"script": "urb-jax train --mode hybrid --hybrid-conf default --train-days 6000"}, True),  # old row
])
def test_which_runs_are_hybrid(cfg, hybrid):
    assert is_hybrid(cfg) is hybrid


def _run(root: Path, name: str, cfg: dict, **metrics: float) -> Path:
    folder = root / name
    (folder / "metrics").mkdir(parents=True)
    base = {"network": "saint_arnoult", "env_config": "config1", "task_config": "config1",
            "exp_type": "normal", "env_seed": 42, "status": "done"}
    (folder / "exp_config.json").write_text(json.dumps({**base, **cfg, **names_of(cfg)}))
    pd.DataFrame([metrics]).to_csv(folder / "metrics" / "BenchmarkMetrics.csv", index=False)
    return folder


def _train(alg: str, mode: str, seed: int, overrides: list[str] | None = None) -> dict:
    names = train_names(alg, mode, "default", 6000, "config1")
    days = HYBRID_DAYS if mode == "hybrid" else {"sumo_training_days": 6000, "surrogate_training_days": 0}
    return {**names, **days, "seed": seed, "train_args": {"overrides": overrides or []}}


@pytest.fixture
def runs(tmp_path):
    """Hybrid IQL seeds 0, 1, hybrid IQL with an override, IQL in SUMO only; written before the split
    (URB's columns filled in BenchmarkMetrics.csv)."""
    costs = {"t_CAV": 3.1, "t_train": 3.3, "cost_of_learning": 0.02, "cost_of_learning_humans": 0.01,
             "cost_of_learning_CAVs": 0.04, "winrate": 1.0}
    return [_run(tmp_path, "h_s0", _train("iql", "hybrid", 0), **costs),
            _run(tmp_path, "h_s1", _train("iql", "hybrid", 1), **costs),
            _run(tmp_path, "p16_s0", _train("iql", "hybrid", 0, ["hybrid.sumo_days_per_round=16"]), **costs),
            _run(tmp_path, "sumo_s0", _train("iql", "sumo", 0), **costs)]


def test_the_leaderboard_leaves_hybrid_costs_empty_and_keeps_overrides_apart(runs):
    rows = collect_folders(runs).set_index("exp_id")
    assert math.isnan(rows.loc["h_s0", "t_train"]) and rows.loc["h_s0", "t_train_sumo_days"] == 3.3
    assert math.isnan(rows.loc["h_s0", "cost_of_learning"])
    assert rows.loc["h_s0", "cost_of_learning_sumo_days"] == 0.02
    assert rows.loc["sumo_s0", "t_train"] == 3.3 and rows.loc["sumo_s0", "cost_of_learning"] == 0.02
    assert rows.loc["h_s0", "t_CAV"] == 3.1  # every other metric as it was
    assert list(rows["torch_seed"]) == [0, 1, 0, 0]
    assert rows.loc["p16_s0", "script"].endswith("--train-days 6000 --set hybrid.sumo_days_per_round=16")
    table = aggregate(collect_folders(runs))
    assert sorted(table["runs"]) == [1, 1, 2]  # the override run is its own row
    assert table["cost_of_learning_mean"].isna().sum() == 2  # the hybrid rows: N/A


def test_urbs_own_leaderboard_keeps_overrides_apart_and_shows_the_seed(runs, tmp_path):
    if not URB_LEADERBOARD.is_file():
        pytest.skip(f"URB's leaderboard generator not found at {URB_LEADERBOARD} (needs ../shared/urb)")
    spec = importlib.util.spec_from_file_location("urb_generate_leaderboard", URB_LEADERBOARD)
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    rows = gen.collapse_repeated_experiments(gen.collect_experiments(tmp_path))
    members = sorted(tuple(r.get("fold_members") or [r["exp_id"]]) for r in rows)
    assert members == [("h_s0", "h_s1"), ("p16_s0",), ("sumo_s0",)]
    assert {r["exp_id"]: r["torch_seed"] for r in rows if not r.get("fold_members")} == {"p16_s0": 0,
                                                                                         "sumo_s0": 0}


def test_an_old_hybrid_ledger_row_is_split_when_read(tmp_path):
    row = {"entry": "scenario1", "exp_id": "x", "t_train": 3.3, "cost_of_learning": 0.02,
           "script": "urb-jax train --mode hybrid --hybrid-conf default --train-days 6000"}
    (tmp_path / "paper_runs.json").write_text(json.dumps({"runs": [row]}))
    read = read_ledger(tmp_path / "paper_runs.json").iloc[0]
    assert math.isnan(read["cost_of_learning"]) and read["cost_of_learning_sumo_days"] == 0.02
    assert hybrid_note(read.to_dict()) == "not comparable: hybrid (its SUMO training days not recorded)"


def test_the_paper_page_shows_hybrid_costs_as_not_comparable(runs):
    paper = load_paper_numbers()
    rows = collect_folders(runs[:2]).assign(network="saint_arnoult")
    text = paper_markdown([EntryResults("scenario1", "Scenario 1", rows, 21, 1, 5)], paper, "")
    note = "not comparable: hybrid (160 SUMO of 6560 training days)"
    iql = text[text.index("| **IQL** |"):]
    ours = next(line for line in iql.splitlines() if line.startswith("|  | ours, SUMO duration |"))
    assert ours.count(note) == 3  # c_all, c_HDV, c_CAV
    assert f"c_all > 0 [tab:kpis caption]: **not comparable** ({note})" in iql
