"""URB's own config files, as written: each loads under URB's key names with the values URB wrote,
or is refused with a ConfigError naming the file and the URB feature urb-jax lacks; unknown keys
still fail; `urb-jax train --dry-run` checks a run without simulating or creating anything.

URB's files are read from ../shared/urb (never copied into the repository); tests that need them
skip where that folder is absent."""

from __future__ import annotations

import fnmatch
import json
from pathlib import Path

import pytest

from urb_jax.commands import cli
from urb_jax.core.errors import ConfigError
from urb_jax.runs import baseline
from urb_jax.runs import train as run
from urb_jax.runs.request import BaselineRequest, TrainRequest
from urb_jax.runs.urb_configs import CONFIG_ALIASES_KEY, load_urb_file

URB = Path(__file__).resolve().parents[1].parent / "shared" / "urb"
CONFIG = URB / "config"
NO_URB = f"URB's config files not found at {CONFIG} (needs ../shared/urb)"

# URB file (pattern, relative to config/) -> a phrase its refusal must contain. Every other file loads.
REFUSED = {
    "algo_config/centralized/*": "centralised recurrent PPO",
    "algo_config/centralized_dqn/*": "centralised DQN",
    "algo_config/feudal_hrl/*": "feudal hierarchical RL",
    "algo_config/greedy/*": "centralised greedy baseline",
    "algo_config/hyp_ippo/*": "hypernetwork IPPO",
    "algo_config/pact1/*": "PACT-1",
    "algo_config/iql/config2_longer.json": "missing key(s) 'eps_min'",
    "algo_config/iql/config2_medium.json": "missing key(s) 'eps_min'",
    "env_config/clusters-eta-mask.json": "ETA observations",
    "env_config/clusters_eta.json": "ETA observations",
    "env_config/clusters_eta2.json": "ETA observations",
    "env_config/config1_eta.json": "ETA observations",
    "env_config/clusters-sumo-obs.json": "live SUMO observations",
    "env_config/clusters.json": "clustered route sets",
    "env_config/test.json": "clustered route sets",
    "task_config/asgn_*": "assignment-sampling experiments",
}


def _urb_files() -> list:
    if not CONFIG.is_dir():
        return [pytest.param(None, marks=pytest.mark.skip(reason=NO_URB))]
    files = [*CONFIG.glob("algo_config/*/*.json"), *CONFIG.glob("env_config/*.json"),
             *CONFIG.glob("task_config/*.json")]
    return [pytest.param(f, id=str(f.relative_to(CONFIG))) for f in sorted(files)]


def _refusal(rel: str) -> str | None:
    return next((why for pattern, why in REFUSED.items() if fnmatch.fnmatch(rel, pattern)), None)


@pytest.mark.parametrize("path", _urb_files())
def test_urb_config_loads_as_written_or_is_refused_by_feature(path: Path) -> None:
    rel = str(path.relative_to(CONFIG))
    why = _refusal(rel)
    if why is not None:
        with pytest.raises(ConfigError) as err:
            load_urb_file(path)
        assert str(path) in str(err.value) and why in str(err.value)
        assert "remove them" not in str(err.value)
        return
    loaded = load_urb_file(path)
    res = loaded.resolution
    for key, value in json.loads(path.read_text()).items():
        if key == "desc":
            continue
        if key in res.ignored or key in res.derived:
            assert res.given[key] == value
            continue
        got = getattr(loaded.config, res.aliases.get(key, key))
        assert got == (tuple(value) if isinstance(value, list) else value), (key, got, value)


def test_urb_names_set_our_fields() -> None:
    """URB's key aliases, checked on URB's own files."""
    if not CONFIG.is_dir():
        pytest.skip(NO_URB)
    iql = load_urb_file(CONFIG / "algo_config/iql_torchrl/config3.json")
    assert (iql.config.mlp_depth, iql.config.mlp_cells, iql.config.target_eps) == (5, 256, 0.995)
    assert iql.resolution.ignored.keys() == {"tau"}  # unused by URB's scripts/iql_torchrl.py
    qmix = load_urb_file(CONFIG / "algo_config/qmix_torchrl/test.json")
    assert qmix.config.eps_init == 1.0 and qmix.config.shared_parameters is False
    star = load_urb_file(CONFIG / "algo_config/iql/config4.json")
    assert star.config.num_episodes == 4000 and star.config.widths == (96, 64, 32)
    assert star.resolution.derived.keys() == {"num_hidden"}


