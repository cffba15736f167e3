"""Routes are JanuX's, and valid in the SUMO network (checked independently with sumolib)."""

import itertools
import logging

import networkx as nx
import numpy as np
import pytest
import sumolib
from janux.path_generators.extended_generator import ExtendedPathGenerator

from urb_jax.city.network import find_network, read_demand
from urb_jax.city.netxml import read_net
from urb_jax.city.routes import RouteParams, build_route_graph, generate_od_routes, graph_adjacency
from urb_jax.city.scenario import load_scenario


def _janux(graph, origin, destination, seed):
    params = RouteParams()
    gen = ExtendedPathGenerator(
        graph, [origin], [destination], number_of_paths=params.number_of_paths, beta=params.beta,
        num_samples=params.num_samples, max_path_length=params.max_path_length, random_seed=seed,
        verbose=False,
    )
    return [tuple(r) for r in gen.generate_routes(as_df=False)[(0, 0)]]


def _od_edges(name, networks_dir=None):
    files = find_network(name, networks_dir)
    net = read_net(files.net)
    demand = read_demand(files, net)
    pairs = sorted({(int(o), int(d)) for o, d in zip(demand.origin, demand.destination, strict=True)})
    return net, [(demand.origins[o], demand.destinations[d]) for o, d in pairs]


@pytest.mark.parametrize("seed", [42, 0])
def test_identical_to_janux_on_embedded(seed):
    net, ods = _od_edges("urb_grid")
    graph = build_route_graph(net)
    adj = graph_adjacency(graph)
    for origin, destination in ods:
        ours = generate_od_routes(graph, origin, destination, RouteParams(), seed, adj)
        assert list(ours.routes) == _janux(graph, origin, destination, seed)


def test_identical_to_janux_on_saint_arnoult(real_networks_dir):
    net, ods = _od_edges("saint_arnoult", real_networks_dir)
    graph = build_route_graph(net)
    adj = graph_adjacency(graph)
    rng = np.random.default_rng(1)
    for i in rng.choice(len(ods), size=8, replace=False):
        origin, destination = ods[i]
        ours = generate_od_routes(graph, origin, destination, RouteParams(), 42, adj)
        assert list(ours.routes) == _janux(graph, origin, destination, 42), (origin, destination)


def test_fewer_distinct_routes_are_padded_and_masked():
    graph = nx.DiGraph()
    for u, v in [("o", "a"), ("a", "d"), ("o", "b"), ("b", "d")]:  # exactly two o->d routes
        graph.add_edge(u, v, travel_time=1.0)
    res = generate_od_routes(graph, "o", "d", RouteParams(max_attempts=500), 42)
    assert res.n_distinct == 2
    assert len(res.routes) == 4 and len(set(res.routes)) == 2
    assert res.routes[2] == res.routes[3] == res.routes[1]


def _check_routes_in_sumo(scn):
    """Independent check with sumolib's own parser: connectivity, endpoints, loops, FFT."""
    net = sumolib.net.readNet(scn.net_file)
    for od in range(scn.n_od):
        for k in range(scn.k):
            edges = scn.route_edge_ids(od, k)
            assert edges[0] == scn.od_origin_edge[od]
            assert edges[-1] == scn.od_destination_edge[od]
            assert len(set(edges)) == len(edges), f"repeated edge in od {od} route {k}"
            sumo_edges = [net.getEdge(e) for e in edges]
            for a, b in itertools.pairwise(sumo_edges):
                assert b in a.getOutgoing(), f"{a.getID()} -> {b.getID()} is not a connection"
                assert a.allows("passenger")
            fft = sum(e.getLength() / e.getSpeed() for e in sumo_edges[:-1]) / 60.0
            assert scn.od_fft[od, k] == pytest.approx(fft, rel=1e-9)
            full = fft + sumo_edges[-1].getLength() / sumo_edges[-1].getSpeed() / 60.0
            assert scn.od_fft_full[od, k] == pytest.approx(full, rel=1e-9)
            assert scn.od_route_length[od, k] == pytest.approx(sum(e.getLength() for e in sumo_edges))


def test_embedded_routes_valid(grid_scenario):
    assert grid_scenario.k == 4 and grid_scenario.od_route_valid.all()
    _check_routes_in_sumo(grid_scenario)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["saint_arnoult", "provins", "ingolstadt_custom"])
def test_real_network_routes_valid(name, real_networks_dir):
    scn = load_scenario(name, networks_dir=real_networks_dir, workers=2)
    assert scn.routes.shape[:2] == (scn.n_agents, 4)
    _check_routes_in_sumo(scn)


def test_short_od_is_reported(caplog, tmp_path, monkeypatch):
    """A build with an OD of fewer distinct routes than K warns (never silent)."""
    from urb_jax.city import scenario as scenario_mod

    real = scenario_mod.generate_routes

    def fewer(graph, od_edges, params, seed, workers=1):
        return real(graph, od_edges, RouteParams(number_of_paths=12, max_attempts=2000), seed, workers=1)

    monkeypatch.setattr(scenario_mod, "generate_routes", fewer)
    with caplog.at_level(logging.WARNING):
        scn = load_scenario("urb_grid", use_cache=False, route_params=RouteParams(number_of_paths=12))
    assert (~scn.od_route_valid).any()
    assert "fewer than 12 distinct routes" in caplog.text
