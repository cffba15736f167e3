"""SUMO's emissions as first-class data: the SumoConfig option, the tripinfo parser, the day store's
keys, the records' columns, the emission metrics (hand-computed), the refusal where no SUMO runs,
and one real SUMO day against SUMO's own CLI run of the same day."""

from __future__ import annotations

import re
import subprocess
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from support.fakeday import FakeExecutor
from support.tiny_runs import tiny_iql_run, train_iql

from urb_jax.commands.cli import main
from urb_jax.core.errors import ConfigError, UrbJaxError
from urb_jax.reporting.day_export import day_routes_xml
from urb_jax.reporting.metrics import (
    EMISSION_SOCIAL_COLUMNS,
    SOCIAL_COLUMNS,
    emission_days,
    emission_metrics,
)
from urb_jax.reporting.records import SCHEMA, DayRecord, RecordsWriter, read_records, write_run_metrics
from urb_jax.runs import train as train_module
from urb_jax.sumo_bridge import ARRIVED, InProcessExecutor, SumoConfig, day_key, run_day
from urb_jax.sumo_bridge.memo import load_day, save_day
from urb_jax.sumo_bridge.tripinfo import parse_tripinfo
from urb_jax.sumo_bridge.types import DayResult
from urb_jax.training.human_phase import TRAIN_MUST_MATCH, ReplayHumanPhase, _checked_source

# Two trips as SUMO 1.28 writes them with the emission device (attributes shortened, and wrapped:
# XML allows it), the second removed (vaporized) on the way: its emissions are those up to the removal.
TRIPINFO_WITH_EMISSIONS = """<?xml version="1.0" encoding="UTF-8"?>
<!-- <emissions> <device.emissions.probability value="1"/> </emissions> -->
<tripinfos>
    <tripinfo id="7" depart="3.00" departDelay="1.00" arrival="140.00" duration="136.00"
              routeLength="2094.90" timeLoss="8.42" vType="Human" vaporized="">
        <emissions CO_abs="2673.17" CO2_abs="339066.94" HC_abs="18.05" PMx_abs="47.28"
                   NOx_abs="124.22" fuel_abs="109921.13" electricity_abs="0.00"/>
    </tripinfo>
    <tripinfo id="9" depart="5.00" departDelay="0.00" arrival="700.00" duration="695.00"
              routeLength="120.50" timeLoss="600.00" vType="AV" vaporized="byTeleport">
        <emissions CO_abs="10.00" CO2_abs="1500.50" HC_abs="0.10" PMx_abs="0.01" NOx_abs="0.50"
                   fuel_abs="480.25" electricity_abs="0.00"/>
    </tripinfo>
</tripinfos>
"""
TRIPINFO_PLAIN = """<tripinfos>
    <tripinfo id="7" depart="3.00" departDelay="1.00" arrival="140.00" duration="136.00"
              routeLength="2094.90" timeLoss="8.42" vaporized=""/>
    <tripinfo id="9" depart="5.00" departDelay="0.00" arrival="700.00" duration="695.00"
              routeLength="120.50" timeLoss="600.00" vaporized=""/>
</tripinfos>
"""


def test_tripinfo_parser_reads_the_emission_children(tmp_path):
    path = tmp_path / "trip.xml"
    path.write_text(TRIPINFO_WITH_EMISSIONS)
    trips = parse_tripinfo(path)
    assert set(trips) == {"7", "9"}
    assert trips["7"]["CO2_abs"] == 339066.94 and trips["7"]["fuel_abs"] == 109921.13
    assert trips["7"]["arrival"] == 140.0 and trips["7"]["vaporized"] == ""
    assert trips["9"]["CO2_abs"] == 1500.50 and trips["9"]["fuel_abs"] == 480.25
    assert trips["9"]["vaporized"] == "byTeleport" and trips["9"]["timeLoss"] == 600.0
    path.write_text(TRIPINFO_PLAIN)  # without the device: the same trips, no emission fields
    plain = parse_tripinfo(path)
    assert plain["9"]["routeLength"] == 120.5 and "CO2_abs" not in plain["7"] and "CO2_abs" not in plain["9"]


def test_the_option_adds_the_device_and_is_validated():
    assert "--device.emissions.probability" not in SumoConfig().sumo_args(1)
    args = SumoConfig(emissions=True).sumo_args(1)
    i = args.index("--device.emissions.probability")
    assert args[i + 1] == "1"
    with pytest.raises(ConfigError, match=r"key 'emissions' is 'yes'\. Fix: use true or false"):
        SumoConfig(emissions="yes")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"key 'extra_args' .* Fix: set 'emissions' true"):
        SumoConfig(extra_args=("--device.emissions.probability", "1"))


