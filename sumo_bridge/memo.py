"""The one SUMO-day cache: identical days are run once. SUMO is deterministic for a (scenario,
choices, CAV mask, seed, SumoConfig), so a stored result is the day a re-run would give
(`tests/test_sumo_pool.py` checks that days are deterministic across workers and repeats).

Two users: URB's test phase repeats one joint action (greedy policies meet frozen deterministic
humans, so all `test_eps` days of a seed are the same day): simulating it once gives the same
records at a hundredth of the cost. Surrogate calibration and validation (`surrogate.sumo_days`)
keep days on disk across runs. Keys: `keys.day_key`; files: `store_dir/<net>-<scenario key>/
<day key>.npz`, written atomically; an entry that cannot be read is run again and rewritten. Each
entry also holds its day key and the sha256 of its arrays (`_key`, `_sha256`): an entry whose
content does not match its name (a renamed or copied file, bytes changed on disk) is a miss, logged,
and the day is run again and rewritten. Entries from before these fields are read as they are.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import cast

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.atomic import write_npz
from urb_jax.sumo_bridge.batch import as_batch
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.sumo_bridge.keys import day_key, scenario_key
from urb_jax.sumo_bridge.types import DayExecutor, DayResult

log = logging.getLogger(__name__)

# what np.load and DayResult(**fields) raise on a truncated, foreign or outdated file
_DAMAGED = (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile)


class MemoExecutor:
    """Wraps a `DayExecutor`: a batch runs each distinct day not yet stored once, in one inner batch.

    `store_dir`: also keep days on disk there (None: in memory only, for this object's life).
    `config`: the SumoConfig the inner executor runs with, part of every key; by default the inner
    executor's `config` (SumoPool, RayExecutor and InProcessExecutor have one)."""

    def __init__(self, inner: DayExecutor, store_dir: str | os.PathLike | None = None,
                 config: SumoConfig | None = None) -> None:
        self.inner = inner
        self.store_dir = Path(store_dir) if store_dir is not None else None
        self.config: SumoConfig | None = config if config is not None else getattr(inner, "config", None)
        self.cache: dict[str, DayResult] = {}
        self.simulated = 0
        self.reused = 0  # served from memory or disk

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: int | Sequence[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        batch = as_batch(choices, seeds, is_cav)
        keys = [day_key(scenario, c, s, m, self.config)
                for c, s, m in zip(batch.choices, batch.seeds, batch.cavs, strict=True)]
        todo: dict[str, int] = {}  # key -> first batch row with it
        for i, key in enumerate(keys):
            if key not in todo and not self._lookup(scenario, key):
                todo[key] = i
        if todo:
            rows = list(todo.values())
            # every row has a mask or none has (as_batch)
            mask_arg = None if batch.cavs[0] is None else np.stack(
                cast("list[np.ndarray]", [batch.cavs[i] for i in rows]))
            days = self.inner.run_days(scenario, batch.choices[rows], [batch.seeds[i] for i in rows],
                                       is_cav=mask_arg)
            for key, day in zip(todo, days, strict=True):
                self.cache[key] = day
                if self.store_dir is not None:
                    save_day(self._path(scenario, key), day, key)
        self.simulated += len(todo)
        self.reused += len(keys) - len(todo)
        return [self.cache[k] for k in keys]

    def _lookup(self, scenario: Scenario, key: str) -> bool:
        """Whether the day is in memory, after loading it from disk if it is stored there."""
        if key in self.cache:
            return True
        if self.store_dir is None:
            return False
        path = self._path(scenario, key)
        if not path.is_file():
            return False
        try:
            self.cache[key] = load_day(path, key)
        except _DAMAGED as exc:  # a damaged entry: run the day again (and rewrite it)
            log.warning("SUMO day cache entry %s is unreadable (%s): re-running the day and rewriting it",
                        path, _first_line(exc))
            return False
        except EntryMismatchError as exc:
            log.warning("SUMO day cache entry %s does not match its key (%s): re-running the day and "
                        "rewriting it", path, exc)
            return False
        return True

    def _path(self, scenario: Scenario, key: str) -> Path:
        assert self.store_dir is not None
        return self.store_dir / f"{scenario.name}-{scenario_key(scenario)}" / f"{key}.npz"

    def close(self) -> None:
        self.inner.close()

    def __enter__(self) -> MemoExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]


class EntryMismatchError(Exception):
    """A stored day whose content is not the day its key names."""


def _arrays_sha256(arrays: dict[str, np.ndarray]) -> str:
    """sha256 over the fields' names, dtypes, shapes and bytes, in name order."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name};{a.dtype.str};{a.shape};".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_day(path: str | os.PathLike, day: DayResult, key: str | None = None) -> None:
    """One DayResult as an .npz of its fields (atomic; `leave_time` left out when None), with the
    sha256 of its arrays and, given, the day key it is stored under."""
    arrays = {f.name: np.asarray(getattr(day, f.name)) for f in dataclasses.fields(day)
              if getattr(day, f.name) is not None}
    tags = {"_sha256": np.asarray(_arrays_sha256(arrays))}
    if key is not None:
        tags["_key"] = np.asarray(key)
    write_npz(path, **arrays, **tags)


def load_day(path: str | os.PathLike, key: str | None = None) -> DayResult:
    """The DayResult `save_day` wrote (raises on a damaged file; EntryMismatchError where its arrays
    do not match their stored sha256, or it was stored under another key than `key`)."""
    with np.load(path) as d:
        a = {k: d[k] for k in d.files}
    digest, stored_key = a.pop("_sha256", None), a.pop("_key", None)
    if digest is not None and str(digest) != _arrays_sha256(a):
        raise EntryMismatchError("its arrays do not match the sha256 stored with them")
    if key is not None and stored_key is not None and str(stored_key) != key:
        raise EntryMismatchError(f"it holds day {stored_key}")
    return DayResult(
        travel_time=a["travel_time"], duration=a["duration"], route_length=a["route_length"],
        mean_speed=a["mean_speed"], time_loss=a["time_loss"], depart_delay=a["depart_delay"],
        status=a["status"], seed=int(a["seed"]), stat_mean_speed=float(a["stat_mean_speed"]),
        stat_mean_route_length=float(a["stat_mean_route_length"]),
        stat_mean_duration=float(a["stat_mean_duration"]), teleports=int(a["teleports"]),
        n_removed=int(a["n_removed"]), sim_end_time=float(a["sim_end_time"]),
        wall_time=float(a["wall_time"]), leave_time=a.get("leave_time"),
    )
