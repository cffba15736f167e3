"""The paper page's ledger reproduces: each row keeps its run's provenance, and `urb-jax suite ENTRY
--verify` reruns recorded rows beside the results folder and says, row by row, identical or
different (naming the metric, both runs' commit and machine side by side)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from support.fakeday import FakeDay

from urb_jax.core.atomic import write_text
from urb_jax.reporting.paper import ledger_json, read_ledger
from urb_jax.reporting.provenance import NOT_RECORDED, provenance
from urb_jax.runs.folder import source_commit
from urb_jax.runs.suite import SuiteRun, ledger_rows, run_suite
from urb_jax.runs.verify import report_lines, rows_to_verify, verify_folder, verify_rows


def _runs() -> list[SuiteRun]:
    """Two tiny baselines on fake SUMO days (the suite machinery is the same for train runs)."""
    return [SuiteRun("baseline", "aon", {"model": "aon", "task_conf": "test"}, {"executor": FakeDay()}),
            SuiteRun("baseline", "rnd", {"model": "random", "task_conf": "test"}, {"executor": FakeDay()})]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(the ledger file recording both runs as entry 'e', the folder holding them, their runs)."""
    root = tmp_path_factory.mktemp("verify")
    runs = _runs()
    folders = run_suite(runs, root / "machine1", progress=False, log=lambda _: None)
    ledger = root / "paper_runs.json"
    write_text(ledger, ledger_json(ledger_rows(folders).assign(entry="e")))
    return ledger, root, runs


def test_a_ledger_row_keeps_its_runs_provenance(recorded):
    ledger, root, _ = recorded
    text = ledger.read_text()
    row = next(r for r in json.loads(text)["runs"] if r["exp_id"] == "aon")
    prov = row["provenance"]
    assert prov["commit"] == source_commit()
    assert prov["machine"]["cpu_count"] and prov["versions"]["jax"]
    assert prov["request"] == NOT_RECORDED  # a baseline records no train request
    assert prov["overrides"] == [] and prov["human_phase_from"] is None
    assert prov["seeds_trained_together"] == prov["seed_axis"] == NOT_RECORDED  # no learner, no seed group
    assert prov["wall_time_s"] >= 0 and prov["date"].endswith("+00:00")  # exp_config.json's finished_at
    rnd = next(r for r in json.loads(text)["runs"] if r["exp_id"] == "rnd")
    assert rnd["provenance"]["human_phase_from"] == "aon"  # the suite replayed aon's human phase
    assert str(root) not in text  # no absolute path of this machine in the committed ledger


def test_a_train_runs_provenance_names_its_seed_group_and_axis(tmp_path):
    cfg = {"group": ["x_s0", "x_s1"], "seeds_together": 2, "seed_axis_used": "map",
           "finished_at": "2026-01-01T00:00:00+00:00"}
    prov = provenance(cfg, tmp_path / "exp_config.json")
    assert prov["seeds_trained_together"] == ["x_s0", "x_s1"] and prov["seed_axis"] == "map"


def test_verify_says_identical_when_rerun_unchanged_and_names_an_edited_metric(recorded):
    ledger, root, runs = recorded
    out = verify_folder(root / "machine2", "e")
    lines: list[str] = []
    checks = verify_rows(runs, rows_to_verify(read_ledger(ledger), "e", [], ledger), out, log=lines.append)
    assert [c.identical for c in checks] == [True, True]
    assert report_lines(checks) == ["aon: identical", "rnd: identical", "verify: 2 of 2 rows identical"]
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["aon", "rnd"]

    # a recorded metric edited by hand, and a row from before the ledger kept provenance
    edited = json.loads(ledger.read_text())
    row = next(r for r in edited["runs"] if r["exp_id"] == "aon")
    row["t_CAV"] += 0.001
    row.pop("provenance")
    changed = root / "edited_runs.json"
    changed.write_text(json.dumps(edited))
    checks = verify_rows(runs, rows_to_verify(read_ledger(changed), "e", ["aon"], changed), out,
                         log=lines.append)
    [check] = checks
    assert not check.identical and [m for m, _, _ in check.differences] == ["t_CAV"]
    report = report_lines(checks)
    assert report[0].startswith("aon: different: t_CAV ") and "recorded, " in report[0]
    assert report[1] == f"  recorded: commit {NOT_RECORDED}, machine {NOT_RECORDED}, finished {NOT_RECORDED}"
    assert report[2].startswith(f"  rerun:    commit {source_commit()}, machine ")
    assert report[-1] == "verify: 0 of 1 rows identical"


def test_verify_refuses_a_run_the_ledger_does_not_hold(recorded, capsys):
    from urb_jax.commands.cli import main

    ledger, root, _ = recorded
    rc = main(["suite", "scenario1", "--verify", "s1_saint_arnoult_iql_s0", "--ledger", str(ledger),
               "--results-dir", str(root / "r")])
    err = capsys.readouterr().err
    assert rc == 2 and str(ledger) in err and "scenario1" in err and "Fix:" in err
    assert not Path(root / "r").exists()
