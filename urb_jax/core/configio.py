"""Load JSON configs into typed, frozen dataclasses; unknown keys and wrong types are errors
that name the file, the key and the fix. Shared by task/env/algo configs; a file may be written
with URB's key names (`urb_jax.core.urb_keys`, resolved here, in `load_resolved`)."""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from urb_jax import configs
from urb_jax.core.errors import ConfigError
from urb_jax.core.urb_keys import Family, Resolution, resolve

T = TypeVar("T")


def configs_dir() -> Path:
    """The shipped configs (installed as the package urb_jax.configs)."""
    return Path(configs.__file__).resolve().parent


def _type_ok(value: Any, annotation: Any) -> bool:
    origin = typing.get_origin(annotation)
    if annotation is Any:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, a) for a in typing.get_args(annotation))
    if annotation is type(None):
        return value is None
    if annotation is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if annotation is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if origin in (tuple, list):
        args = typing.get_args(annotation)
        if not isinstance(value, list | tuple):
            return False
        if origin is tuple and args and args[-1] is not Ellipsis:
            return len(value) == len(args) and all(_type_ok(v, a) for v, a in zip(value, args, strict=True))
        inner = args[0] if args else Any
        return all(_type_ok(v, inner) for v in value)
    if origin is typing.Literal:
        return value in typing.get_args(annotation)
    if isinstance(annotation, type):
        return isinstance(value, annotation)
    return True


def from_dict(cls: type[T], data: dict[str, Any], source: str = "<dict>") -> T:
    """Build `cls` from a dict, naming `source` and the key in every error."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls} is not a dataclass")
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(known) - {"desc"})
    if unknown:
        raise ConfigError(
            f"{source}: unknown key(s) {', '.join(repr(k) for k in unknown)}. Fix: correct the name; the "
            f"keys are: {', '.join(sorted(known))} (URB's names for them are accepted too, "
            "docs/experiment.md, \"URB's configs as written\")."
        )
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        if name == "desc":
            continue
        annotation = hints[name]
        if not _type_ok(value, annotation):
            raise ConfigError(
                f"{source}: key '{name}' has value {value!r} of type {type(value).__name__}; "
                f"expected {getattr(annotation, '__name__', annotation)}."
            )
        if typing.get_origin(annotation) is tuple or annotation is tuple:
            value = tuple(value)
        elif annotation is float and isinstance(value, int):
            value = float(value)
        kwargs[name] = value
    missing = [f.name for f in known.values()
               if f.name not in kwargs and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ConfigError(f"{source}: missing key(s) {', '.join(missing)}.")
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from exc


@dataclass(frozen=True)
class Loaded(Generic[T]):
    """A typed config, the file it came from, and how its keys were resolved."""

    config: T
    path: Path
    resolution: Resolution


def load_json(cls: type[T], path: str | Path, family: Family | None = None) -> T:
    return load_resolved(cls, path, family).config


def load_resolved(cls: type[T], path: str | Path, family: Family | None = None) -> Loaded[T]:
    """`path` as `cls`, read in the dialect of URB's config `family` (None: urb-jax's names only)."""
    data = read_json(Path(path))
    resolved, resolution = resolve(data, family, str(path))
    return Loaded(from_dict(cls, resolved, str(path)), Path(path), resolution)


def read_json(path: Path) -> dict[str, Any]:
    """The JSON object in `path`; a missing file, bad JSON or a non-object are ConfigErrors."""
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found.")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc}).") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: must hold a JSON object.")
    return data


def find_config(kind: str, name: str, subdir: str | None = None) -> Path:
    """Resolve a config by id (`configs/<kind>[/<subdir>]/<name>.json`) or by explicit path."""
    as_path = Path(name)
    if as_path.suffix == ".json" and as_path.is_file():
        return as_path
    folder = configs_dir() / kind / (subdir or "")
    path = folder / f"{name}.json"
    if not path.is_file():
        choices = sorted(p.stem for p in folder.glob("*.json")) if folder.is_dir() else []
        raise ConfigError(
            f"{path}: no {kind} config '{name}'. Fix: use one of {', '.join(choices) or '(none)'} "
            "or pass a path to a .json file."
        )
    return path


def to_dict(obj: Any) -> dict[str, Any]:
    return dataclasses.asdict(obj)
