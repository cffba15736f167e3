"""The valid range of every numeric config value, declared once per config class and checked by one
validator.

Each config dataclass (task, env, algorithm, hybrid, SUMO) declares `RANGES: ClassVar[dict[str,
Range]]`, a range for each of its int and float fields (a tuple of numbers: for each element), and
calls `check_ranges(self)` first thing in `__post_init__`, so a file, a `--set` item, a
`dataclasses.replace` and a dry run are all checked alike. NaN and +-Infinity are never in a range
(JSON reads `NaN`, `Infinity`; every `<=` check lets NaN through), and every range has an upper end,
so an absurd size is refused at load instead of failing hours later (or exhausting memory). A
numeric field without a declared range is a programming error (`TypeError` on first use), so a new
field cannot skip the check.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass
from typing import Any

from urb_jax.core.errors import ConfigError

_NUMBER = (int, float)


@dataclass(frozen=True)
class Range:
    """Values from `low` to `high` (both included, unless `open_low`); `note`: why, or what URB uses."""

    low: float
    high: float
    open_low: bool = False
    note: str = ""

    def __contains__(self, value: object) -> bool:
        if not isinstance(value, _NUMBER) or isinstance(value, bool):
            return False
        if not math.isfinite(value):
            return False
        return (value > self.low if self.open_low else value >= self.low) and value <= self.high

    def text(self, integer: bool) -> str:
        """'an integer in [1, 4096]', 'a finite number in (0, 10]' (and the note)."""
        kind = "an integer" if integer else "a finite number"
        note = f" ({self.note})" if self.note else ""
        return f"{kind} in {'(' if self.open_low else '['}{_num(self.low)}, {_num(self.high)}]{note}"


def between(low: float, high: float, note: str = "") -> Range:
    """[low, high]."""
    return Range(low, high, note=note)


def above(low: float, high: float, note: str = "") -> Range:
    """(low, high]: e.g. a learning rate, a timeout."""
    return Range(low, high, open_low=True, note=note)


FRACTION = between(0, 1)  # a share, a probability, a discount
SIZE = 65_536  # a layer's width, an embedding: beyond it one layer alone outgrows a GPU
DAYS = 10_000_000  # day budgets: ~10,000 x URB's 1,000 training days
STEPS = 10_000_000  # iterations, optimiser steps
WORKERS = 1_024  # processes and seeds run side by side
ENVS = 16_384  # parallel environments


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else repr(x)


def _shown(value: Any) -> str:
    return repr(value) if not isinstance(value, float) or math.isfinite(value) or math.isnan(value) \
        else ("Infinity" if value > 0 else "-Infinity")


_numeric: dict[type, dict[str, bool]] = {}  # numeric_fields' answers, by class


def numeric_fields(cls: type) -> dict[str, bool]:
    """The fields of dataclass `cls` that hold numbers (or tuples of numbers): name -> integer-valued."""
    if cls not in _numeric:
        hints = typing.get_type_hints(cls)
        kinds = {f.name: _number_kinds(hints[f.name]) for f in dataclasses.fields(cls)}
        _numeric[cls] = {name: k == {int} for name, k in kinds.items() if k}
    return _numeric[cls]


def _number_kinds(annotation: Any) -> set[type]:
    origin = typing.get_origin(annotation)
    if annotation in _NUMBER:
        return {annotation}
    if origin in (typing.Union, types.UnionType, tuple, list):
        return set().union(*(_number_kinds(a) for a in typing.get_args(annotation) if a is not Ellipsis))
    return set()


def check_ranges(config: Any) -> None:
    """Every numeric field of `config` in its class's declared range; else a ConfigError naming the
    key, the value and the valid range (the loader prefixes the file)."""
    cls = type(config)
    ranges: dict[str, Range] = getattr(cls, "RANGES", {})
    undeclared = sorted(set(numeric_fields(cls)) - set(ranges))
    if undeclared:
        raise TypeError(f"{cls.__name__}.RANGES declares no range for {', '.join(undeclared)}")
    for name, integer in numeric_fields(cls).items():
        value = getattr(config, name)
        values = value if isinstance(value, tuple | list) else (value,)
        for v in values:
            if isinstance(v, _NUMBER) and not isinstance(v, bool) and v not in ranges[name]:
                which = f" holds {_shown(v)}" if values is value else f" is {_shown(v)}"
                raise ConfigError(f"key '{name}'{which}. Fix: use {ranges[name].text(integer)}.")
