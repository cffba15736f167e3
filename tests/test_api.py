"""The Python API (docs/api.md): `import urb_jax` exposes the entry points, imports neither JAX
nor SUMO, and nothing it offers starts a process that re-runs the caller's script, so a script
without an `if __name__ == "__main__":` guard runs."""

from __future__ import annotations

import ast
import importlib
import multiprocessing
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import urb_jax
from urb_jax.core.errors import UrbJaxError

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "python_api.py"


def _python(args: list[str], cwd: Path, timeout: float, **env: str) -> subprocess.CompletedProcess:
    """A fresh interpreter that imports this checkout's urb_jax."""
    environ = {**os.environ, **env, "PYTHONPATH": os.pathsep.join(
        p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=environ, capture_output=True, text=True,
                          timeout=timeout)


def test_every_exported_name_is_its_implementation():
    assert set(urb_jax.__all__) == {*urb_jax._EXPORTS, "__version__"}
    for name, module in urb_jax._EXPORTS.items():
        assert getattr(urb_jax, name) is getattr(importlib.import_module(module), name), name
        assert name in dir(urb_jax)
    with pytest.raises(AttributeError, match="no attribute 'load_scenarios'"):
        urb_jax.load_scenarios  # noqa: B018


def test_import_loads_no_heavy_module(tmp_path):
    heavy = ("jax", "jaxlib", "libsumo", "sumolib", "numpy", "pandas", "networkx", "urb_jax.city")
    out = _python(["-c", f"import sys, urb_jax; print([m for m in {heavy!r} if m in sys.modules])"],
                  tmp_path, 60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_load_scenario_starts_no_process(monkeypatch, tmp_path):
    """Built from scratch and read back from the cache, urb_grid's Scenario comes from this
    process alone: any attempt to start a process or a subprocess fails the test."""
    def refuse(*args, **kwargs):
        raise AssertionError("load_scenario started a process")

    monkeypatch.setattr(multiprocessing.process.BaseProcess, "start", refuse)
    monkeypatch.setattr(subprocess.Popen, "__init__", refuse)
    monkeypatch.setenv("URB_JAX_CACHE", str(tmp_path))
    built = urb_jax.load_scenario("urb_grid")
    cached = urb_jax.load_scenario("urb_grid")
    assert any((tmp_path / "scenarios").iterdir())  # the first call built and saved it
    assert np.array_equal(built.od_routes, cached.od_routes) and built.n_agents == 400
    assert multiprocessing.active_children() == []


def test_route_workers_do_not_rerun_a_script_without_main_guard(tmp_path):
    """Parallel route sampling from a guardless script: the script's top level runs once (a
    multiprocessing pool's spawn/forkserver children ran it again and crashed) and the workers'
    routes equal one process's."""
    script = tmp_path / "guardless.py"
    script.write_text(textwrap.dedent(f"""
        with open({str(tmp_path / "ran")!r}, "a") as f:
            f.write("top level\\n")
        from urb_jax.city.network import find_network, read_demand
        from urb_jax.city.netxml import read_net
        from urb_jax.city.routes import MIN_PARALLEL, RouteParams, build_route_graph, generate_routes
        files = find_network("urb_grid")
        net = read_net(files.net)
        demand = read_demand(files, net)
        pairs = [(o, d) for o in demand.origins for d in demand.destinations]
        assert len(pairs) >= MIN_PARALLEL, "too few pairs: the workers would not start"
        (one,) = generate_routes(build_route_graph(net), pairs, RouteParams(), 42, workers=1)
        (two,) = generate_routes(build_route_graph(net), pairs, RouteParams(), 42, workers=2)
        print("identical" if one == two else "different")
    """))
    out = _python([str(script)], tmp_path, 300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "identical"
    assert (tmp_path / "ran").read_text() == "top level\n"


@pytest.mark.sumo
def test_run_days_is_the_in_process_executor_with_the_env_seed(grid_scenario):
    """`run_days` with no seed runs URB's days (env seed) and gives InProcessExecutor's days."""
    from urb_jax.sumo_bridge import InProcessExecutor

    choices = np.stack([np.zeros(grid_scenario.n_agents, np.int32),
                        grid_scenario.fft.argmin(axis=1).astype(np.int32)])  # [2, N]
    days = urb_jax.run_days(grid_scenario, choices)
    executor = InProcessExecutor()
    try:
        reference = executor.run_days(grid_scenario, choices, [grid_scenario.env_seed] * 2)
    finally:
        executor.close()
    assert [d.seed for d in days] == [42, 42]
    assert all(a.same_as(b) for a, b in zip(days, reference, strict=True))
    assert not np.array_equal(days[0].travel_time, days[1].travel_time)  # two different days


def _has_main_guard(source: str) -> bool:
    return any(isinstance(node, ast.If) and "__name__" in ast.unparse(node.test)
               for node in ast.parse(source).body)


@pytest.mark.slow
@pytest.mark.sumo
def test_example_runs_as_a_plain_script(tmp_path):
    """examples/python_api.py, which has no main guard, runs end to end in a fresh interpreter,
    and what it prints agrees with the files its training run wrote."""
    assert not _has_main_guard(EXAMPLE.read_text())
    out = _python([str(EXAMPLE), str(tmp_path / "results")], tmp_path, 900,
                  URB_JAX_CACHE=str(tmp_path / "cache"))
    assert out.returncode == 0, out.stdout + out.stderr
    folder = tmp_path / "results" / "api_example"
    csv = pd.read_csv(folder / "metrics" / "BenchmarkMetrics.csv").iloc[0]
    row = urb_jax.run_metrics(folder)
    assert list(row) == list(csv.index)
    assert np.allclose(list(row.values()), csv.to_numpy(float), equal_nan=True, rtol=1e-12)
    assert (f"t_pre {row['t_pre']:.3f} min, t_CAV {row['t_CAV']:.3f} min" in out.stdout)
    assert "scenario urb_grid: 400 agents" in out.stdout


def test_run_metrics_refuses_an_unfinished_run(tmp_path):
    (tmp_path / "exp_config.json").write_text('{"status": "running", "human_days": 10}')
    with pytest.raises(UrbJaxError, match="not a finished run"):
        urb_jax.run_metrics(tmp_path)
