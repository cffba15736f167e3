"""Results folder: atomic record parts, compaction, refusal to overwrite, CLI and leaderboard."""

import json
import shutil
import subprocess

import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeDay

from urb_jax.commands.cli import main
from urb_jax.reporting.leaderboard import aggregate, collect
from urb_jax.reporting.records import (
    PARTS_DIR,
    RECORDS_FILE,
    RecordsWriter,
    read_records,
    remove_parts,
    run_config,
    write_run_config,
)
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.folder import (
    ResultsExistError,
    _cpu,
    create_results_dir,
    machine,
    source_commit,
)
from urb_jax.runs.request import BaselineRequest
from urb_jax.training.protocol import DayRecord

TINY = {"human_learning_episodes": 3, "training_eps": 2, "test_eps": 2}


def _day(day, n=4, cav=None):
    fake = FakeDay()

    class S:  # the fields FakeDay reads
        agent_od = np.zeros(n, np.int32)
        k = 2
        fft = np.tile([[1.0, 2.0]], (n, 1))
        od_route_length = np.array([[100.0, 200.0]])

    choices = np.arange(n) % 2
    is_cav = np.zeros(n, bool) if cav is None else cav
    obs = None if cav is None else np.where(is_cav[:, None], np.arange(n * 3).reshape(n, 3), np.nan)
    res = fake(S, choices, seed=0)
    return DayRecord(day, "human" if cav is None else "train", choices, is_cav, res, -res.travel_time, obs)


def test_parts_are_atomic_and_compacted(tmp_path):
    w = RecordsWriter(tmp_path, np.array([5, 6, 7, 8]), np.zeros(4), np.array([0, 1, 2, 3]), flush_every=2)
    for d in (1, 2, 3):
        w.add(_day(d))
    # a crashed run: 2 days flushed as one part, day 3 pending, plus a stray temp file
    (tmp_path / PARTS_DIR / ".part.junk.tmp").write_bytes(b"half a file")
    assert sorted(read_records(tmp_path)["day"].unique()) == [1, 2]
    cav = np.array([False, True, False, True])
    w.add(_day(4, cav=cav))
    path = w.close()
    assert path.name == RECORDS_FILE and (tmp_path / PARTS_DIR).is_dir()  # kept until the run is done
    remove_parts(tmp_path)
    assert not (tmp_path / PARTS_DIR).exists()
    df = read_records(tmp_path)
    assert len(df) == 16 and sorted(df["day"].unique()) == [1, 2, 3, 4]
    d4 = df[df.day == 4].set_index("agent")
    assert d4.loc[6, "observation"].tolist() == [3.0, 4.0, 5.0] and d4.loc[5, "observation"] is None
    assert d4.loc[6, "kind"] == "CAV" and d4.loc[5, "kind"] == "HDV"
    assert df[df.day == 1]["observation"].isna().all()


def test_refuses_to_overwrite(tmp_path):
    p = create_results_dir(tmp_path, "exp")
    (p / "exp_config.json").write_text("{}")  # a urb-jax run (--overwrite removes nothing else)
    (p / "marker").write_text("x")
    with pytest.raises(ResultsExistError, match="--overwrite"):
        create_results_dir(tmp_path, "exp")
    assert (p / "marker").exists()
    create_results_dir(tmp_path, "exp", overwrite=True)
    assert not (p / "marker").exists()


