"""`urb-jax export-urb` against URB's own tools, and URB's names in exp_config.json.

A small real run (a random-CAV baseline on urb_grid, days from tests/support/fakeday.py) is exported;
URB's unmodified analysis/metrics.py runs on the export in a subprocess and its BenchmarkMetrics
are compared with ours column by column; URB's leaderboard generator reads our names. Both come
from ../shared/urb and are skipped, with the reason, where it is absent; the layout test checks
the same files, columns and phase slicing without it."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeDay

from urb_jax.algorithms.registry import ALGORITHMS, URB_ALIASES, canonical, urb_algorithm
from urb_jax.commands.cli import main
from urb_jax.core.errors import ConfigError, UrbJaxError
from urb_jax.reporting.leaderboard import aggregate, collect
from urb_jax.reporting.records import read_records
from urb_jax.reporting.urb_export import export_urb
from urb_jax.reporting.urb_names import train_names
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.request import BaselineRequest

URB = Path(__file__).resolve().parents[1].parent / "shared" / "urb"
URB_METRICS = URB / "analysis" / "metrics.py"
URB_LEADERBOARD = URB / "leaderboard" / "generate_leaderboard.py"
H, T, E = 12, 4, 5
URB_COLUMNS = ["t_pre", "t_test", "t_train", "t_CAV", "t_HDV_pre", "t_HDV_test", "CAV_advantage",
               "Effect_of_change", "Effect_of_remaining", "avg_speed_pre", "avg_speed_test",
               "avg_mileage_pre", "avg_mileage_test", "winrate", "cost_of_learning",
               "cost_of_learning_humans", "cost_of_learning_CAVs", "avg_time_lost", "avg_human_time_lost",
               "avg_CAV_time_lost", "diff_sumo_routerl"]
COST = ["cost_of_learning", "cost_of_learning_humans", "cost_of_learning_CAVs"]  # the paper's, on purpose
# URB's collector writes combined_data.csv with 2 decimals in its numeric columns, the SUMO statistic
# ones (travel times come in full): the largest difference that rounding allows, per column
ROUNDED = {"avg_speed_pre": 3.6 * 0.005, "avg_speed_test": 3.6 * 0.005,  # m/s -> km/h
           "avg_mileage_pre": 0.005 / 1000, "avg_mileage_test": 0.005 / 1000,  # m -> km
           "diff_sumo_routerl": 0.005 / 60}  # s -> min
needs_urb = pytest.mark.skipif(not URB_METRICS.is_file(), reason=f"URB's analysis/metrics.py not found at "
                               f"{URB_METRICS} (needs ../shared/urb)")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A finished run, and the same run as a urb-jax train run before URB's names existed wrote
    it: `algorithm` our id, `script` "urb-jax train", the task's training_eps 200 while the
    records hold 4 training days (what URB's slicing used to find no test days with)."""
    root = tmp_path_factory.mktemp("urb-export")
    out = run_baseline(BaselineRequest(model="random", task_conf="config1",
                                       results_dir=str(root / "results"), exp_id="rnd",
                                       progress=False),
                       executor=FakeDay(),
                       task_overrides={"human_learning_episodes": H, "training_eps": T, "test_eps": E})
    old = root / "results" / "old_iql"
    shutil.copytree(out.folder, old)
    cfg = json.loads((old / "exp_config.json").read_text())
    for key in ("alg", "baseline_model", "phase_days", "experience_collecting_episodes", "content_sha256"):
        cfg.pop(key)
    cfg.update(algorithm="iql", script="urb-jax train", alg_config="config1", training_eps=200, mode="hybrid",
               hybrid_config="default", hybrid_train_days=1000)
    (old / "exp_config.json").write_text(json.dumps(cfg))
    return root, out.folder, old


