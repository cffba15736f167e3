"""Synthetic cities (networks/synthetic.py): URB-valid folders, the embedded urb_grid reproduced,
seeded demand, and the sizing rule (agents per lane-km) checked against the net netconvert built."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from urb_jax.city.network import describe, find_network, read_demand
from urb_jax.city.netxml import read_net
from urb_jax.city.scenario import load_scenario
from urb_jax.core.paths import embedded_networks_dir
from urb_jax.networks.synthetic import URB_GRID, city_for_agents, generate, lane_km, zones


def _without_header(path: Path) -> str:
    return re.sub(r"<!--.*?-->", "", path.read_text(), count=1, flags=re.S)


@pytest.fixture(scope="module")
def small_city(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate(city_for_agents(200, "synth_200"), tmp_path_factory.mktemp("nets"))


def test_urb_grid_is_reproduced(tmp_path: Path) -> None:
    """The shipped urb_grid is URB_GRID's output: the same demand and od file byte for byte, the same
    net apart from netconvert's dated header (which names its temporary input files)."""
    folder = generate(URB_GRID, tmp_path)
    shipped = embedded_networks_dir() / "urb_grid"
    for name in ("agents.csv", "od_urb_grid.txt"):
        assert (folder / name).read_bytes() == (shipped / name).read_bytes(), name
    assert _without_header(folder / "urb_grid.net.xml") == _without_header(shipped / "urb_grid.net.xml")


def test_regenerating_in_place_leaves_files_untouched(tmp_path: Path) -> None:
    folder = generate(URB_GRID, tmp_path)
    net = folder / "urb_grid.net.xml"
    before = net.read_bytes()
    generate(URB_GRID, tmp_path)
    assert net.read_bytes() == before  # the dated header too: git sees no change


def test_small_city_is_a_valid_urb_network(small_city: Path) -> None:
    files = find_network(small_city.name, small_city.parent)
    info = describe(files)  # validates agents.csv against the od file and the net
    assert info.agents == 200
    demand = read_demand(files, read_net(files.net))
    cfg = city_for_agents(200, "synth_200")
    # the od file lists the fringe entries/exits and then one origin and destination per zone
    n_fringe = cfg.rows + len(range(1, cfg.cols, 2))
    assert len(demand.origins) == len(demand.destinations) == n_fringe + len(zones(cfg))
    assert demand.origins[n_fringe:] == tuple(f"h{c}_{r}" for c, r in zones(cfg))
    interior = demand.origin >= n_fringe
    assert 0.65 < interior.mean() < 0.95  # interior_share 0.8
    assert ((demand.destination >= n_fringe) == interior).all()  # zone trips end in zones
    assert demand.start_time.min() >= 0 and demand.start_time.max() <= cfg.window_s
    # every OD pair has routes (the scenario build fails on an unroutable pair)
    scn = load_scenario(small_city.name, networks_dir=small_city.parent, workers=1)
    assert scn.n_agents == 200 and bool(scn.od_route_valid[:, 0].all())


def test_demand_is_seeded(small_city: Path, tmp_path: Path) -> None:
    again = generate(city_for_agents(200, "synth_200"), tmp_path / "a")
    other = generate(dataclasses.replace(city_for_agents(200, "synth_200"), seed=7), tmp_path / "b")
    for name in ("agents.csv", "od_synth_200.txt"):
        assert (again / name).read_bytes() == (small_city / name).read_bytes()
    assert (other / "agents.csv").read_bytes() != (small_city / "agents.csv").read_bytes()


def test_lane_km_matches_the_built_net(small_city: Path) -> None:
    """lane_km (the sizing rule's denominator) against netconvert's lanes: within the length lost
    to junctions (netconvert shortens each edge by its junctions' size)."""
    net = read_net(small_city / "synth_200.net.xml")
    grid = np.array([not e.startswith(("in_", "out_")) for e in net.edge_ids])
    built = float((net.length * net.lanes)[grid].sum()) / 1000
    assert 0.85 < built / lane_km(city_for_agents(200, "synth_200")) <= 1.0


@pytest.mark.parametrize("agents", [1000, 10000, 50000])
def test_grid_grows_with_agents_at_constant_density(agents: int) -> None:
    cfg = city_for_agents(agents, "x")
    assert 10 < agents / lane_km(cfg) < 16
    assert 1.3 < cfg.cols / cfg.rows < 1.7
