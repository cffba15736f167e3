"""Shared fixtures. Real URB networks are read from ../shared/networks next to the repo."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_NETWORKS = REPO.parent / "shared" / "networks"


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Tests never read or pollute the user's route cache."""
    os.environ["URB_JAX_CACHE"] = str(tmp_path_factory.mktemp("urb-jax-cache"))


@pytest.fixture(scope="session")
def real_networks_dir() -> Path:
    if not (SHARED_NETWORKS / "saint_arnoult").is_dir():
        pytest.skip(f"real URB networks not found at {SHARED_NETWORKS} (needs ../shared/networks)")
    return SHARED_NETWORKS


@pytest.fixture(scope="session")
def grid_scenario(_isolated_cache):
    from urb_jax.city.scenario import load_scenario

    return load_scenario("urb_grid")
