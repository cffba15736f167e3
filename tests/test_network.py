import shutil
from pathlib import Path

import pytest

from urb_jax.city.network import describe, find_network, read_demand
from urb_jax.city.netxml import read_net
from urb_jax.city.scenario import load_scenario
from urb_jax.commands.cli import main
from urb_jax.core.errors import NetworkError
from urb_jax.core.paths import embedded_networks_dir


@pytest.fixture
def grid_copy(tmp_path: Path) -> Path:
    dst = tmp_path / "nets" / "urb_grid"
    shutil.copytree(embedded_networks_dir() / "urb_grid", dst)
    return dst


def _rewrite_agents(folder: Path, row: int, field: str, value: str) -> None:
    """`row` is the 0-based index into the file's lines (0 = header)."""
    path = folder / "agents.csv"
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[row].split(",")
    cells[header.index(field)] = value
    lines[row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def test_embedded_default_network_is_found_and_valid():
    files = find_network("urb_grid")
    info = describe(files)
    assert (info.agents, info.od_pairs) == (400, 25)
    assert files.folder == embedded_networks_dir() / "urb_grid"


def test_missing_network_names_search_path_and_fix(tmp_path):
    with pytest.raises(NetworkError) as err:
        find_network("atlantis", tmp_path)
    msg = str(err.value)
    assert "atlantis" in msg and str(tmp_path) in msg and "--networks-dir" in msg and "urb_grid" in msg


def test_missing_file_is_named(grid_copy):
    (grid_copy / "agents.csv").unlink()
    with pytest.raises(NetworkError, match=r"agents\.csv: missing demand file"):
        find_network(str(grid_copy))


def test_index_out_of_range_names_row_and_field(grid_copy):
    _rewrite_agents(grid_copy, 3, "destination", "99")
    files = find_network(str(grid_copy))
    with pytest.raises(NetworkError) as err:
        read_demand(files)
    msg = str(err.value)
    assert "agents.csv" in msg and "line 4" in msg and "'destination'" in msg and "99" in msg
    assert "0..6" in msg


def test_edge_not_in_net_names_od_file_and_position(grid_copy):
    od = grid_copy / "od_urb_grid.txt"
    od.write_text(od.read_text().replace("'in_w2'", "'no_such_edge'"))
    files = find_network(str(grid_copy))
    with pytest.raises(NetworkError) as err:
        read_demand(files, read_net(files.net))
    msg = str(err.value)
    assert "od_urb_grid.txt" in msg and "origins'[2]" in msg and "no_such_edge" in msg


def test_non_integer_time_is_reported(grid_copy):
    _rewrite_agents(grid_copy, 5, "start_time", "12.5")
    with pytest.raises(NetworkError, match=r"line 6, field 'start_time': '12.5' is not an integer"):
        read_demand(find_network(str(grid_copy)))


def test_integral_float_time_is_accepted(grid_copy):
    _rewrite_agents(grid_copy, 5, "start_time", "120.0")
    demand = read_demand(find_network(str(grid_copy)))
    assert demand.start_time[4] == 120  # line 5 is the 5th agent


def test_duplicate_ids_are_reported(grid_copy):
    _rewrite_agents(grid_copy, 4, "id", "0")
    with pytest.raises(NetworkError, match=r"field 'id': duplicate id 0 on lines \[2, 5\]"):
        read_demand(find_network(str(grid_copy)))


def test_missing_column_is_reported(grid_copy):
    path = grid_copy / "agents.csv"
    path.write_text(path.read_text().replace("start_time", "departure", 1))
    with pytest.raises(NetworkError, match=r"missing column.*start_time"):
        read_demand(find_network(str(grid_copy)))


def test_od_file_must_be_a_literal(grid_copy):
    (grid_copy / "od_urb_grid.txt").write_text("origins = ['a']")
    with pytest.raises(NetworkError, match="not a Python literal"):
        read_demand(find_network(str(grid_copy)))


def test_columns_are_read_by_name(grid_copy):
    """Ingolstadt orders the columns id,start_time,origin,destination,kind."""
    path = grid_copy / "agents.csv"
    rows = [line.split(",") for line in path.read_text().splitlines()]
    reordered = [[r[0], r[3], r[1], r[2], r[4]] for r in rows]
    path.write_text("\n".join(",".join(r) for r in reordered) + "\n")
    a = read_demand(find_network(str(grid_copy)))
    b = read_demand(find_network("urb_grid"))
    assert (a.start_time == b.start_time).all() and (a.origin == b.origin).all()


def test_unreachable_od_names_the_agents(grid_copy):
    # in_w0 is an entry edge: nothing leads into it, so no route can end there.
    od = grid_copy / "od_urb_grid.txt"
    od.write_text(od.read_text().replace("'out_e0'", "'in_w0'"))
    with pytest.raises(NetworkError) as err:
        load_scenario(str(grid_copy), use_cache=False, workers=1)
    msg = str(err.value)
    assert "no route" in msg and "agents" in msg and "in_w0" in msg


def test_unroutable_pairs_are_found_on_the_graph_before_sampling(grid_copy, monkeypatch):
    """The route-graph check names the agents without sampling a single route."""
    from urb_jax.city import scenario as scenario_module

    od = grid_copy / "od_urb_grid.txt"
    od.write_text(od.read_text().replace("'out_e0'", "'in_w0'"))

    def no_sampling(*args, **kwargs):
        raise AssertionError("routes were sampled before the unroutable pairs were reported")

    monkeypatch.setattr(scenario_module, "generate_routes", no_sampling)
    message = r"(?s)agents.csv: \d+ OD pair\(s\) have no route.*all agent ids: \d"
    with pytest.raises(NetworkError, match=message):
        load_scenario(str(grid_copy), use_cache=False, workers=1)


def test_search_order_flag_then_env_then_embedded(tmp_path, monkeypatch, grid_copy):
    flag_dir = tmp_path / "flag"
    shutil.copytree(grid_copy, flag_dir / "urb_grid")
    lines = (flag_dir / "urb_grid" / "agents.csv").read_text().splitlines()[:11]
    (flag_dir / "urb_grid" / "agents.csv").write_text("\n".join(lines) + "\n")
    monkeypatch.setenv("URB_JAX_NETWORKS", str(grid_copy.parent))
    assert find_network("urb_grid").folder == grid_copy
    assert find_network("urb_grid", flag_dir).folder == flag_dir / "urb_grid"
    monkeypatch.delenv("URB_JAX_NETWORKS")
    assert find_network("urb_grid").folder == embedded_networks_dir() / "urb_grid"


def test_networks_list_cli(capsys):
    assert main(["networks", "list"]) == 0
    out = capsys.readouterr().out
    assert "urb_grid" in out and " 400 " in out


def test_networks_list_real(capsys, real_networks_dir):
    assert main(["networks", "list", "--networks-dir", str(real_networks_dir)]) == 0
    out = capsys.readouterr().out
    expected = {"saint_arnoult": 222, "provins": 523, "ingolstadt_custom": 1035, "nangis": 362,
                "nemours": 729, "gretz_armainvilliers": 636, "gargenville": 1000,
                "mantes_la_jolie": 4271, "rambouillet": 1507}
    for line in out.splitlines():
        parts = line.split()
        if parts and parts[0] in expected:
            assert int(parts[1]) == expected.pop(parts[0]), line
    assert not expected, f"not listed: {expected}"


def test_huge_start_time_is_an_error_not_an_overflow(grid_copy):
    _rewrite_agents(grid_copy, 3, "start_time", "1e30")
    with pytest.raises(NetworkError, match=r"line 4, field 'start_time': '1e30' is not an integer below"):
        read_demand(find_network(str(grid_copy)))


def test_header_only_agents_file_is_refused(grid_copy):
    path = grid_copy / "agents.csv"
    path.write_text(path.read_text().splitlines()[0] + "\n")
    with pytest.raises(NetworkError, match=r"agents.csv: holds no agents .*Fix: add one row per agent"):
        read_demand(find_network(str(grid_copy)))


@pytest.mark.parametrize("name", ["od_urb_grid.txt", "agents.csv"])
def test_file_that_is_not_utf8_is_named(grid_copy, name):
    path = grid_copy / name
    path.write_bytes(path.read_bytes() + b"\n\xff\xfe")
    message = rf"{name}: is not UTF-8 text \(byte 0xff on line \d+\).*save it as UTF-8"
    with pytest.raises(NetworkError, match=message):
        read_demand(find_network(str(grid_copy)))


def test_start_time_past_the_simulated_day_is_refused_at_load(grid_copy):
    """It was found only on the first SUMO day, as SumoConfig's error, without naming agents.csv."""
    from urb_jax.city.network import DAY_LIMIT_S
    from urb_jax.sumo_bridge import SumoConfig

    assert SumoConfig().max_sim_time_s == DAY_LIMIT_S  # one limit: the day's and the check's
    _rewrite_agents(grid_copy, 3, "start_time", str(DAY_LIMIT_S))
    with pytest.raises(NetworkError, match=r"agents.csv: line 4, field 'start_time': 21600 s is past the end "
                                           r"of a simulated day .*ids \[2\].*Fix: give every agent a "
                                           r"start_time below 21600"):
        read_demand(find_network(str(grid_copy)))
    _rewrite_agents(grid_copy, 3, "start_time", str(DAY_LIMIT_S - 1))
    read_demand(find_network(str(grid_copy)))
