"""Agents whose OD pair has no route: found on the route graph before sampling, refused by default
(URB stops on them), left out and recorded with --drop-unroutable; sampling in parallel changes no
route."""

import json
import shutil
import time
from pathlib import Path

import networkx as nx
import pytest
from support.fakeday import FakeDay

from urb_jax.city import scenario as scenario_module
from urb_jax.city.network import find_network, read_demand
from urb_jax.city.netxml import read_net
from urb_jax.city.routes import RouteParams, build_route_graph, generate_routes, unroutable
from urb_jax.city.scenario import load_scenario
from urb_jax.commands.cli import main
from urb_jax.core.errors import NetworkError
from urb_jax.core.paths import cache_dir, embedded_networks_dir
from urb_jax.reporting.day_export import scenario_of_run
from urb_jax.runs.baseline import run_baseline
from urb_jax.runs.request import BaselineRequest

TINY = {"human_learning_episodes": 3, "training_eps": 2, "test_eps": 2}


@pytest.fixture
def broken_grid(tmp_path: Path) -> Path:
    """urb_grid whose exit out_e0 is replaced by the entry in_w0, which no road leads into."""
    dst = tmp_path / "nets" / "urb_grid"
    shutil.copytree(embedded_networks_dir() / "urb_grid", dst)
    od = dst / "od_urb_grid.txt"
    od.write_text(od.read_text().replace("'out_e0'", "'in_w0'"))
    return dst


def _unroutable_ids(folder: Path) -> list[int]:
    """Agents with no path, by networkx's own search (independent of `unroutable`); an OD from an
    edge to itself has none either (JanuX's walk never returns to its start)."""
    files = find_network(str(folder))
    net = read_net(files.net)
    demand = read_demand(files, net)
    graph = build_route_graph(net)
    return sorted(int(a) for a, o, d in zip(demand.agent_id, demand.origin, demand.destination, strict=True)
                  if demand.origins[o] == demand.destinations[d]
                  or not nx.has_path(graph, demand.origins[o], demand.destinations[d]))


def test_unroutable_agrees_with_has_path(broken_grid):
    net = read_net(find_network(str(broken_grid)).net)
    graph = build_route_graph(net)
    edges = sorted(graph.nodes)[::7]
    pairs = [(o, d) for o in edges for d in edges] + [("nowhere", edges[0])]
    bad = unroutable(graph, pairs)
    assert "no connection" in bad[len(pairs) - 1]
    assert set(bad) == {i for i, (o, d) in enumerate(pairs)
                        if o not in graph or o == d or not nx.has_path(graph, o, d)}


def test_default_refuses_naming_file_ids_and_fix(broken_grid, capsys):
    expected = _unroutable_ids(broken_grid)
    assert expected
    assert main(["scenario", "--net", str(broken_grid), "--no-cache"]) == 2
    err = capsys.readouterr().err
    assert "agents.csv" in err and "--drop-unroutable" in err
    assert f"all agent ids: {' '.join(map(str, expected))}" in err


def test_drop_leaves_out_exactly_the_unroutable_agents(broken_grid):
    expected = _unroutable_ids(broken_grid)
    scn = load_scenario(str(broken_grid), drop_unroutable=True, use_cache=False, workers=1)
    assert scn.dropped_unroutable.tolist() == expected
    every = read_demand(find_network(str(broken_grid))).agent_id
    assert sorted(scn.agent_id.tolist()) == sorted(set(every.tolist()) - set(expected))
    assert scn.dropped_record() == {"count": len(expected), "ids": expected}
    # Routes are seeded per OD pair, so the kept pairs have the routes the intact network gives them.
    intact = load_scenario("urb_grid", use_cache=False, workers=1)
    index = {(intact.od_origin_edge[j], intact.od_destination_edge[j]): j for j in range(intact.n_od)}
    for i in range(scn.n_od):
        j = index[scn.od_origin_edge[i], scn.od_destination_edge[i]]
        assert [scn.route_edge_ids(i, k) for k in range(scn.k)] == [
            intact.route_edge_ids(j, k) for k in range(intact.k)]


