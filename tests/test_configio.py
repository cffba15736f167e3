from dataclasses import dataclass

import pytest

from urb_jax.core.configio import from_dict, load_json
from urb_jax.core.errors import ConfigError


@dataclass(frozen=True)
class Example:
    lr: float
    widths: tuple[int, ...] = (64, 64)
    name: str = "x"
    share: float | None = None


def test_valid_and_coerced():
    cfg = from_dict(Example, {"lr": 1, "widths": [32], "desc": "ignored"})
    assert cfg == Example(lr=1.0, widths=(32,))
    assert isinstance(cfg.lr, float)


def test_unknown_key_names_source_and_fix():
    with pytest.raises(ConfigError, match=r"cfg\.json: unknown key\(s\) 'lrr'. Fix: .*lr"):
        from_dict(Example, {"lrr": 1.0}, "cfg.json")


def test_wrong_type_and_missing():
    with pytest.raises(ConfigError, match="key 'widths' has value 'abc'"):
        from_dict(Example, {"lr": 1.0, "widths": "abc"})
    with pytest.raises(ConfigError, match=r"key .lr. has value True"):
        from_dict(Example, {"lr": True})
    with pytest.raises(ConfigError, match=r"missing key"):
        from_dict(Example, {})


def test_load_json_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match=r"bad\.json: not valid JSON"):
        load_json(Example, bad)
    with pytest.raises(ConfigError, match="not found"):
        load_json(Example, tmp_path / "missing.json")
