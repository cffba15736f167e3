"""Load JSON configs into typed, frozen dataclasses; unknown keys and wrong types are errors
that name the file, the key and the fix. Shared by task/env/algo configs; a file may be written
with URB's key names (`urb_jax.core.urb_keys`, resolved here, in `load_resolved`). Command-line
overrides (`--set alg.lr=1e-3`, `Override`) replace a file's key before it is resolved, so they
are typed, aliased and validated exactly like the file's own keys."""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar, cast

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
    overridden: dict[str, Any] = field(default_factory=dict)  # field set by --set -> its typed value


@dataclass(frozen=True)
class Override:
    """One `--set SECTION.KEY=VALUE`: VALUE read as JSON (1e-3, 8, true, null, [64, 64], "text"),
    or as text when it is not JSON (a bare word)."""

    given: str  # as typed, for errors and exp_config.json
    section: str  # task, env, alg, hybrid
    key: str  # urb-jax's name or URB's
    value: Any


OVERRIDE_HELP = ('values are read as JSON (1e-3, 8, true, null, [64, 64], "text"); a bare word is text, '
                 "so quote a text that JSON would read otherwise: 'SECTION.KEY=\"1\"'")


def parse_overrides(items: Iterable[str], sections: Sequence[str]) -> tuple[Override, ...]:
    """`--set` items as `Override`s; a malformed item or an unknown section is a ConfigError."""
    out = []
    for item in items:
        target, sep, text = item.partition("=")
        section, dot, key = target.strip().partition(".")
        if not sep or not dot or not key or section not in sections:
            raise ConfigError(f"--set {item!r}: expected SECTION.KEY=VALUE with SECTION one of "
                              f"{', '.join(sections)}. Fix: e.g. --set {sections[0]}.<key>=<value>.")
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        out.append(Override(item, section, key, value))
    return tuple(out)


def in_section(overrides: Iterable[Override], name: str) -> tuple[Override, ...]:
    return tuple(o for o in overrides if o.section == name)


def load_json(cls: type[T], path: str | Path, family: Family | None = None,
              overrides: Sequence[Override] = ()) -> T:
    return load_resolved(cls, path, family, overrides).config


def load_resolved(cls: type[T], path: str | Path, family: Family | None = None,
                  overrides: Sequence[Override] = ()) -> Loaded[T]:
    """`path` as `cls`, read in the dialect of URB's config `family` (None: urb-jax's names only),
    with `overrides` (one section's) replacing the file's keys before anything is resolved."""
    data = read_json(Path(path))
    source = str(path)
    if overrides:
        data = _apply_overrides(cls, data, overrides, family, source)
        source = f"{path} with --set {' '.join(o.given for o in overrides)}"
    resolved, resolution = resolve(data, family, source)
    config = from_dict(cls, resolved, source)
    fields = {f.name for f in dataclasses.fields(cast(type, cls))}  # a dataclass: from_dict checked
    targets = [_target(o.key, family) for o in overrides]
    return Loaded(config, Path(path), resolution,
                  {t: getattr(config, t) for t in targets if t in fields})


def _target(key: str, family: Family | None) -> str:
    """The urb-jax field a key sets (URB's alias resolved)."""
    return family.aliases.get(key, key) if family is not None else key


def _apply_overrides(cls: type, data: Mapping[str, Any], overrides: Sequence[Override],
                     family: Family | None, source: str) -> dict[str, Any]:
    """`data` with each override's key set, after removing the file's keys that set the same
    field under another name (ours or URB's). An override's key must be a key of the config (or
    a URB key its family knows: refused and ignored ones are reported by `resolve`), and its
    value of the key's type; errors name the override and the fix. A URB alias given for a file
    in urb-jax's names sets our field directly (else the file would read as URB's, whose
    required keys it need not have)."""
    hints = typing.get_type_hints(cls)
    fields = sorted(f.name for f in dataclasses.fields(cls) if f.init)
    urb_keys = set(family.aliases) | set(family.ignored) | set(family.derived) | set(family.refused) \
        if family is not None else set()
    urb_file = family is not None and any(k in family.aliases for k in data)
    out = dict(data)
    for o in overrides:
        target = _target(o.key, family)
        if target not in fields and o.key not in urb_keys:
            raise ConfigError(f"--set {o.given}: the {o.section} config ({source}) has no key '{o.key}'. "
                              f"Fix: use one of {', '.join(fields)} (URB's names for them are accepted too).")
        if target in fields and not _type_ok(o.value, hints[target]):
            expected = getattr(hints[target], "__name__", hints[target])
            raise ConfigError(f"--set {o.given}: key '{o.key}' takes {expected}, got {o.value!r} "
                              f"({type(o.value).__name__}). Fix: give a {expected}; {OVERRIDE_HELP}.")
        for key in [k for k in out if _target(k, family) == target]:
            del out[key]
        out[o.key if urb_file else target] = o.value
    return out


class DuplicateKeyError(ValueError):
    """A JSON object names one key twice (json.loads would keep the last value without a word)."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    seen: set[str] = set()
    for key, _ in pairs:
        if key in seen:
            raise DuplicateKeyError(key)
        seen.add(key)
    return dict(pairs)


def loads_strict(text: str, source: object) -> Any:
    """JSON `text` where an object that gives one key twice is a ConfigError naming `source` and the
    key (plain json.loads keeps the last value); invalid JSON raises json.JSONDecodeError, as
    json.loads does. What every config and suite file the tool reads is parsed with."""
    try:
        return json.loads(text, object_pairs_hook=_unique_keys)
    except DuplicateKeyError as exc:
        raise ConfigError(f"{source}: key '{exc.args[0]}' is given twice in one object (JSON would keep the "
                          "last value and ignore the first). Fix: keep one of them.") from None


def read_json(path: Path) -> dict[str, Any]:
    """The JSON object in `path`; a missing file, bad JSON, a key given twice or a non-object are
    ConfigErrors."""
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found.")
    try:
        data = loads_strict(path.read_text(), path)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc}).") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read it ({exc}). Fix: check the file's permissions and that it "
                          "is a UTF-8 JSON file.") from exc
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
