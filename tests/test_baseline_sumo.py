"""A short real SUMO baseline run on the embedded urb_grid network (H=5, 2 training, 3 test days)."""

import numpy as np
import pandas as pd
import pytest

from urb_jax.reporting.records import read_records
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.request import BaselineRequest

pytestmark = pytest.mark.sumo


def test_aon_baseline_on_sumo(tmp_path, grid_scenario, capsys):
    from urb_jax.sumo_bridge import run_day

    out = run_baseline(BaselineRequest(model="aon", results_dir=str(tmp_path), progress=False),
                       task_overrides={"human_learning_episodes": 5, "training_eps": 2, "test_eps": 3})
    rec = read_records(out.folder)
    assert (out.folder / "sumo.log").exists()  # SUMO's messages are kept with the run
    assert sorted(rec["day"].unique()) == list(range(1, 11)) and rec["sumo"].all()
    assert (rec["travel_time"] > 0).all() and (rec.loc[rec.status == 0, "speed"] > 0).all()
    # records hold what SUMO returns: re-simulating day 1's choices gives the same times
    d1 = rec[rec.day == 1].set_index("agent").loc[grid_scenario.agent_id]
    again = run_day(grid_scenario, d1["action"].to_numpy(), seed=42,
                    is_cav=np.zeros(grid_scenario.n_agents, bool))
    np.testing.assert_allclose(d1["travel_time"].to_numpy(), again.travel_time, rtol=1e-6)
    # AON CAVs drive the minimum free-flow route on every post-mutation day
    cav = rec[(rec.day > 5) & (rec.kind == "CAV")].merge(
        pd.DataFrame({"agent": grid_scenario.agent_id,
                      "aon": np.argmin(np.where(grid_scenario.route_valid, grid_scenario.fft, np.inf), 1)}))
    assert len(cav) == 5 * int(0.4 * grid_scenario.n_agents) and (cav["action"] == cav["aon"]).all()
    m = out.metrics
    t_pre = rec[rec.day <= 5].groupby("day")["travel_time"].mean().mean()
    assert m["t_pre"] == pytest.approx(t_pre, rel=1e-5)
    assert 1.0 < m["t_CAV"] < 30.0 and m["winrate"] in (0.0, 1.0)
    # the last (test) day exported as a routes file: SUMO's own CLI replays it to the recorded times
    _check_export_replays(out.folder, grid_scenario, tmp_path, capsys)


def _check_export_replays(folder, scn, tmp_path, capsys):
    import json

    from urb_jax.commands.cli import main
    from urb_jax.reporting.day_export import cli_travel_times

    rou = tmp_path / "last.rou.xml"
    capsys.readouterr()
    assert main(["export-day", str(folder), "--out", str(rou)]) == 0
    info = json.loads(capsys.readouterr().out)
    rec = read_records(folder)
    last = rec[rec.day == rec.day.max()].set_index("agent").loc[scn.agent_id]
    assert info["day"] == 10 and info["cavs"] == int((last["kind"] == "CAV").sum()) > 0
    np.testing.assert_allclose(cli_travel_times(scn, rou, 42), last["travel_time"].to_numpy(), rtol=1e-6)
    # a day that is not in the records is a clear error naming the fix
    assert main(["export-day", str(folder), "--day", "99", "--out", str(tmp_path / "x.rou.xml")]) == 2
    assert "--day" in capsys.readouterr().err
