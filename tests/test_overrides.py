"""`--set SECTION.KEY=VALUE`: one config key without a new JSON file, typed, aliased and validated
exactly like the file's own keys; recorded in exp_config.json; honoured by --dry-run and re-applied
(never changed) by --resume. No SUMO day runs here."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from urb_jax.commands import cli
from urb_jax.core.configio import from_dict, in_section, parse_overrides, read_json
from urb_jax.core.errors import ConfigError
from urb_jax.game.config import TaskConfig, load_task
from urb_jax.runs import baseline
from urb_jax.runs import train as run
from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.urb_configs import OVERRIDES_KEY, TRAIN_SECTIONS

URB_CONFIG = Path(__file__).resolve().parents[1].parent / "shared" / "urb" / "config"
REQUEST = TrainRequest(net="urb_grid", alg="iql")  # what a request without --alg resolves to


def test_values_are_json_and_bare_words_text() -> None:
    ov = parse_overrides(["alg.lr=1e-3", "task.av_behavior=malicious", "alg.widths=[64, 64]",
                          "task.should_humans_adapt=true", 'env.observations="1"', "hybrid.x=a=b"],
                         TRAIN_SECTIONS)
    assert [o.value for o in ov] == [0.001, "malicious", [64, 64], True, "1", "a=b"]
    assert [o.section for o in ov] == ["alg", "task", "alg", "task", "env", "hybrid"]
    for bad in ("alg.lr", "lr=1", "algo.lr=1", "alg.=1"):
        with pytest.raises(ConfigError, match=r"SECTION\.KEY=VALUE"):
            parse_overrides([bad], TRAIN_SECTIONS)


def test_an_override_equals_the_same_key_written_in_the_file(tmp_path) -> None:
    """The reference: a copy of the file with the key changed, loaded the ordinary way."""
    base = read_json(Path(load_task("config1").path))
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps({**base, "human_learning_episodes": 100, "av_behavior": [1, 0, 0, 0]}))
    by_set = load_task("config1", parse_overrides(["task.human_learning_episodes=100",
                                                   "task.av_behavior=[1, 0, 0, 0]"], TRAIN_SECTIONS))
    assert by_set.config == load_task(str(edited)).config
    assert by_set.config != load_task("config1").config
    assert by_set.overridden == {"human_learning_episodes": 100, "av_behavior": (1.0, 0.0, 0.0, 0.0)}


def test_urb_key_names_resolve_like_in_a_file() -> None:
    """URB's name for a key sets our field, on our file and on URB's (where the file's own
    spelling of that key, URB's or ours, is replaced)."""
    from urb_jax.algorithms.registry import load_algo

    ours = load_algo("iql", "config1", parse_overrides(["alg.policy_network_depth=3", "alg.eps=0.5"],
                                                       TRAIN_SECTIONS))
    assert ours.config.mlp_depth == 3 and ours.config.target_eps == 0.5
    assert ours.overridden == {"mlp_depth": 3, "target_eps": 0.5}
    if not URB_CONFIG.is_dir():
        pytest.skip(f"URB's config files not found at {URB_CONFIG} (needs ../shared/urb)")
    path = str(URB_CONFIG / "algo_config/iql_torchrl/config1.json")
    for key in ("policy_network_depth", "mlp_depth"):
        urb = load_algo("iql", path, parse_overrides([f"alg.{key}=2"], TRAIN_SECTIONS))
        assert urb.config.mlp_depth == 2 and urb.config.lr == load_algo("iql", path).config.lr
        assert urb.resolution.family == "iql_torchrl"


def test_unknown_keys_wrong_types_and_bad_values_fail_naming_the_override(tmp_path, capsys) -> None:
    cases = {
        "alg.lrr=1": ["--set alg.lrr=1", "no key 'lrr'", "Fix: use one of", "lr,"],
        "alg.lr=abc": ["--set alg.lr=abc", "'lr' takes float", "'abc' (str)", "Fix: give a float"],
        "hybrid.num_envs=2.5": ["--set hybrid.num_envs=2.5", "'num_envs' takes int"],
        "task.ratio_machines=2": ["with --set task.ratio_machines=2", "'ratio_machines' is 2.0. Fix: use a "
                                  "finite number in [0, 1]"],
        "task.greedy_num_samples=5": ["assignment-sampling experiments", "does not implement"],
        "task.marginal_cost_coefficient_beta=-1": ["'marginal_cost_beta' is -1.0",
                                                   "in [0, 1000] (URB: 0 to 5)"],
        "task.desc=x": ["no key 'desc'"],
        "foo.lr=1": ["SECTION one of task, env, alg, hybrid"],
    }
    for item, phrases in cases.items():
        argv = ["train", "--dry-run", "--results-dir", str(tmp_path / "r"), "--set", item]
        assert cli.main(argv) == 2, item
        err = capsys.readouterr().err
        for phrase in phrases:
            assert phrase in err, (item, phrase, err)
    assert not (tmp_path / "r").exists()
    assert cli.main(["train", "--dry-run", "--train-days", "10", "--set", "hybrid.train_days=5"]) == 2
    assert "both set the training budget" in capsys.readouterr().err


def test_dry_run_shows_the_overridden_values(tmp_path, capsys) -> None:
    argv = ["train", "--dry-run", "--results-dir", str(tmp_path / "r"), "--set", "alg.lr=1e-3",
            "--set", "task.human_learning_episodes=100", "--set", "hybrid.num_envs=8",
            "--set", "env.number_of_paths=3", "--set", "alg.policy_network_depth=3"]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    for line in ("lr = 0.001   (--set)", "human_learning_episodes = 100   (--set)", "num_envs = 8   (--set)",
                 "number_of_paths = 3   (--set)", "mlp_depth = 3   (--set)", "3 routes each",
                 "overrides    --set alg.lr=1e-3"):
        assert line in out, line


def test_exp_config_records_the_overrides_as_given_and_resolved() -> None:
    given = ("alg.lr=1e-3", "alg.policy_network_depth=3", "hybrid.num_envs=8",
             "task.human_learning_episodes=100")
    req = dataclasses.replace(REQUEST, overrides=given)
    setup = run.load_setup(req)
    assert setup.alg_config.lr == 0.001 and setup.alg_config.mlp_depth == 3
    assert setup.hyb.num_envs == 8 and setup.task.human_learning_episodes == 100
    config = run._train_config(setup, req)
    assert config[OVERRIDES_KEY] == {
        "given": list(given),
        "resolved": {"alg": {"lr": 0.001, "mlp_depth": 3}, "hybrid": {"num_envs": 8},
                     "task": {"human_learning_episodes": 100}}}
    assert config["human_days"] == 100 and config["hybrid_num_envs"] == 8
    json.dumps(config)
    assert run._train_config(run.load_setup(REQUEST), REQUEST)[OVERRIDES_KEY] == {"given": [], "resolved": {}}


def _recorded_run(results: Path, overrides: list[str] | None) -> None:
    folder = results / "r"
    folder.mkdir(parents=True)
    args = REQUEST.record(0)
    args.pop("overrides")
    if overrides is not None:  # None: a run recorded before --set existed
        args["overrides"] = overrides
    (folder / "exp_config.json").write_text(json.dumps({"train_args": args, "group": ["r"],
                                                        "status": "running"}))


def test_resume_reapplies_the_recorded_overrides(tmp_path, monkeypatch) -> None:
    seen = []

    def stop(setup, *_a, **_k):
        seen.append(setup)
        raise ConfigError("stop here")

    monkeypatch.setattr(run, "_train", stop)
    monkeypatch.setattr(run, "latest_checkpoint", lambda _folder: (1, None))
    closable = type("Executor", (), {"close": lambda self: None})
    monkeypatch.setattr(run, "make_executor", lambda *_a, **_k: closable())
    _recorded_run(tmp_path / "a", ["alg.lr=1e-3", "hybrid.num_envs=8"])
    for given in (None, ["alg.lr=0.001", "hybrid.num_envs=8"]):  # the same overrides, however spelled
        with pytest.raises(ConfigError, match="stop here"):
            run.resume_train(ResumeRequest("r", results_dir=str(tmp_path / "a"), overrides=given))
        assert seen[-1].alg_config.lr == 0.001 and seen[-1].hyb.num_envs == 8
    _recorded_run(tmp_path / "b", None)
    with pytest.raises(ConfigError, match="stop here"):
        run.resume_train(ResumeRequest("r", results_dir=str(tmp_path / "b")))
    assert seen[-1].hyb.num_envs == 16  # configs/hybrid/default.json


def test_resume_refuses_different_overrides(tmp_path, capsys) -> None:
    _recorded_run(tmp_path, ["alg.lr=1e-3"])
    argv = ["train", "--resume", "r", "--results-dir", str(tmp_path), "--set", "alg.lr=1e-2"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "--set alg.lr=1e-3" in err and "would change them half-way" in err and "Fix: drop --set" in err


def test_baseline_overrides_task_and_env_and_records_them(tmp_path, monkeypatch, capsys) -> None:
    seen = {}

    def stop(folder, config, scn, task, env, *_a):
        seen.update(config=config, task=task, env=env)
        raise ConfigError("stop here")

    monkeypatch.setattr(baseline, "_run_baseline_days", stop)
    argv = ["baseline", "--results-dir", str(tmp_path), "--no-progress", "--set", "task.test_eps=3",
            "--set", "env.number_of_paths=3"]
    assert cli.main(argv) == 2 and "stop here" in capsys.readouterr().err
    assert seen["task"].test_eps == 3 and seen["env"].number_of_paths == 3
    assert seen["config"][OVERRIDES_KEY] == {"given": ["task.test_eps=3", "env.number_of_paths=3"],
                                             "resolved": {"task": {"test_eps": 3},
                                                          "env": {"number_of_paths": 3}}}
    assert cli.main(["baseline", "--results-dir", str(tmp_path), "--set", "alg.training_eps=3"]) == 2
    assert "only with --alg-conf" in capsys.readouterr().err
    assert cli.main(["baseline", "--results-dir", str(tmp_path), "--set", "hybrid.num_envs=3"]) == 2
    assert "SECTION one of task, env, alg" in capsys.readouterr().err


def test_in_section_and_from_dict_agree_on_types() -> None:
    """An override's type check is the file's: what from_dict refuses, --set refuses."""
    ov = parse_overrides(["task.test_eps=1.5"], TRAIN_SECTIONS)
    with pytest.raises(ConfigError, match="'test_eps'"):
        from_dict(TaskConfig, {"test_eps": 1.5})
    with pytest.raises(ConfigError, match="'test_eps' takes int"):
        load_task("config1", in_section(ov, "task"))