def test_the_day_store_keys_on_the_option(grid_scenario):
    """A day with emissions is never served for one without, nor the other way round."""
    scn = grid_scenario
    a = scn.fft.argmin(1)
    off = day_key(scn, a, 42, None, SumoConfig(), "libsumo 1.28.0")
    on = day_key(scn, a, 42, None, SumoConfig(emissions=True), "libsumo 1.28.0")
    assert off != on


def _day(n: int, co2=None, fuel=None):
    """A plain arrived day of `n` vehicles, with the given emissions (None: a day without)."""
    z = np.zeros(n)
    return DayResult(travel_time=z + 3.0, duration=z + 178.0, route_length=z + 1000.0, mean_speed=z + 5.6,
                     time_loss=z, depart_delay=z, status=np.full(n, ARRIVED, np.int8), seed=1,
                     stat_mean_speed=5.6, stat_mean_route_length=1000.0, stat_mean_duration=178.0,
                     teleports=0, n_removed=0, sim_end_time=200.0, wall_time=0.0, leave_time=z + 180.0,
                     co2_g=co2, fuel_mg=fuel)


def test_a_stored_day_keeps_its_emissions(tmp_path):
    day = _day(3, np.array([1.5, 2.0, np.nan]), np.array([500.0, 640.0, np.nan]))
    save_day(tmp_path / "d.npz", day, "k")
    back = load_day(tmp_path / "d.npz", "k")
    assert back.same_as(day)
    np.testing.assert_array_equal(back.co2_g, day.co2_g)
    plain = _day(3)
    save_day(tmp_path / "p.npz", plain, "k")
    assert load_day(tmp_path / "p.npz", "k").co2_g is None


def test_records_get_the_columns_only_when_asked(tmp_path):
    ids, od, dep = np.arange(2), np.zeros(2, np.int32), np.zeros(2, np.int32)
    cav = np.array([False, True])

    def write(folder: Path, emissions: bool, day) -> pd.DataFrame:
        w = RecordsWriter(folder, ids, od, dep, emissions=emissions)
        w.add(DayRecord(1, "human", np.zeros(2, int), cav, day, np.zeros(2), None))
        return pq.read_table(w.close()).to_pandas()

    plain = write(tmp_path / "a", False, _day(2, np.array([1.0, 2.0]), np.array([3.0, 4.0])))
    assert list(plain.columns) == SCHEMA.names  # the device's numbers are not URB's columns
    with_em = write(tmp_path / "b", True, _day(2, np.array([1.0, 2.0]), np.array([3.0, 4.0])))
    assert list(with_em.columns) == [*SCHEMA.names, "co2_g", "fuel_mg"]
    assert with_em["co2_g"].tolist() == [1.0, 2.0] and with_em["fuel_mg"].tolist() == [3.0, 4.0]
    with pytest.raises(ValueError, match="day 1 has no emissions"):
        write(tmp_path / "c", True, _day(2))


def _emission_records() -> pd.DataFrame:
    """Agents 0-2; agent 2 a CAV from day 3. H = 2 (days 1-2 pre-CAV), T = 1 (day 3), test days 4-5.
    CO2 (g) = 100 x agent + day; fuel (mg) = 10 x CO2; agent 1 never inserted on day 5 (NaN)."""
    rows = []
    for d in range(1, 6):
        for a in range(3):
            co2 = np.nan if (a == 1 and d == 5) else 100.0 * a + d
            rows.append({"day": d, "agent": a, "kind": "CAV" if (a == 2 and d > 2) else "HDV",
                         "travel_time": 3.0, "co2_g": np.float32(co2), "fuel_mg": np.float32(10 * co2)})
    return pd.DataFrame(rows)


def test_emission_metrics_hand_computed():
    per_day = emission_days(_emission_records()).set_index("episode")
    # day 1: 1 + 101 + 201, all humans; day 4: humans 4 + 104, the CAV 204; day 5: 5 + (none) + 205
    assert per_day.loc[1, "co2_g"] == 303.0 and per_day.loc[1, "co2_cav_g"] == 0.0
    assert per_day.loc[4, "co2_human_g"] == 108.0 and per_day.loc[4, "co2_cav_g"] == 204.0
    assert per_day.loc[5, "co2_g"] == 210.0 and per_day.loc[5, "fuel_human_mg"] == 50.0
    m = emission_metrics(_emission_records(), 2, 1)
    assert m["co2_test_g"] == 312.0 + 210.0
    assert m["co2_test_human_g"] == 108.0 + 5.0 and m["co2_test_cav_g"] == 204.0 + 205.0
    assert m["fuel_test_mg"] == 5220.0 and m["fuel_test_cav_mg"] == 4090.0
    assert m["co2_pre_day_g"] == (303.0 + 306.0) / 2 and m["co2_test_day_g"] == (312.0 + 210.0) / 2
    assert list(m) == EMISSION_SOCIAL_COLUMNS
    assert np.isnan(emission_metrics(_emission_records(), 2, 3)["co2_test_g"])  # no test day