def test_cache_keys_differ_with_the_choice_where_it_matters(broken_grid, tmp_path, monkeypatch):
    monkeypatch.setenv("URB_JAX_CACHE", str(tmp_path / "cache"))
    load_scenario(str(broken_grid), drop_unroutable=True)
    with pytest.raises(NetworkError, match="no route"):  # not served from the dropped entry
        load_scenario(str(broken_grid))
    plain = load_scenario("urb_grid")

    def no_build(*args, **kwargs):
        raise AssertionError("rebuilt although the cache holds the same scenario")

    monkeypatch.setattr(scenario_module, "build_scenario", no_build)
    dropped = load_scenario("urb_grid", drop_unroutable=True)  # nothing to drop: the plain entry serves
    assert dropped.agent_id.tolist() == plain.agent_id.tolist() and dropped.dropped_unroutable.size == 0
    assert len(list((cache_dir() / "scenarios").glob("urb_grid-*.npz"))) == 2  # broken_grid + plain
    cached = load_scenario(str(broken_grid), drop_unroutable=True)
    assert cached.dropped_unroutable.tolist() == _unroutable_ids(broken_grid)


def test_baseline_records_dropped_agents_in_exp_config(broken_grid, tmp_path, caplog):
    expected = _unroutable_ids(broken_grid)
    out = run_baseline(BaselineRequest(model="aon", net=str(broken_grid), results_dir=str(tmp_path / "res"),
                                       progress=False,
                                       drop_unroutable=True), executor=FakeDay(), task_overrides=TINY)
    cfg = json.loads((out.folder / "exp_config.json").read_text())
    assert cfg["drop_unroutable"] is True
    assert cfg["dropped_unroutable_agents"] == {"count": len(expected), "ids": expected}
    assert cfg["num_agents"] == 400 - len(expected)
    assert f"left out {len(expected)} agent(s)" in caplog.text
    rebuilt = scenario_of_run(out.folder, networks_dir=str(broken_grid.parent))  # what export-day reads
    assert rebuilt.dropped_unroutable.tolist() == expected and rebuilt.n_agents == cfg["num_agents"]


def test_parallel_sampling_gives_identical_routes():
    net = read_net(find_network("urb_grid").net)
    demand = read_demand(find_network("urb_grid"), net)
    graph = build_route_graph(net)
    pairs = [(o, d) for o in demand.origins for d in demand.destinations]
    assert len(pairs) >= 32  # below that generate_routes stays in this process
    (one,) = generate_routes(graph, pairs, RouteParams(), 42, workers=1)
    (two,) = generate_routes(graph, pairs, RouteParams(), 42, workers=2)
    assert one == two


@pytest.mark.real_networks
def test_mantes_fails_fast_naming_its_35_agents(real_networks_dir, monkeypatch):
    """mantes_la_jolie: 35 agents start or end on bus/bicycle-only edges; they are named from the
    route graph alone, and --drop-unroutable samples the other 4,108 pairs."""
    def no_sampling(graph, od_edges, params, seed, workers=1):
        raise AssertionError(len(od_edges))

    monkeypatch.setattr(scenario_module, "generate_routes", no_sampling)
    t0 = time.perf_counter()
    with pytest.raises(NetworkError, match=r"35 OD pair\(s\) have no route.*35 agent\(s\)") as err:
        load_scenario("mantes_la_jolie", networks_dir=real_networks_dir, use_cache=False)
    assert time.perf_counter() - t0 < 60  # ~1.5 s on a quiet machine (was minutes)
    assert "all agent ids: 157 336 681 " in str(err.value) and "agents.csv" in str(err.value)
    with pytest.raises(AssertionError, match=r"^4108$"):
        load_scenario("mantes_la_jolie", networks_dir=real_networks_dir, use_cache=False,
                      drop_unroutable=True)