def test_baseline_run_writes_results_folder_and_leaderboard(tmp_path):
    for seed in (1, 2):
        out = run_baseline(BaselineRequest(model="random", task_conf="config1", results_dir=str(tmp_path),
                                           env_seed=seed,
                                           progress=False), executor=FakeDay(), task_overrides=TINY)
    folder = out.folder
    cfg = json.loads((folder / "exp_config.json").read_text())
    assert cfg["status"] == "done" and cfg["env_seed"] == 2 and cfg["baseline_model"] == "random"
    assert cfg["network"] == "urb_grid" and cfg["human_learning_episodes"] == 3 and "versions" in cfg
    assert cfg["machine"] == machine() and cfg["machine"]["backend"] == "cpu"  # where its bits came from
    bm = pd.read_csv(folder / "metrics" / "BenchmarkMetrics.csv")
    assert {"t_pre", "t_CAV", "t_HDV_test", "winrate", "cost_of_learning", "avg_speed_test"} <= set(
        bm.columns)
    assert len(pd.read_csv(folder / "metrics" / "VectorMetrics.csv")) == 4
    assert (folder / "plots" / "travel_times.png").stat().st_size > 1000
    assert read_records(folder)["day"].max() == 7
    with pytest.raises(ResultsExistError):
        run_baseline(BaselineRequest(model="random", task_conf="config1", results_dir=str(tmp_path),
                                     env_seed=2, progress=False), executor=FakeDay(), task_overrides=TINY)
    table = aggregate(collect(tmp_path))
    assert len(table) == 1 and table.loc[0, "runs"] == 2
    runs = collect(tmp_path)
    assert table.loc[0, "t_CAV_mean"] == pytest.approx(runs["t_CAV"].mean())
    assert table.loc[0, "WR"] == pytest.approx(100 * runs["winrate"].mean())
    assert table.loc[0, "t_CAV_duration_mean"] == pytest.approx(runs["t_CAV_duration"].mean())
    assert main(["leaderboard", str(tmp_path)]) == 0
    assert "| random | urb-jax baseline | training_eps_2 |" in (tmp_path / "leaderboard.md").read_text()


