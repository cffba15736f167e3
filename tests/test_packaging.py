"""The installed package: everything under the `urb_jax` namespace, nothing under generic names.

The repository keeps the user's top-level folders (algorithms/, surrogate/, sumo_bridge/, ...);
`pip install .` must still put only `urb_jax` into site-packages, or installing urb-jax beside a
PyPI package called `algorithms` or `surrogate` would break one of them.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _tracked_copy(dest: Path) -> Path:
    """The checkout's tracked files (links kept as links), so the build leaves nothing in the repo."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, check=True, capture_output=True,
                           text=True).stdout.split("\0")
    for rel in filter(None, files):
        src, dst = REPO / rel, dest / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            dst.symlink_to(os.readlink(src))
        elif src.is_file():
            shutil.copy2(src, dst)
    return dest


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if not (REPO / ".git").exists():
        pytest.skip("needs a git checkout (the test builds from the tracked files)")
    src = _tracked_copy(tmp_path_factory.mktemp("src"))
    target = tmp_path_factory.mktemp("site")
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                    "--no-compile", "--target", str(target), str(src)], check=True, capture_output=True)
    return target


def test_only_urb_jax_is_installed_at_top_level(site: Path) -> None:
    top = {p.name for p in site.iterdir()
           if not p.name.endswith((".dist-info", ".egg-info")) and p.name not in ("bin", "__pycache__")}
    assert top == {"urb_jax"}


def test_every_module_and_data_file_is_installed(site: Path) -> None:
    """Each tracked file of the package (through the links: the user's folders too) is in the
    installed tree; a room without __init__.py, say, would silently be left out of the wheel."""
    pkg = site / "urb_jax"
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, check=True, capture_output=True,
                             text=True).stdout.split()
    roots = {"urb_jax/": "", **{f"{d}/": f"{d}/" for d in ("algorithms", "surrogate", "sumo_bridge",
                                                           "networks", "configs")}}
    wanted = [roots[r] + f[len(r):] for f in tracked for r in roots
              if f.startswith(r) and f.endswith((".py", ".json", ".xml", ".csv", ".txt"))
              and not (REPO / f).is_symlink()]
    assert len(wanted) > 80 and "algorithms/registry.py" in wanted and "reporting/__init__.py" in wanted
    missing = [w for w in wanted if not (pkg / w).is_file()]
    assert not missing
    assert not (pkg / "algorithms").is_symlink()  # a wheel carries files, not the checkout's links


def test_installed_copy_imports_on_its_own(site: Path, tmp_path: Path) -> None:
    """Imported from the installed files alone (not the checkout): every room, and the registry."""
    code = ("import urb_jax.algorithms.registry as r, urb_jax.commands.cli, urb_jax.surrogate.model, "
            "urb_jax.sumo_bridge.sim; print(r.__file__); print(sorted(r.ALGORITHMS))")
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, check=True,
                         capture_output=True, text=True).stdout.split("\n")
    assert out[0].startswith(str(site))
    assert "iql_star" in out[1]
