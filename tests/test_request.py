"""The typed run requests: refused when they cannot run, recorded in exp_config.json, and rebuilt
from there by a resume exactly as the run was asked for."""

from __future__ import annotations

import dataclasses
import json
import types

import pytest

from urb_jax.commands import cli
from urb_jax.core.errors import ConfigError
from urb_jax.core.paths import embedded_networks_dir
from urb_jax.runs import train as run
from urb_jax.runs.request import BaselineRequest, ResumeRequest, TrainRequest, request_fields


@pytest.mark.parametrize(("fields", "message"), [
    ({"seeds": (0, 1, 0)}, r"seeds \[0, 1, 0\]: a seed is given twice"),
    ({"seeds": ()}, r"seeds \[\]: a run needs one or more integer seeds"),
    ({"seeds": ("0",)}, r"a run needs one or more integer seeds"),
    ({"mode": "sumo_only"}, r"mode 'sumo_only'\. Fix: use one of hybrid, sumo, surrogate"),
    ({"executor": "slurm"}, r"executor 'slurm'\. Fix: use one of pool, ray"),
    ({"train_days": 0}, r"--train-days 0: a run needs at least one training day"),
])
def test_a_request_that_cannot_run_is_refused_when_built(fields, message):
    with pytest.raises(ConfigError, match=message):
        TrainRequest(**fields)


def test_lists_become_tuples_so_a_request_is_frozen_and_hashable():
    req = TrainRequest(seeds=[2, 0], overrides=["alg.lr=1e-3"])
    assert req.seeds == (2, 0) and req.overrides == ("alg.lr=1e-3",)
    assert hash(req) == hash(TrainRequest(seeds=(2, 0), overrides=("alg.lr=1e-3",)))
    assert BaselineRequest(overrides=None).overrides == ()
    assert ResumeRequest("r", overrides=None).overrides == ()
    with pytest.raises(dataclasses.FrozenInstanceError):
        req.alg = "qmix"  # type: ignore[misc]


def test_resolved_names_the_algorithm_network_and_config_files(tmp_path, monkeypatch):
    (tmp_path / "task.json").write_text("{}")
    monkeypatch.chdir(tmp_path)
    req = TrainRequest(alg="iql_torchrl", task_conf="task.json", networks_dir="nets").resolved()
    assert req.alg == "iql" and req.net == "urb_grid"
    assert req.task_conf == str(tmp_path / "task.json") and req.networks_dir == str(tmp_path / "nets")
    assert req.alg_conf == "config1"  # an id stays an id


def test_the_record_rebuilds_the_request():
    req = TrainRequest(alg="qmix", task_conf="config2", seeds=(3, 4), mode="sumo", train_days=40,
                       overrides=("alg.lr=1e-3",), log="tensorboard", drop_unroutable=True).resolved()
    rec = req.record(4)
    assert rec["seed"] == 4 and rec["overrides"] == ["alg.lr=1e-3"]
    assert json.loads(json.dumps(rec)) == rec  # JSON as exp_config.json holds it
    assert TrainRequest.from_record(rec, (3, 4)) == req
    # a run recorded before a key existed gets the key's default
    old = {k: v for k, v in rec.items() if k not in ("overrides", "log", "executor")}
    assert TrainRequest.from_record(old, (3, 4)) == dataclasses.replace(req, overrides=(), log=None)


def test_suite_files_may_set_every_request_field_but_where_the_results_go():
    assert "seeds" in request_fields(TrainRequest) and "mode" in request_fields(TrainRequest)
    assert "model" in request_fields(BaselineRequest) and "alg_conf" in request_fields(BaselineRequest)
    for kind in (TrainRequest, BaselineRequest):
        assert not {"exp_id", "results_dir", "progress", "overwrite"} & request_fields(kind)


def test_a_resume_rebuilds_the_recorded_request(tmp_path, monkeypatch):
    """The request a resumed run trains with is the one its exp_config.json recorded, with only
    what the resume may change (where results are, progress); not a re-read of the flags."""
    asked = TrainRequest(alg="iql_torchrl", task_conf="test", hybrid_conf="test", seeds=(0,), exp_id="r",
                         overrides=("alg.lr=1e-3",), results_dir=str(tmp_path), progress=False)
    seen: list[TrainRequest] = []

    def stop(setup, req, *_a, **_k):
        seen.append(req)
        raise ConfigError("stop here")

    monkeypatch.setattr(run, "_train_groups", lambda setup, req, *_a, **_k: stop(setup, req))
    monkeypatch.setattr(run, "_simulate_human_phase", lambda *_a, **_k: None)  # no SUMO day
    monkeypatch.setattr(run, "save_human_phase", lambda *_a, **_k: None)
    monkeypatch.setattr(run, "journal", lambda *_a, **_k: types.SimpleNamespace(reused=0))
    with pytest.raises(ConfigError, match="stop here"):
        run.run_train(asked, executor=_NoDays())
    monkeypatch.setattr(run, "_train", stop)
    monkeypatch.setattr(run, "latest_checkpoint", lambda _folder: (1, None))
    with pytest.raises(ConfigError, match="stop here"):
        run.resume_train(ResumeRequest("r", results_dir=str(tmp_path), progress=False), executor=_NoDays())
    started, resumed = seen
    assert started == asked.resolved()
    # the same request, field by field; the network is looked up where the run found it
    assert resumed == dataclasses.replace(started, networks_dir=str(embedded_networks_dir()))


def test_the_cli_builds_one_request_for_a_run_and_its_dry_run(tmp_path, capsys):
    argv = ["train", "--dry-run", "--alg", "qmix", "--seeds", "1,2", "--mode", "sumo", "--train-days", "40",
            "--set", "alg.lr=1e-3", "--results-dir", str(tmp_path)]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "algorithm    qmix" in out and "mode sumo, seeds 1,2" in out and "--set alg.lr=1e-3" in out
    assert f"{tmp_path}/qmix_sumo_urb_grid_config1_s1" in out


class _NoDays:
    """An executor a test never reaches."""

    def run_days(self, *_a, **_k):
        pytest.fail("no SUMO day")

    def close(self) -> None:
        pass