def test_metric_files_keep_urbs_columns_and_bytes(tmp_path):
    """The emission columns are appended to SocialMetrics.csv and EmissionMetrics.csv is added; URB's
    two files are the bytes of the same run without emissions."""
    full = _emission_records().assign(phase="x", od=0, start_time=0, action=0, route_length=1000.0,
                                      speed=5.0, duration=178.0, time_loss=0.0, depart_delay=0.0, status=0,
                                      reward=0.0, sumo=True)
    for name, table in (("plain", full.drop(columns=["co2_g", "fuel_mg"])), ("emissions", full)):
        (tmp_path / name).mkdir()
        table.to_parquet(tmp_path / name / "records.parquet")
        write_run_metrics(tmp_path / name, 2, 1)
    plain, em = tmp_path / "plain" / "metrics", tmp_path / "emissions" / "metrics"
    for urb in ("BenchmarkMetrics.csv", "VectorMetrics.csv"):
        assert (plain / urb).read_bytes() == (em / urb).read_bytes()
    assert not (plain / "EmissionMetrics.csv").exists()
    assert pd.read_csv(plain / "SocialMetrics.csv").columns.tolist() == SOCIAL_COLUMNS
    social = pd.read_csv(em / "SocialMetrics.csv")
    assert social.columns.tolist() == [*SOCIAL_COLUMNS, *EMISSION_SOCIAL_COLUMNS]
    assert social["co2_test_g"].item() == 522.0
    assert pd.read_csv(em / "EmissionMetrics.csv")["co2_g"].tolist() == [303.0, 306.0, 309.0, 312.0, 210.0]


def test_a_replayed_human_phase_carries_the_emissions():
    rec = _emission_records().assign(action=0, route_length=1.0, speed=1.0, duration=1.0, time_loss=0.0,
                                     depart_delay=0.0, status=0)
    replay = ReplayHumanPhase(rec, np.arange(3), 2, FakeExecutor())
    (day,) = replay.run_days(None, np.zeros((1, 3), np.int64), [1])
    np.testing.assert_array_equal(day.co2_g, [1.0, 101.0, 201.0])
    np.testing.assert_array_equal(day.fuel_mg, [10.0, 1010.0, 2010.0])


def test_emissions_refused_where_no_sumo_runs_them(tmp_path, monkeypatch, capsys):
    """A run given the stand-in executor (no SUMO) cannot record emissions: exit 2 with the hybrid
    file, the key and the fix, before any results folder or day."""
    confs = tiny_iql_run(tmp_path)
    fake = FakeExecutor()
    monkeypatch.setattr(train_module, "run_train", partial(train_module.run_train, executor=fake))
    code = main(["train", "--alg", "iql", "--task-conf", confs["task_conf"], "--hybrid-conf",
                 confs["hybrid_conf"], "--alg-conf", confs["alg_conf"], "--results-dir", str(tmp_path / "r"),
                 "--no-progress", "--set", "hybrid.emissions=true"])
    err = capsys.readouterr().err
    assert code == 2
    assert f"hybrid config {tmp_path / 'hyb.json'}: key 'emissions' is true" in err
    assert "FakeExecutor" in err and "Fix: set 'emissions' false" in err
    assert not fake.batches and not (tmp_path / "r").exists()


def _cli_emissions(scn, choices, is_cav, seed, tmp: Path) -> dict[str, tuple[float, float]]:
    """SUMO's one-shot CLI run of the same day with the emission device: {id: (CO2 mg, fuel mg)}."""
    import os

    import sumo

    rou = tmp / "day.rou.xml"
    rou.write_text(day_routes_xml(scn, choices, is_cav))
    subprocess.run(
        [os.path.join(sumo.SUMO_HOME, "bin", "sumo"), "-n", scn.net_file, "-r", str(rou), "--seed", str(seed),
         "--time-to-teleport", "-1", "--no-step-log", "true", "--no-warnings", "true",
         "--device.emissions.probability", "1", "--tripinfo-output", str(tmp / "trip.xml")],
        check=True, timeout=300,
    )
    text = (tmp / "trip.xml").read_text()
    found = re.finditer(r'<tripinfo id="([^"]*)"[^>]*>\s*<emissions [^>]*'
                        r'CO2_abs="([^"]*)"[^>]*fuel_abs="([^"]*)"', text)
    return {m[1]: (float(m[2]), float(m[3])) for m in found}


