"""Every numeric config value has a declared range (urb_jax.core.ranges): NaN, +-Infinity, zero or
negative where meaningless and absurd sizes are refused at load, naming the file, the key and the fix
(exit 2, --dry-run too); a JSON object that gives a key twice is refused in every config and suite
file. Before: alg.lr=NaN and task.human_beta=NaN trained to the end with exit 0 (NaN passes every
`<=` check), alg.minibatch_size=0 too; demand_scale NaN/Infinity/1e9 and mlp_cells=0 gave tracebacks."""

from __future__ import annotations

import dataclasses
import importlib
import json
import pkgutil
import sys
from typing import ClassVar

import pytest

import urb_jax
from urb_jax.algorithms.configs import BaselineConfig
from urb_jax.algorithms.registry import ALGORITHMS
from urb_jax.analysis.optimum import SearchConfig
from urb_jax.commands import cli
from urb_jax.core.configio import configs_dir, read_json
from urb_jax.core.errors import ConfigError
from urb_jax.core.ranges import Range, check_ranges, numeric_fields
from urb_jax.game.config import EnvConfig, TaskConfig
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.training.hybrid.plan import HybridConfig


def _declaring_ranges() -> list[type]:
    """Every dataclass of the package that declares RANGES (found, not listed: a new one is checked)."""
    for info in pkgutil.walk_packages(urb_jax.__path__, "urb_jax."):
        importlib.import_module(info.name)
    seen: dict[str, type] = {}
    for mod in list(sys.modules.values()):
        if getattr(mod, "__name__", "").startswith("urb_jax."):
            for obj in vars(mod).values():
                if dataclasses.is_dataclass(obj) and isinstance(obj, type) and hasattr(obj, "RANGES"):
                    seen[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return [seen[k] for k in sorted(seen)]


CONFIGS = _declaring_ranges()
# The fields a config class has no default for (a fleet of a task's `fleets` has its name, share and
# algorithm): a valid value each, so its other defaults are checked too
REQUIRED = {"FleetConfig": {"name": "a", "share": 0.2, "alg": "iql_star"}}


def test_every_config_a_user_can_load_declares_ranges() -> None:
    loaded = {TaskConfig, EnvConfig, HybridConfig, SumoConfig, BaselineConfig, SearchConfig,
              *(a.config_class for a in ALGORITHMS.values())}
    assert loaded <= set(CONFIGS), loaded - set(CONFIGS)


@pytest.mark.parametrize("cls", CONFIGS, ids=lambda c: c.__name__)
def test_every_numeric_field_declares_a_range_its_default_is_in(cls) -> None:
    assert numeric_fields(cls), cls
    assert set(numeric_fields(cls)) <= set(cls.RANGES)
    check_ranges(cls(**REQUIRED.get(cls.__name__, {})))  # the defaults are valid


def test_a_numeric_field_without_a_range_is_a_programming_error() -> None:
    @dataclasses.dataclass(frozen=True)
    class Forgot:
        RANGES: ClassVar[dict[str, Range]] = {"a": TaskConfig.RANGES["ratio_machines"]}
        a: float = 0.5
        b: int = 3

    with pytest.raises(TypeError, match="declares no range for b"):
        check_ranges(Forgot())


# --set item -> what the error must say (besides the exit code and the file)
BAD = {
    "alg.lr=NaN": "key 'lr' is nan. Fix: use a finite number in (0, 10]",
    "alg.lr=Infinity": "key 'lr' is Infinity. Fix: use a finite number in (0, 10]",
    "alg.lr=-Infinity": "key 'lr' is -Infinity",
    "alg.lr=0": "key 'lr' is 0.0",
    "alg.minibatch_size=0": "key 'minibatch_size' is 0. Fix: use an integer in [1, 10000000]",
    "alg.mlp_cells=0": "key 'mlp_cells' is 0. Fix: use an integer in [1, 65536]",
    "alg.mlp_cells=100000000": "key 'mlp_cells' is 100000000",
    "task.human_beta=NaN": "key 'human_beta' is nan. Fix: use a finite number in [-100, 100] (URB: -1.5)",
    "task.demand_scale=NaN": "key 'demand_scale' is nan",
    "task.demand_scale=Infinity": "key 'demand_scale' is Infinity",
    "task.demand_scale=1e9": "key 'demand_scale' is 1000000000.0. Fix: use a finite number in (0, 100]",
    "task.demand_scale=0": "key 'demand_scale' is 0.0",
    "task.av_behavior=[1, 0, NaN, 0]": "key 'av_behavior' holds nan",
    "env.number_of_paths=1000000": "key 'number_of_paths' is 1000000. Fix: use an integer in [1, 64]",
    "hybrid.day_timeout_s=NaN": "key 'day_timeout_s' is nan",
    "hybrid.train_days=1000000000000": "key 'train_days' is 1000000000000",
    "hybrid.keep_checkpoints_at=[10, -1]": "key 'keep_checkpoints_at' holds -1. Fix: use an integer in [0,",
}


@pytest.mark.parametrize("item", BAD)
def test_a_bad_value_is_refused_by_the_dry_run_and_the_run(item, tmp_path, capsys) -> None:
    for dry in (["--dry-run"], []):
        argv = ["train", *dry, "--results-dir", str(tmp_path / "r"), "--no-progress", "--set", item]
        assert cli.main(argv) == 2, (item, dry)
        err = capsys.readouterr().err
        assert BAD[item] in err, err
        assert f"with --set {item}:" in err and ".json" in err, err  # the file and the item
        assert "would run" not in err
    assert not (tmp_path / "r").exists()


def test_iql_star_widths_are_checked_element_by_element(tmp_path, capsys) -> None:
    argv = ["train", "--dry-run", "--alg", "iql_star", "--set", "alg.widths=[64, 0]"]
    assert cli.main(argv) == 2
    assert "key 'widths' holds 0. Fix: use an integer in [1, 65536]" in capsys.readouterr().err


def test_a_file_with_nan_names_the_file(tmp_path, capsys) -> None:
    task = {**json.loads((configs_dir() / "task" / "test.json").read_text()), "human_beta": float("nan")}
    path = tmp_path / "task.json"
    path.write_text(json.dumps(task))  # json writes NaN, which json reads back
    assert "NaN" in path.read_text()
    assert cli.main(["train", "--dry-run", "--task-conf", str(path)]) == 2
    assert f"{path}: key 'human_beta' is nan. Fix:" in capsys.readouterr().err


def test_replace_is_checked_too() -> None:
    """A value set in code (e.g. --train-days, the learner's fitted num_envs) is checked like a file's."""
    with pytest.raises(ConfigError, match="key 'train_days' is 0"):
        dataclasses.replace(HybridConfig(), train_days=0)
    with pytest.raises(ConfigError, match="key 'stuck_time_s' is 0"):
        SumoConfig(stuck_time_s=0)


def test_every_shipped_config_is_in_range() -> None:
    classes = {"task": TaskConfig, "env": EnvConfig, "hybrid": HybridConfig}
    for kind, cls in classes.items():
        for path in sorted((configs_dir() / kind).glob("*.json")):
            check_ranges(cls(**{k: tuple(v) if isinstance(v, list) else v
                                for k, v in read_json(path).items() if k != "desc"}))


def test_a_key_given_twice_is_refused(tmp_path, capsys) -> None:
    path = tmp_path / "task.json"
    text = (configs_dir() / "task" / "test.json").read_text().rstrip().rstrip("}")
    path.write_text(text + ', "ratio_machines": 0.1, "ratio_machines": 0.9}')
    with pytest.raises(ConfigError, match=r"task.json: key 'ratio_machines' is given twice.*Fix: keep one"):
        read_json(path)
    assert cli.main(["train", "--dry-run", "--task-conf", str(path)]) == 2
    assert "key 'ratio_machines' is given twice" in capsys.readouterr().err
    nested = tmp_path / "hyb.json"  # any object of the file, not only the top one
    nested.write_text('{"train_days": 10, "x": {"a": 1, "a": 2}}')
    with pytest.raises(ConfigError, match="key 'a' is given twice"):
        read_json(nested)


def test_a_suite_file_with_a_key_given_twice_is_refused(tmp_path) -> None:
    from urb_jax.runs.suite import load_suite

    path = tmp_path / "suite.json"
    path.write_text('{"title": "t", "runs": [{"kind": "train", "id": "a", "args": {"seed": 1, "seed": 2}}]}')
    with pytest.raises(ConfigError, match=r"suite.json: key 'seed' is given twice"):
        load_suite(path)


def test_a_paper_file_with_a_key_given_twice_is_refused(tmp_path) -> None:
    from urb_jax.reporting.paper import load_paper_numbers

    path = tmp_path / "paper.json"
    path.write_text('{"entries": {}, "entries": {}}')
    with pytest.raises(ConfigError, match=r"paper.json: key 'entries' is given twice"):
        load_paper_numbers(path)



@pytest.mark.parametrize("flag", [["--sumo-rounds", "-1"], ["--relax-steps", "0"]])
def test_optimum_flags_out_of_range_name_the_flag(flag, tmp_path, capsys) -> None:
    assert cli.main(["optimum", str(tmp_path), *flag]) == 2  # before the run folder is read
    assert f"flag {flag[0]} is {flag[1]}. Fix: use an integer in" in capsys.readouterr().err
