"""`urb-jax headroom` on a tiny finished run: a real SUMO AON baseline on the embedded urb_grid
(5 human days, 2 training, 3 test days, as tests/test_baseline_sumo.py)."""

from __future__ import annotations

import pytest

from urb_jax.commands.cli import main
from urb_jax.runs.request import BaselineRequest

pytestmark = pytest.mark.sumo


@pytest.fixture(scope="module")
def aon_run(tmp_path_factory):
    from urb_jax.runs.baseline import run_baseline

    return run_baseline(BaselineRequest(model="aon", results_dir=str(tmp_path_factory.mktemp("headroom")),
                                        progress=False), task_overrides={"human_learning_episodes": 5,
                                                                         "training_eps": 2, "test_eps": 3})


def _rows(out: str) -> dict[str, list[float]]:
    """The printed table's rows: name -> [t_CAV] or [t_CAV, t_HDV]."""
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in out.splitlines()
             if line.startswith("| ") and "SUMO day" not in line]
    return {c[0]: [float(x) for x in c[1:] if x] for c in cells}


def test_headroom_of_an_aon_run(aon_run, capsys):
    capsys.readouterr()
    assert main(["headroom", str(aon_run.folder), "--deviations", "1", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("unilateral deviations, 1 CAVs") and "selfish:" in out and "team:" in out
    assert f"CAVs, run {aon_run.folder}" in out and "urb_grid: " in out
    rows = _rows(out)
    assert list(rows) == ["t_pre (all agents, last 50 human days)",
                          "CAVs pre-mutation (same agents as humans)", "policy (test day 10 replayed)",
                          "AON, same humans",
                          "CAVs only, policy routes (no humans)", "CAVs only, AON routes (no humans)"]
    assert rows["t_pre (all agents, last 50 human days)"][0] == pytest.approx(aon_run.metrics["t_pre"],
                                                                             abs=1e-4)
    # the run's policy is AON: its replayed test day is the AON day, with and without the humans
    assert rows["policy (test day 10 replayed)"] == rows["AON, same humans"]
    assert rows["policy (test day 10 replayed)"][0] == pytest.approx(aon_run.metrics["t_CAV"], abs=1e-4)
    assert rows["CAVs only, policy routes (no humans)"] == rows["CAVs only, AON routes (no humans)"]


def test_headroom_of_a_folder_that_is_no_run_exits_2(tmp_path, capsys):
    assert main(["headroom", str(tmp_path)]) == 2
    assert "exp_config.json: not found" in capsys.readouterr().err