@pytest.mark.sumo
def test_a_real_day_with_emissions_matches_the_cli(grid_scenario, tmp_path):
    """The embedded default network: every arrived vehicle emitted CO2, the numbers are SUMO CLI's for
    the same day, and the device changes nothing else of the day."""
    scn = grid_scenario
    rng = np.random.default_rng(5)
    choices = rng.integers(0, scn.k, size=scn.n_agents)
    is_cav = rng.random(scn.n_agents) < 0.4
    day = run_day(scn, choices, seed=7, is_cav=is_cav, config=SumoConfig(emissions=True))
    plain = run_day(scn, choices, seed=7, is_cav=is_cav)
    arrived = day.status == ARRIVED
    assert arrived.all() and day.co2_g is not None and day.fuel_mg is not None
    assert (day.co2_g[arrived] > 0).all() and (day.fuel_mg[arrived] > 0).all()
    assert plain.co2_g is None and plain.fuel_mg is None
    np.testing.assert_array_equal(day.travel_time, plain.travel_time)
    np.testing.assert_array_equal(day.route_length, plain.route_length)
    cli = _cli_emissions(scn, choices, is_cav, 7, tmp_path)
    ids = [str(a) for a in scn.agent_id]
    assert set(cli) == set(ids)
    np.testing.assert_allclose(day.co2_g, [cli[v][0] / 1000 for v in ids], rtol=0, atol=1e-9)
    np.testing.assert_allclose(day.fuel_mg, [cli[v][1] for v in ids], rtol=0, atol=1e-9)


def test_a_reused_human_phase_must_match_the_emissions(tmp_path):
    """A source run's human days carry emissions exactly when this run's do; a run from before the
    key recorded none (off)."""
    this = {k: 1 for k in TRAIN_MUST_MATCH} | {"hybrid_emissions": True}
    (tmp_path / "exp_config.json").write_text(pd.Series(this | {"hybrid_emissions": False}).to_json())
    with pytest.raises(UrbJaxError, match=r"hybrid_emissions \(source False, this run True\)"):
        _checked_source(tmp_path, this, TRAIN_MUST_MATCH)
    older = {k: v for k, v in this.items() if k != "hybrid_emissions"}
    (tmp_path / "exp_config.json").write_text(pd.Series(older).to_json())
    _checked_source(tmp_path, this | {"hybrid_emissions": False}, TRAIN_MUST_MATCH)


@pytest.mark.sumo
@pytest.mark.slow
def test_a_real_run_with_emissions_keeps_urbs_files_and_reuses_its_human_phase(tmp_path):
    """The tiny IQL run on urb_grid in SUMO, without and with emissions: URB's metric files are the same
    bytes, the records the same plus co2_g and fuel_mg (positive for every arrived trip); a run reusing
    its human phase replays the emissions, and one without emissions may not reuse it."""
    confs = tiny_iql_run(tmp_path)

    def train(exp_id: str, emissions: bool, **request):
        ex = InProcessExecutor(SumoConfig(emissions=emissions))
        try:
            overrides = ("hybrid.emissions=true",) if emissions else ()
            (out,) = train_iql(confs, tmp_path, exp_id, executor=ex, overrides=overrides, **request)
        finally:
            ex.close()
        return out.folder

    off, on = train("off", False), train("on", True)
    for name in ("BenchmarkMetrics.csv", "VectorMetrics.csv"):
        assert (on / "metrics" / name).read_bytes() == (off / "metrics" / name).read_bytes()
    social = pd.read_csv(on / "metrics" / "SocialMetrics.csv")
    pd.testing.assert_frame_equal(social[SOCIAL_COLUMNS], pd.read_csv(off / "metrics" / "SocialMetrics.csv"))
    rec_on = read_records(on)
    pd.testing.assert_frame_equal(rec_on.drop(columns=["co2_g", "fuel_mg"]), read_records(off))
    arrived = rec_on["status"] == ARRIVED
    assert (rec_on.loc[arrived, "co2_g"] > 0).all() and (rec_on.loc[arrived, "fuel_mg"] > 0).all()
    again = train("again", True, human_phase_from="on")
    pd.testing.assert_frame_equal(read_records(again), rec_on)
    with pytest.raises(UrbJaxError, match="hybrid_emissions"):
        train("without", False, human_phase_from="on")
