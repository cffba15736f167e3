"""Folders the OS refuses become messages: a cache folder, HOME or results folder that cannot be
created or written (a file in the way, read-only, no permission) ends with exit 2, the path and the
fix, --dry-run included; an empty HOME is no home folder (Path.home() made it the filesystem root);
a damaged exp_config.json on --resume is named. Before, each was a traceback."""

from __future__ import annotations

import errno
import json
import os

import pytest
from support.fakeday import FakeExecutor

from urb_jax.commands import cli
from urb_jax.core import paths
from urb_jax.core.compile_cache import COMPILE_CACHE_ENV
from urb_jax.core.paths import CACHE_ENV


@pytest.fixture
def file_in_the_way(tmp_path):
    f = tmp_path / "a_file"
    f.write_text("not a folder")
    return f


@pytest.fixture
def no_sumo(monkeypatch):
    """A run that got past its checks would run its days here, not in SUMO."""
    monkeypatch.setattr("urb_jax.runs.train.make_executor", lambda *a, **k: FakeExecutor())


def _train(capsys, *argv) -> tuple[int, str]:
    code = cli.main(["train", "--no-progress", *argv])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("dry", [True, False])
@pytest.mark.parametrize("below", ["", "sub/folder"])
def test_a_cache_folder_behind_a_file(file_in_the_way, monkeypatch, capsys, tmp_path, no_sumo, dry, below):
    cache = file_in_the_way / below if below else file_in_the_way
    monkeypatch.setenv(CACHE_ENV, str(cache))
    code, err = _train(capsys, *(["--dry-run"] if dry else []), "--results-dir", str(tmp_path / "r"))
    assert code == 2
    assert (f"{cache}: urb-jax's cache folder ($URB_JAX_CACHE) cannot be created or written (a file is in "
            f"the way: {file_in_the_way}). Fix: set URB_JAX_CACHE to a folder you can write to.") in err, err
    assert "Traceback" not in err and not (tmp_path / "r").exists()


def test_a_read_only_cache_folder(tmp_path, monkeypatch, capsys):
    cache = tmp_path / "cache"
    cache.mkdir()
    cache.chmod(0o555)
    if os.geteuid() == 0:  # root writes anyway: the filesystem says no instead
        def read_only(*args, **kwargs):
            raise OSError(errno.EROFS, "Read-only file system")

        monkeypatch.setattr(paths.tempfile, "TemporaryFile", read_only)
    monkeypatch.setenv(CACHE_ENV, str(cache))
    try:
        code, err = _train(capsys, "--dry-run")
    finally:
        cache.chmod(0o755)
    assert code == 2
    assert f"{cache}: urb-jax's cache folder ($URB_JAX_CACHE) cannot be created or written (" in err
    assert "read-only" in err or "Permission denied" in err, err


def test_an_empty_home_is_no_home_folder(monkeypatch, capsys):
    monkeypatch.delenv(CACHE_ENV)
    monkeypatch.setenv("HOME", "")
    code, err = _train(capsys, "--dry-run")
    assert code == 2
    assert "HOME is set but empty" in err and "Fix: set HOME to your home folder, or URB_JAX_CACHE" in err
    assert "/.cache/urb-jax:" not in err  # never the filesystem root's


def test_a_home_that_is_a_file(file_in_the_way, monkeypatch, capsys):
    monkeypatch.delenv(CACHE_ENV)
    monkeypatch.setenv("HOME", str(file_in_the_way))
    code, err = _train(capsys, "--dry-run")
    assert code == 2
    assert (f"{file_in_the_way}/.cache/urb-jax: urb-jax's cache folder (~/.cache/urb-jax) cannot be "
            f"created or written (a file is in the way: {file_in_the_way}). Fix: make it writable, or set "
            "URB_JAX_CACHE") in err, err


def test_a_compilation_cache_behind_a_file(file_in_the_way, monkeypatch, capsys):
    monkeypatch.setenv(COMPILE_CACHE_ENV, str(file_in_the_way / "jax"))
    code, err = _train(capsys, "--dry-run")
    assert code == 2
    assert f"{file_in_the_way}/jax: the compilation cache" in err and "a file is in the way" in err
    assert "Fix: set URB_JAX_COMPILE_CACHE to a folder you can write to, or URB_JAX_COMPILE_CACHE=off" in err


@pytest.mark.parametrize("dry", [True, False])
def test_a_results_folder_behind_a_file(file_in_the_way, capsys, confs, no_sumo, dry):
    results = file_in_the_way / "results"
    code, err = _train(capsys, *(["--dry-run"] if dry else []), "--results-dir", str(results),
                       "--task-conf", confs["task_conf"], "--hybrid-conf", confs["hybrid_conf"],
                       "--alg-conf", confs["alg_conf"])
    assert code == 2
    assert (f"--results-dir {results}: cannot be created: {file_in_the_way} is a file. Fix: pass a folder"
            in err), err
    assert "would run" not in err and "Traceback" not in err


@pytest.mark.parametrize("dry", [True, False])
def test_a_results_folder_that_is_not_writable(tmp_path, monkeypatch, capsys, confs, no_sumo, dry):
    results = tmp_path / "results"
    results.mkdir()
    refused = str(results)
    real_access = os.access
    monkeypatch.setattr("urb_jax.runs.folder.os.access",  # as for a user without write permission
                        lambda p, mode: False if str(p) == refused else real_access(p, mode))
    code, err = _train(capsys, *(["--dry-run"] if dry else []), "--results-dir", str(results / "sub"),
                       "--task-conf", confs["task_conf"], "--hybrid-conf", confs["hybrid_conf"],
                       "--alg-conf", confs["alg_conf"])
    assert code == 2
    assert (f"--results-dir {results / 'sub'}: {results} is not writable by this user. Fix: pass a folder "
            "you can write to.") in err, err
    assert not any(results.iterdir())


def test_a_lock_the_os_refuses_is_named(tmp_path, monkeypatch):
    """Past the checks, the OS may still refuse (a race, an ACL): the error names the folder."""
    from urb_jax.core.errors import UrbJaxError
    from urb_jax.runs import folder

    def refused(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(folder.os, "open", refused)
    with pytest.raises(UrbJaxError, match=r"--results-dir .*: cannot create or write the run's folder there "
                                          r"\(Permission denied\)\. Fix: pass a folder you can write to"):
        folder.create_results_dir(tmp_path, "x")


@pytest.mark.parametrize("text", ['{"status": "running", "train_ar', "", "[1, 2]", "\xff\xfe"])
def test_a_damaged_exp_config_on_resume_is_named(tmp_path, capsys, text):
    run = tmp_path / "k"
    run.mkdir()
    (run / "exp_config.json").write_bytes(text.encode("latin-1"))
    code, err = _train(capsys, "--resume", "k", "--results-dir", str(tmp_path))
    assert code == 2
    assert f"{run / 'exp_config.json'}: the run's record" in err, err
    assert "Fix: restore the file from a backup, or start the run again with the same command and " \
           "--overwrite." in err and "Traceback" not in err


def test_a_complete_exp_config_still_resumes_its_run(tmp_path):
    """read_run_config reads what write_config wrote (less the digest of its content it carries)."""
    from urb_jax.runs.folder import read_run_config, write_config

    write_config(tmp_path, {"status": "running", "seed": 3})
    assert read_run_config(tmp_path) == {"status": "running", "seed": 3}
    assert json.loads((tmp_path / "exp_config.json").read_text())["content_sha256"]
