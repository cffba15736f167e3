"""Fixtures shared by several test modules (helpers they share are in tests/support/). Real URB
networks are read from ../shared/networks next to the repo."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_NETWORKS = REPO.parent / "shared" / "networks"


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Tests never read or pollute the user's route cache; the SUMO day store is off, so that a test
    comparing two runs' SUMO days runs both (tests/test_day_store.py turns it on where it tests it)."""
    os.environ["URB_JAX_CACHE"] = str(tmp_path_factory.mktemp("urb-jax-cache"))
    os.environ["URB_JAX_DAY_STORE_GB"] = "0"


@pytest.fixture(scope="session")
def real_networks_dir() -> Path:
    if not (SHARED_NETWORKS / "saint_arnoult").is_dir():
        pytest.skip(f"real URB networks not found at {SHARED_NETWORKS} (needs ../shared/networks)")
    return SHARED_NETWORKS


@pytest.fixture(scope="session")
def grid_scenario(_isolated_cache):
    from urb_jax.city.scenario import load_scenario

    return load_scenario("urb_grid")


@pytest.fixture(scope="session")
def tiny_iql_confs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """support.tiny_runs.tiny_iql_run's configs: a tiny IQL hybrid run, written once per session."""
    from support.tiny_runs import tiny_iql_run

    return tiny_iql_run(tmp_path_factory.mktemp("tiny_iql_confs"))


@pytest.fixture(scope="session")
def tiny_iql_reference(tiny_iql_confs, tmp_path_factory: pytest.TempPathFactory):
    """(RunOutput, FakeExecutor): the tiny IQL run on `tiny_iql_confs`, uninterrupted, with the
    executor that ran its days. Many tests compare a killed, resumed or reused run against exactly
    this run; run once per test process (it is most of such a test's cost). Read it, never write."""
    from support.fakeday import FakeExecutor

    from urb_jax.runs.request import TrainRequest
    from urb_jax.runs.train import run_train

    ex = FakeExecutor()
    (out,) = run_train(TrainRequest(alg="iql", exp_id="ref",
                                    results_dir=str(tmp_path_factory.mktemp("tiny_iql_ref")), progress=False,
                                    **tiny_iql_confs), executor=ex)
    return out, ex


@pytest.fixture(scope="module")
def confs(tiny_iql_confs):
    """tiny_iql_confs, under the name the hybrid-run tests give their run's configs (runs on them
    compare against tiny_iql_reference). Modules whose runs have configs of their own (test_credit.py,
    test_marginal_cost.py, test_human_adapt.py, test_round_log.py) define their own `confs`."""
    return tiny_iql_confs