def test_cli_refusal_is_a_clean_error(tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    code = main(["baseline", "--results-dir", str(tmp_path), "--id", "taken", "--no-progress"])
    assert code == 2 and "already exist" in capsys.readouterr().err


def test_human_phase_replay_matches_a_fresh_run(tmp_path):
    """A random run replaying an aon run's human phase: no SUMO calls for days 1..H, identical
    human-phase records and t_pre; a tampered source is refused."""
    from urb_jax.core.errors import UrbJaxError

    src = run_baseline(BaselineRequest(model="aon", results_dir=str(tmp_path), exp_id="src", progress=False),
                       executor=FakeDay(), task_overrides=TINY)
    fresh = run_baseline(BaselineRequest(model="random", results_dir=str(tmp_path), exp_id="fresh",
                                         progress=False), executor=FakeDay(), task_overrides=TINY)
    fake = FakeDay()
    replayed = run_baseline(BaselineRequest(model="random", results_dir=str(tmp_path), exp_id="replayed",
                                            progress=False,
                                            human_phase_from="src"), executor=fake, task_overrides=TINY)
    assert len(fake.calls) == 2 + 2  # training + test days only
    a, b = read_records(fresh.folder), read_records(replayed.folder)
    pd.testing.assert_frame_equal(a, b)
    assert replayed.metrics["t_pre"] == src.metrics["t_pre"]
    with pytest.raises(UrbJaxError, match="env_seed"):
        run_baseline(BaselineRequest(model="random", results_dir=str(tmp_path), exp_id="other_seed",
                                     env_seed=5, progress=False,
                                     human_phase_from="src"), executor=FakeDay(), task_overrides=TINY)
    rec = read_records(src.folder)
    rec.loc[(rec.day == 2) & (rec.agent == rec.agent.iloc[0]), "action"] += 1
    rec.to_parquet(src.folder / "records.parquet")
    tampered = BaselineRequest(model="random", results_dir=str(tmp_path), exp_id="tampered", progress=False,
                               human_phase_from="src")
    with pytest.raises(UrbJaxError, match=r"records\.parquet: does not match its digest"):
        run_baseline(tampered, executor=FakeDay(), task_overrides=TINY)
    (src.folder / "records.parquet.sha256").unlink()  # a source from before digests: the replay tells
    with pytest.raises(UrbJaxError, match="day 2"):
        run_baseline(tampered, executor=FakeDay(), task_overrides=TINY)


def test_metrics_command_recomputes_a_finished_runs_columns(tmp_path, capsys):
    """`urb-jax metrics RUN`: an older run without the duration columns gets them, equal to what
    the run itself wrote; an unfinished run is refused with the fix."""
    out = run_baseline(BaselineRequest(model="random", results_dir=str(tmp_path), exp_id="old",
                                       progress=False), executor=FakeDay(), task_overrides=TINY)
    path = out.folder / "metrics" / "BenchmarkMetrics.csv"
    written = pd.read_csv(path)
    assert written["t_CAV_duration"].iloc[0] == pytest.approx(written["t_CAV"].iloc[0] - 2 / 60)
    written.drop(columns=[c for c in written.columns if c.endswith("_duration")]).to_csv(path, index=False)
    assert main(["metrics", str(out.folder)]) == 0
    pd.testing.assert_frame_equal(pd.read_csv(path), written)
    assert "t_CAV_duration" in capsys.readouterr().out
    write_run_config(out.folder, {**run_config(out.folder), "status": "running"})  # as an unfinished run's
    assert main(["metrics", str(out.folder)]) == 2
    err = capsys.readouterr().err
    assert "exp_config.json" in err and "Fix: re-run the baseline" in err


def test_a_baseline_runs_each_distinct_day_once(tmp_path):
    """AON CAVs among frozen deterministic humans repeat one day through training and test: it runs
    once (the one day cache, sumo_bridge.MemoExecutor), and every recorded day is still the day of
    its own choices (checked against a fresh FakeDay)."""
    from urb_jax.city.scenario import load_scenario

    fake = FakeDay()
    overrides = {"human_learning_episodes": 6, "training_eps": 8, "test_eps": 4}
    out = run_baseline(BaselineRequest(model="aon", results_dir=str(tmp_path), progress=False), executor=fake,
                       task_overrides=overrides)
    cfg = json.loads((out.folder / "exp_config.json").read_text())
    assert cfg["sumo_days_run"] == len(fake.calls) < out.days == 18
    assert cfg["sumo_days_run"] + cfg["sumo_days_repeated"] == out.days
    scn = load_scenario("urb_grid")
    rec = read_records(out.folder).sort_values(["day", "agent"])
    pos = {a: i for i, a in enumerate(scn.agent_id)}
    for day, rows in rec.groupby("day"):
        choices = np.empty(scn.n_agents, np.int64)
        choices[[pos[a] for a in rows["agent"]]] = rows["action"].to_numpy()
        want = FakeDay()(scn, choices, seed=42).travel_time[[pos[a] for a in rows["agent"]]]
        np.testing.assert_allclose(rows["travel_time"].to_numpy(), want, rtol=1e-6, err_msg=f"day {day}")


def test_source_commit_names_the_checkout_commit(tmp_path):
    """A run records the commit of the code that made it: HEAD in a git checkout, '+changes' when
    tracked files differ; a folder inside another repository (a venv) or outside any is unknown."""
    if shutil.which("git") is None:
        pytest.skip("git is not installed here")
    repo = tmp_path / "repo"
    repo.mkdir()

    def git(*args):
        return subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=repo,
                              check=True, capture_output=True, text=True).stdout.strip()

    git("init", "-q")
    (repo / "a.py").write_text("x = 1\n")
    git("add", "a.py")
    git("commit", "-q", "-m", "one")
    head = git("rev-parse", "HEAD")
    commit = source_commit.__wrapped__  # uncached
    assert commit(repo) == head and len(head) == 40
    (repo / "a.py").write_text("x = 2\n")
    assert commit(repo) == head + "+changes"
    (repo / "venv").mkdir()
    assert commit(repo / "venv") == "unknown (not a git checkout)"
    (tmp_path / "plain").mkdir()
    assert commit(tmp_path / "plain") == "unknown (not a git checkout)"


def test_a_run_names_the_cpu_its_bits_depend_on(tmp_path):
    """A VM's generic model name gets family/model/stepping and the cache size; only whole ISA flag
    names count."""
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: GenuineIntel\ncpu family\t: 6\nmodel\t\t: 207\n"
                    "model name\t: Intel(R) Xeon(R) Processor\nstepping\t: 2\ncache size\t: 107520 KB\n"
                    "flags\t\t: fpu sse4_2 avx2 fma avx512fx avx512f amx_tile\n\nprocessor\t: 1\n")
    model, isa = _cpu(info)
    assert model == "Intel(R) Xeon(R) Processor (family 6, model 207, stepping 2), cache 107520 KB"
    assert isa == ["sse4_2", "avx2", "fma", "avx512f", "amx_tile"]  # no avx, no avx512fx
    model, isa = _cpu(tmp_path / "absent")
    assert isa == [] and model  # not Linux: platform's name, no flags
