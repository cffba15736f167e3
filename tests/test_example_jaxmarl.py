"""examples/jaxmarl_routing.py runs (so it cannot rot), and its tiny learner learns on the surrogate."""

import importlib.util
from pathlib import Path

import pytest

pytest.importorskip("jaxmarl", reason="the JaxMARL extra: pip install 'urb-jax[jaxmarl]'")

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "jaxmarl_routing.py"


@pytest.mark.slow
def test_the_jaxmarl_example_learns_routes_better_than_random(capsys):
    spec = importlib.util.spec_from_file_location("jaxmarl_routing", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    out = example.main(["--days", "30", "--envs", "4"])
    assert out["last_days"] > out["first_days"]  # rewards (minus minutes) rise while learning
    assert out["greedy_time"] < -out["random_routes"]  # the learned routes beat random ones
    assert "160 CAVs" in capsys.readouterr().out