def _write(tmp_path: Path, data: dict, name: str = "mine.json") -> Path:
    folder = tmp_path / "algo_config" / "iql_torchrl"  # URB's layout: read as URB's iql_torchrl
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(json.dumps(data))
    return path


URB_IQL = {"agent_frames_per_batch": 2, "n_iters": 3, "num_epochs": 1, "minibatch_size": 8, "lr": 1e-3,
           "max_grad_norm": 1.0, "gamma": 0.9, "memory_size": 100, "tau": 0.01, "eps": 0.9, "eps_init": 1.0,
           "eps_end": 0.1, "exploration_fraction": 0.5, "share_params_agent": True,
           "policy_network_depth": 2, "policy_network_num_cells": 16, "od_embedding_dim": 4}


def test_unknown_key_still_fails_naming_file_and_key(tmp_path: Path) -> None:
    path = _write(tmp_path, {**URB_IQL, "policy_network_dept": 3})
    with pytest.raises(ConfigError, match=r"mine\.json: unknown key\(s\) 'policy_network_dept'") as err:
        load_urb_file(path)
    assert "remove them" not in str(err.value)


def test_two_names_for_one_field_must_agree(tmp_path: Path) -> None:
    path = _write(tmp_path, {**URB_IQL, "mlp_depth": 3})  # our name and URB's, different values
    with pytest.raises(ConfigError, match="'policy_network_depth' = 2 and 'mlp_depth' = 3"):
        load_urb_file(path)
    ok = _write(tmp_path, {**URB_IQL, "mlp_depth": 2}, "same.json")
    assert load_urb_file(ok).config.mlp_depth == 2


def test_derived_key_must_agree_and_missing_urb_keys_are_not_guessed(tmp_path: Path) -> None:
    folder = tmp_path / "algo_config" / "iql"
    folder.mkdir(parents=True)
    star = {"training_eps": 10, "eps_init": 1.0, "eps_decay": 0.99, "eps_min": 0.0, "buffer_size": 64,
            "batch_size": 8, "lr": 1e-3, "num_epochs": 1, "num_hidden": 2, "widths": [16, 16],
            "update_every": 1}
    (folder / "bad_hidden.json").write_text(json.dumps(star))
    with pytest.raises(ConfigError, match=r"bad_hidden\.json: key 'num_hidden' = 2 disagrees with len"):
        load_urb_file(folder / "bad_hidden.json")
    (folder / "no_min.json").write_text(json.dumps({k: v for k, v in star.items() if k != "eps_min"}
                                                   | {"num_hidden": 1}))
    with pytest.raises(ConfigError, match=r"no_min\.json: missing key\(s\) 'eps_min'.*scripts/iql\.py"):
        load_urb_file(folder / "no_min.json")


def test_wrong_urb_algorithm_folder_names_the_right_alg(tmp_path: Path) -> None:
    from urb_jax.algorithms.registry import load_algo

    folder = tmp_path / "algo_config" / "iql"
    folder.mkdir(parents=True)
    (folder / "c.json").write_text("{}")
    with pytest.raises(ConfigError, match="URB's 'iql', which urb-jax runs as --alg iql_star"):
        load_algo("iql", str(folder / "c.json"))


def test_train_run_records_config_aliases() -> None:
    """exp_config.json's config_aliases: URB's keys as given and what they set (no SUMO day)."""
    if not CONFIG.is_dir():
        pytest.skip(NO_URB)
    req = TrainRequest(alg="iql", net="urb_grid", task_conf=str(CONFIG / "task_config/config1.json"),
                       alg_conf=str(CONFIG / "algo_config/iql_torchrl/config1.json"),
                       env_conf=str(CONFIG / "env_config/config1.json"))
    config = run._train_config(run.load_setup(req), req)
    alg = config[CONFIG_ALIASES_KEY]["alg"]
    assert alg["aliases"]["eps"] == "target_eps" and alg["given"]["eps"] == 0.99
    assert alg["aliases"]["policy_network_depth"] == "mlp_depth" and alg["given"]["policy_network_depth"] == 4
    assert "tau" in alg["ignored"] and alg["urb_family"] == "iql_torchrl"
    json.dumps(config[CONFIG_ALIASES_KEY])  # exp_config.json can hold it


