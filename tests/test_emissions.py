"""SUMO's emissions as first-class data: the SumoConfig option, the tripinfo parser, the day store's
keys, and one real SUMO day against SUMO's own CLI run of the same day."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from urb_jax.core.errors import ConfigError
from urb_jax.reporting.day_export import day_routes_xml
from urb_jax.sumo_bridge import ARRIVED, SumoConfig, day_key, run_day
from urb_jax.sumo_bridge.memo import load_day, save_day
from urb_jax.sumo_bridge.tripinfo import parse_tripinfo
from urb_jax.sumo_bridge.types import DayResult

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