def _urb_metrics(export: Path) -> tuple[pd.Series, pd.DataFrame]:
    """URB's analysis/metrics.py, unmodified, on an export (its own process, as URB runs it)."""
    proc = subprocess.run([sys.executable, str(URB_METRICS), "--id", export.name, "--results-folder",
                           str(export.parent)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return (pd.read_csv(export / "metrics" / "BenchmarkMetrics.csv").iloc[0],
            pd.read_csv(export / "metrics" / "VectorMetrics.csv"))


def test_exp_config_phases_and_names_describe_the_records(runs):
    _, run, _ = runs
    cfg = json.loads((run / "exp_config.json").read_text())
    rec = read_records(run)
    for phase, (first, last) in cfg["phase_days"].items():
        days = sorted(rec.loc[rec["phase"] == phase, "day"].unique())
        assert days == list(range(first, last + 1))
    assert (cfg["human_learning_episodes"], cfg["training_eps"], cfg["test_eps"]) == (H, T, E)
    assert cfg["experience_collecting_episodes"] == 0
    # a baseline as URB's baselines.py writes one: baseline_model, no algorithm; never URB's script
    assert cfg["algorithm"] is None and cfg["baseline_model"] == "random" and cfg["alg"] == "baseline_random"
    assert cfg["script"] == "urb-jax baseline" and cfg["alg_config"] == f"training_eps_{T}"


@pytest.mark.parametrize("which", ["run", "old"])
def test_export_layout_is_what_urbs_metrics_code_reads(runs, which):
    """Files, columns and phase slicing as URB's analysis/metrics.py reads them (its
    get_episodes, load_episode, load_routeRL, load_*_SUMO, get_type_ids and slice_episodes)."""
    root, run, old = runs
    src = run if which == "run" else old
    export = Path(export_urb(src, root / f"urb_{which}")["folder"])
    cfg = json.loads((export / "exp_config.json").read_text())
    rec = read_records(src)
    days = sorted(rec["day"].unique())
    assert sorted(int(p.stem[2:]) for p in (export / "episodes").iterdir()) == days
    for d in days:
        ep = pd.read_csv(export / "episodes" / f"ep{d}.csv")
        assert {"travel_time", "id", "action", "origin", "destination", "start_time", "reward"} <= set(ep)
        one = rec[rec["day"] == d].set_index("agent").loc[ep["id"]]
        np.testing.assert_allclose(ep["travel_time"], one["travel_time"], rtol=1e-6)
        trips = ET.parse(export / "SUMO_output" / f"detailed_sumo_stats_{d}.xml").getroot()
        trips = trips.findall("tripinfo")
        assert {"id", "depart", "departDelay", "arrival", "routeLength", "duration", "waitingTime",
                "timeLoss", "speedFactor", "vType"} <= set(trips[0].attrib)
        vtype = {int(t.get("id")): t.get("vType") for t in trips}
        kinds = zip(one.index, one["kind"], strict=True)
        assert vtype == {a: ("AV" if k == "CAV" else "Human") for a, k in kinds}
        stats = {c.tag: c.attrib for c in ET.parse(export / "SUMO_output" / f"sumo_stats_{d}.xml").getroot()}
        assert {"total", "jam", "yield", "wrongLane"} <= set(stats["teleports"])
        assert {"count", "routeLength", "speed", "duration", "waitingTime", "timeLoss", "departDelay",
                "totalTravelTime", "totalDepartDelay"} <= set(stats["vehicleTripStatistics"])
        mileage = float(stats["vehicleTripStatistics"]["routeLength"])
        assert mileage == pytest.approx(one["route_length"].mean())
    # URB's slice_episodes on the exported keys gives each recorded phase's days, nothing else
    hl, ec, tr = cfg["human_learning_episodes"], cfg["experience_collecting_episodes"], cfg["training_eps"]
    phase = rec.groupby("day")["phase"].first()
    assert [d for d in days if hl + ec < d <= hl + ec + tr] == list(phase[phase == "train"].index)
    assert [d for d in days if d > hl + ec + tr] == list(phase[phase == "test"].index)
    assert [d for d in days if hl - 50 < d <= hl] == list(phase[phase == "human"].index)[-50:]
    assert (tr, cfg["test_eps"]) == (T, E)  # the old run's exp_config said 200: the records hold 4
    assert "algorithm" in cfg  # URB's metrics.py reads exp_config["algorithm"] with no default
    if which == "old":  # an older run is exported under today's names
        assert (cfg["algorithm"], cfg["alg"], cfg["alg_config"]) == ("iql_torchrl", "iql", "config1")
        assert cfg["script"] == "urb-jax train --mode hybrid --hybrid-conf default --train-days 1000"


@needs_urb
@pytest.mark.parametrize("which", ["run", "old"])
def test_urbs_own_metrics_script_agrees_with_ours(runs, which):
    root, run, old = runs
    src = run if which == "run" else old
    export = Path(export_urb(src, root / f"urb_cmp_{which}")["folder"])
    urb, urb_vec = _urb_metrics(export)
    ours = pd.read_csv(src / "metrics" / "BenchmarkMetrics.csv").iloc[0]
    assert list(urb.index) == URB_COLUMNS
    for col in URB_COLUMNS:
        if col in COST:
            continue
        tol = ROUNDED.get(col, 0.0) + 1e-6 * max(1.0, abs(ours[col]))
        assert abs(urb[col] - ours[col]) <= tol, (col, urb[col], ours[col])
    # cost of learning: URB's code is the mean over agents of max - min over the training days,
    # ours the paper's mean excess over each agent's pre-CAV mean (docs/metrics.md); check URB's
    # value against its definition, computed here from the records
    rec = read_records(src)
    tt = rec.pivot(index="day", columns="agent", values="travel_time").astype(np.float64)
    train = tt.loc[H + 1:H + T]
    spread = train.max() - train.min()
    last = rec[rec["day"] == rec["day"].max()].set_index("agent")["kind"]
    cav, hdv = last.index[last == "CAV"], last.index[last != "CAV"]
    assert urb["cost_of_learning_CAVs"] == pytest.approx(spread[cav].mean(), rel=1e-6)
    assert urb["cost_of_learning_humans"] == pytest.approx(spread[hdv].mean(), rel=1e-6)
    assert urb["cost_of_learning"] == pytest.approx(spread.mean(), rel=1e-6)
    assert ours["cost_of_learning"] == pytest.approx((train - tt.loc[H - 49:H].mean()).to_numpy().mean(),
                                                     rel=1e-5)
    # VectorMetrics: the same post-mutation days; URB's instability counts everyone on its first
    # row (it compares within its after-mutation slice), ours compares with the last human day
    ours_vec = pd.read_csv(src / "metrics" / "VectorMetrics.csv")
    assert list(urb_vec["episode"]) == list(ours_vec["episode"]) == list(range(H + 1, H + T + E + 1))
    np.testing.assert_allclose(urb_vec["time_excess"], ours_vec["time_excess"], rtol=1e-5)
    np.testing.assert_allclose(urb_vec["avg_time_lost"], ours_vec["avg_time_lost"], atol=0.01)
    assert (urb_vec.iloc[1:][["instability_humans", "instability_CAVs"]].to_numpy()
            == ours_vec.iloc[1:][["instability_humans", "instability_CAVs"]].to_numpy()).all()
    assert urb_vec.loc[0, "instability_humans"] + urb_vec.loc[0, "instability_CAVs"] == rec["agent"].nunique()


def _urb_generator():
    if not URB_LEADERBOARD.is_file():
        pytest.skip(f"URB's leaderboard generator not found at {URB_LEADERBOARD} (needs ../shared/urb)")
    spec = importlib.util.spec_from_file_location("urb_generate_leaderboard", URB_LEADERBOARD)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _fake_run(root: Path, exp_id: str, cfg: dict, t_cav: float) -> None:
    (root / exp_id / "metrics").mkdir(parents=True)
    base = {"network": "saint_arnoult", "env_config": "config1", "task_config": "config1",
            "exp_type": "normal", "env_seed": 42}
    (root / exp_id / "exp_config.json").write_text(json.dumps({**base, **cfg}))
    metrics = root / exp_id / "metrics" / "BenchmarkMetrics.csv"
    pd.DataFrame([{"t_CAV": t_cav, "winrate": 0.0}]).to_csv(metrics, index=False)


@pytest.fixture
def mixed_results(tmp_path):
    """URB's own bandit IQL run and urb-jax runs of IQL*, IQL (two seeds) and AON side by side."""
    star = train_names("iql_star", "hybrid", "default", 2000, "config1")
    iql = train_names("iql", "hybrid", "default", 6000, "config1")
    sumo = train_names("iql", "sumo", "default", 6000, "config1")
    urb = {"algorithm": "iql", "script": "scripts/iql.py", "alg_config": "config1", "torch_seed": 0}
    _fake_run(tmp_path, "urb_iql", urb, 3.1)
    _fake_run(tmp_path, "ours_iql_star", {**star, "torch_seed": 0}, 3.2)
    _fake_run(tmp_path, "ours_iql_s0", {**iql, "torch_seed": 0}, 3.3)
    _fake_run(tmp_path, "ours_iql_s1", {**iql, "torch_seed": 1}, 3.5)
    _fake_run(tmp_path, "ours_iql_sumo", {**sumo, "torch_seed": 0}, 3.6)
    _fake_run(tmp_path, "urb_aon", {"baseline_model": "aon", "script": "scripts/baselines.py",
                                    "alg_config": "config1"}, 3.0)
    _fake_run(tmp_path, "ours_aon", {"algorithm": None, "baseline_model": "aon", "alg": "baseline_aon",
                                     "script": "urb-jax baseline", "alg_config": "config1"}, 3.01)
    return tmp_path


def test_urbs_leaderboard_keeps_urb_jax_rows_apart_and_links_the_right_configs(mixed_results):
    gen = _urb_generator()
    rows = gen.collapse_repeated_experiments(gen.collect_experiments(mixed_results))
    by_members = {tuple(r.get("fold_members") or [r["exp_id"]]): r for r in rows}
    assert set(by_members) == {("urb_iql",), ("ours_iql_star",), ("ours_iql_s0", "ours_iql_s1"),
                               ("ours_iql_sumo",), ("urb_aon",), ("ours_aon",)}  # only our seeds merge
    assert float(by_members[("ours_iql_s0", "ours_iql_s1")]["metrics"]["t_CAV"]) == pytest.approx(3.4)
    for members, folder in [(("ours_iql_star",), "iql"), (("ours_iql_s0", "ours_iql_s1"), "iql_torchrl"),
                            (("ours_aon",), "baseline"), (("urb_iql",), "iql")]:
        row = by_members[members]
        path = gen.resolve_repo_algorithm_config_file(row["algorithm_config_group"], row["alg_config"], URB)
        # URB's generator resolves links; ../shared may be one (a worktree beside a linked shared/)
        assert path.resolve() == (URB / "config" / "algo_config" / folder / "config1.json").resolve(), members
    assert by_members[("ours_aon",)]["algorithm"] == "aon"


def test_our_leaderboard_groups_as_urbs_does(mixed_results):
    table = aggregate(collect(mixed_results))
    assert sorted(table["runs"]) == [1, 1, 1, 1, 1, 2]
    two = table[table["runs"] == 2].iloc[0]
    assert (two["algorithm"], two["alg"], two["t_CAV_mean"]) == ("iql_torchrl", "iql", pytest.approx(3.4))
    assert set(table.loc[table["algorithm"] == "iql", "script"]) == {
        "iql.py", "urb-jax train --mode hybrid --hybrid-conf default --train-days 2000"}
    assert main(["leaderboard", str(mixed_results)]) == 0
    md = (mixed_results / "leaderboard.md").read_text()
    assert "| iql (--alg iql_star) | urb-jax train --mode hybrid" in md and "| iql | iql.py |" in md


def test_algorithm_names_map_one_to_one_onto_urbs():
    urb_names = [urb_algorithm(a) for a in ALGORITHMS]
    assert len(set(urb_names)) == len(urb_names)  # one urb-jax algorithm per URB algorithm
    assert (urb_algorithm("iql"), urb_algorithm("iql_star")) == ("iql_torchrl", "iql")
    assert URB_ALIASES == {"iql_torchrl": "iql", "ippo_torchrl": "ippo", "mappo_torchrl": "mappo",
                           "qmix_torchrl": "qmix", "vdn_torchrl": "vdn"}
    assert canonical("qmix_torchrl") == "qmix" and canonical("iql_star") == "iql_star"
    with pytest.raises(ConfigError, match="iql_torchrl"):
        canonical("iql_bandit")
    if (URB / "config" / "algo_config").is_dir():  # every name is a folder of URB's config/algo_config
        assert all((URB / "config" / "algo_config" / n).is_dir() for n in urb_names)


def test_alias_dry_run_prints_urb_names(capsys):
    assert main(["train", "--alg", "iql_torchrl", "--task-conf", "test", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "algorithm    iql (reads URB's iql_torchrl configs)" in out
    assert "algorithm 'iql_torchrl', alg 'iql', script 'urb-jax train --mode hybrid" in out


def test_export_refuses_what_it_must_not_touch(runs, capsys):
    root, run, _ = runs
    with pytest.raises(UrbJaxError, match="the run itself"):
        export_urb(run, run.parent)
    (root / "taken" / "rnd").mkdir(parents=True)
    (root / "taken" / "rnd" / "mine.txt").write_text("x")
    assert main(["export-urb", str(run), "--out", str(root / "taken"), "--overwrite"]) == 2
    assert "not a urb-jax export" in capsys.readouterr().err
    assert (root / "taken" / "rnd" / "mine.txt").exists()
    first = export_urb(run, root / "again")
    with pytest.raises(UrbJaxError, match="--overwrite"):
        export_urb(run, root / "again")
    again = export_urb(run, root / "again", overwrite=True, save_every=5)
    assert again["folder"] == first["folder"] and again["days"] == len([d for d in range(1, H + T + E + 1)
                                                                         if d % 5 == 0])
    assert not [p for p in (root / "again").iterdir() if p.name.startswith(".")]  # no temporary left