@pytest.fixture
def no_simulation(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any SUMO day, executor or process pool fails the test."""
    def boom(*_a, **_k):
        raise AssertionError("a dry run started a simulation")

    for name in ("run_day", "SumoPool", "InProcessExecutor", "RayExecutor", "make_executor",
                 "run_human_phase", "train_group"):
        for module in (run, baseline):  # wherever a run would reach it
            if hasattr(module, name):
                monkeypatch.setattr(module, name, boom)


def _dry(tmp_path: Path, *extra: str) -> list[str]:
    return ["train", "--dry-run", "--net", "urb_grid", "--results-dir", str(tmp_path / "results"), *extra]


def test_dry_run_exits_0_for_a_urb_config_and_creates_nothing(tmp_path, capsys, no_simulation) -> None:
    if not CONFIG.is_dir():
        pytest.skip(NO_URB)
    argv = _dry(tmp_path, "--alg", "qmix",
                "--alg-conf", str(CONFIG / "algo_config/qmix_torchrl/config2.json"),
                "--task-conf", str(CONFIG / "task_config/cooperative_40.json"),
                "--env-conf", str(CONFIG / "env_config/config1.json"), "--seeds", "0,1")
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "160 of 400" in out and "would run: yes" in out
    assert "eps_end = 0.05   (given as URB's 'eps_greedy_end')" in out
    assert "av_behavior = 'cooperative'" in out and "mixing_embed_dim = 256" in out
    assert "qmix_hybrid_urb_grid_cooperative_40_s1" in out
    assert not (tmp_path / "results").exists()


def test_dry_run_exits_2_with_the_reason_for_a_refused_config(tmp_path, capsys, no_simulation) -> None:
    if not CONFIG.is_dir():
        pytest.skip(NO_URB)
    assert cli.main(_dry(tmp_path, "--env-conf", str(CONFIG / "env_config/config1_eta.json"))) == 2
    err = capsys.readouterr().err
    assert "config1_eta.json" in err and "'observations' = 'trip_info_eta'" in err
    assert "ETA observations" in err
    assert not (tmp_path / "results").exists()


def test_dry_run_exits_2_where_the_run_would_stop(tmp_path, capsys, no_simulation) -> None:
    """check_runnable (no CAV) and an existing results folder, as a real run would refuse them."""
    task = tmp_path / "no_cavs.json"
    task.write_text(json.dumps({"ratio_machines": 0.0}))
    assert cli.main(_dry(tmp_path, "--task-conf", str(task))) == 2
    assert "makes 0 of the 400 agents CAVs" in capsys.readouterr().err
    (tmp_path / "results" / "taken").mkdir(parents=True)
    assert cli.main(_dry(tmp_path, "--id", "taken")) == 2
    assert "already exist" in capsys.readouterr().err
    assert list((tmp_path / "results").iterdir()) == [tmp_path / "results" / "taken"]


def test_baseline_alg_conf_sets_training_days(tmp_path) -> None:
    """URB's baselines.py reads training_eps from its baseline algo config; so does urb-jax baseline
    (and `--set alg.training_eps` overrides it there, as a key of that file)."""
    conf = tmp_path / "algo_config" / "baseline" / "c.json"
    conf.parent.mkdir(parents=True)
    conf.write_text(json.dumps({"training_eps": 7}))
    loaded, task_keys = baseline._baseline_configs(BaselineRequest(alg_conf=str(conf)), None)
    assert task_keys == {"training_eps": 7} and loaded["alg"].config.training_eps == 7
    req = BaselineRequest(alg_conf=str(conf), overrides=["alg.training_eps=9"])
    _, task_keys = baseline._baseline_configs(req, None)
    assert task_keys == {"training_eps": 9}
