import numpy as np

from urb_jax.city.routes import RouteParams
from urb_jax.city.scenario import load_scenario
from urb_jax.commands.cli import main


def test_agents_sorted_by_departure_and_views_consistent(grid_scenario):
    scn = grid_scenario
    assert (np.diff(scn.agent_depart) >= 0).all()
    assert sorted(scn.agent_id.tolist()) == list(range(scn.n_agents))
    assert scn.routes.shape == (scn.n_agents, scn.k, scn.od_routes.shape[2])
    assert (scn.fft <= scn.fft_full).all()
    assert scn.simulation_timesteps == int(scn.agent_depart.max())


def test_cache_roundtrip_is_identical(grid_scenario):
    again = load_scenario("urb_grid")  # from the cache
    fresh = load_scenario("urb_grid", use_cache=False, workers=1)
    for name in ("od_routes", "od_fft", "agent_id", "agent_depart", "edge_capacity"):
        assert np.array_equal(getattr(again, name), getattr(fresh, name))
        assert np.array_equal(getattr(grid_scenario, name), getattr(fresh, name))
    assert again.edge_ids == fresh.edge_ids and again.route_params == fresh.route_params


def test_seed_and_params_change_routes():
    a = load_scenario("urb_grid", env_seed=1, use_cache=False, workers=1)
    b = load_scenario("urb_grid", env_seed=2, use_cache=False, workers=1)
    c = load_scenario("urb_grid", env_seed=1, route_params=RouteParams(beta=-1.0), use_cache=False, workers=1)
    assert not np.array_equal(a.od_routes, b.od_routes) or not np.array_equal(a.od_routes, c.od_routes)


def test_capacity_from_marouter_table(grid_scenario):
    scn = grid_scenario
    i = scn.edge_ids.index("h0_1")  # arterial: 19.44 m/s, one lane -> 1200 veh/h
    j = scn.edge_ids.index("h0_0")  # side street: 11.11 m/s -> 1125 veh/h
    assert scn.edge_capacity[i] == 1200.0 and scn.edge_capacity[j] == 1125.0


def test_scenario_cli_writes_routes_csv(tmp_path, capsys):
    out = tmp_path / "routes.csv"
    assert main(["scenario", "--routes-csv", str(out)]) == 0
    import pandas as pd

    df = pd.read_csv(out)
    assert list(df.columns) == ["origins", "destinations", "path", "free_flow_time"]
    assert len(df) == 25 * 4
    assert '"agents": 400' in capsys.readouterr().out


def test_cached_scenario_points_at_the_copy_asked_for(tmp_path):
    """Two identical network folders share a cache entry (same contents), but each Scenario's
    net_file is its own folder's file: editing or deleting the first copy never changes which
    file SUMO reads for the second (issue: an edited original made SUMO load the wrong net)."""
    import shutil

    from urb_jax.core.paths import embedded_networks_dir

    a, b = tmp_path / "a" / "urb_grid", tmp_path / "b" / "urb_grid"
    shutil.copytree(embedded_networks_dir() / "urb_grid", a)
    shutil.copytree(embedded_networks_dir() / "urb_grid", b)
    first = load_scenario("urb_grid", networks_dir=a.parent)
    second = load_scenario("urb_grid", networks_dir=b.parent)  # served by the cache entry `a` built
    assert first.net_file == str(a / "urb_grid.net.xml")
    assert second.net_file == str(b / "urb_grid.net.xml")
    assert np.array_equal(first.od_routes, second.od_routes)
