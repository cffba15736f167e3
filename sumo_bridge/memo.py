"""The one SUMO-day cache: identical days are run once. SUMO is deterministic for a (scenario,
choices, CAV mask, seed, SumoConfig, SUMO version), so a stored result is the day a re-run would
give (`tests/test_sumo_pool.py` checks that days are deterministic across workers and repeats).

In memory (`MemoExecutor(inner)`): URB's test phase repeats one joint action (greedy policies meet
frozen deterministic humans, so all `test_eps` days of a seed are the same day), and a baseline's
frozen humans meet fixed CAVs: simulating such a day once gives the same records at a fraction of
the cost.

On disk (`store_dir`), the day store: `day_store(inner)` puts every run's SUMO days behind one
store under the cache root (`$URB_JAX_CACHE/sumo_days/`), shared by train runs (human phase,
calibration, SUMO training and test days), baselines, surrogate validation and suites, so a day is
paid once. Keys: `keys.day_key`; files: `store_dir/<net>-<scenario key>/<day key>.npz`, written
atomically; a read touches the file (its mtime is its last use), and when the store outgrows its
cap the least recently used files go. An entry that cannot be read is run again and rewritten; one
that vanished (another process evicted it) is a miss, run again. Each
entry also holds its day key and the sha256 of its arrays (`_key`, `_sha256`): an entry whose
content does not match its name (a renamed or copied file, bytes changed on disk) is a miss, logged,
and the day is run again and rewritten. Entries from before these fields are read as they are.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import os
import time
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import cast

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.atomic import write_npz
from urb_jax.core.paths import cache_dir, day_store_bytes
from urb_jax.sumo_bridge.batch import as_batch
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.sumo_bridge.keys import day_key, scenario_key, sumo_version
from urb_jax.sumo_bridge.types import DayExecutor, DayResult

log = logging.getLogger(__name__)

# what np.load and DayResult(**fields) raise on a truncated, foreign or outdated file
_DAMAGED = (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile)
STORE_DIR = "sumo_days"  # the day store, under the cache root
RESCAN_EVERY = 256  # stored days between two looks at the whole store's size (other runs write too)
LOW_WATER = 0.9  # eviction frees down to this fraction of the cap, so it does not run every write
STALE_TMP_S = 3600.0  # a writer's temporary file older than this was left by a killed process


class MemoExecutor:
    """Wraps a `DayExecutor`: a batch runs each distinct day not yet stored once, in one inner batch.

    `store_dir`: keep days on disk there, not in memory (None: in memory only, for this object's
    life). `config`: the SumoConfig the inner executor runs with, part of every key; by default the
    inner executor's `config` (SumoPool, RayExecutor and InProcessExecutor have one). `simulator`:
    what runs the days (`keys.sumo_version()`), part of every key; by default the inner executor's
    `simulator`. `max_bytes`: the store's cap (None: no cap); the least recently used days go when
    the store outgrows it."""

    def __init__(self, inner: DayExecutor, store_dir: str | os.PathLike | None = None,
                 config: SumoConfig | None = None, *, simulator: str | None = None,
                 max_bytes: int | None = None) -> None:
        self.inner = inner
        self.store_dir = Path(store_dir) if store_dir is not None else None
        self.config: SumoConfig | None = config if config is not None else getattr(inner, "config", None)
        self.simulator: str | None = simulator if simulator is not None else getattr(inner, "simulator", None)
        self.max_bytes = max_bytes
        self.cache: dict[str, DayResult] = {}  # in memory only (no store_dir)
        self.simulated = 0
        self.reused = 0  # served from memory or disk
        self._size: int | None = None  # the store's bytes at the last look, plus what this object wrote since
        self._since_scan = 0
        self._write_failed = False

    @property
    def stored(self) -> bool:
        """Whether days are kept on disk."""
        return self.store_dir is not None

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: int | Sequence[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        batch = as_batch(choices, seeds, is_cav)
        keys = [day_key(scenario, c, s, m, self.config, self.simulator)
                for c, s, m in zip(batch.choices, batch.seeds, batch.cavs, strict=True)]
        found: dict[str, DayResult] = {}
        todo: dict[str, int] = {}  # key -> first batch row with it
        for i, key in enumerate(keys):
            if key in found or key in todo:
                continue
            day = self._lookup(scenario, key)
            if day is None:
                todo[key] = i
            else:
                found[key] = day
        if todo:
            rows = list(todo.values())
            # every row has a mask or none has (as_batch)
            mask_arg = None if batch.cavs[0] is None else np.stack(
                cast("list[np.ndarray]", [batch.cavs[i] for i in rows]))
            days = self.inner.run_days(scenario, batch.choices[rows], [batch.seeds[i] for i in rows],
                                       is_cav=mask_arg)
            for key, day in zip(todo, days, strict=True):
                found[key] = day
                if self.store_dir is None:
                    self.cache[key] = day
                else:
                    self._store(self._path(scenario, key), day, key)
        self.simulated += len(todo)
        self.reused += len(keys) - len(todo)
        return [found[k] for k in keys]

    def _lookup(self, scenario: Scenario, key: str) -> DayResult | None:
        """The day from memory or the store (touched: its last use), or None."""
        if self.store_dir is None:
            return self.cache.get(key)
        path = self._path(scenario, key)
        try:
            day = load_day(path, key)
        except FileNotFoundError:  # never stored, or evicted (maybe by another run just now)
            return None
        except _DAMAGED as exc:  # a damaged entry: run the day again (and rewrite it)
            log.warning("SUMO day cache entry %s is unreadable (%s): re-running the day and rewriting it",
                        path, _first_line(exc))
            return None
        except EntryMismatchError as exc:
            log.warning("SUMO day cache entry %s does not match its key (%s): re-running the day and "
                        "rewriting it", path, exc)
            return None
        with contextlib.suppress(OSError):  # evicted since the read: the day is in hand anyway
            os.utime(path)
        return day

    def _store(self, path: Path, day: DayResult, key: str) -> None:
        """Write one day (a store that cannot be written is a warning once: the run goes on),
        then keep the store under its cap."""
        if self._write_failed:
            return
        try:
            save_day(path, day, key)
            size = path.stat().st_size
        except OSError as exc:
            self._write_failed = True
            log.warning("SUMO day store %s cannot be written (%s): this run's days are not stored",
                        self.store_dir, _first_line(exc))
            return
        if self.max_bytes is None:
            return
        self._since_scan += 1
        if self._size is not None:
            self._size += size
        if self._size is None or self._size > self.max_bytes or self._since_scan >= RESCAN_EVERY:
            assert self.store_dir is not None
            self._size = evict(self.store_dir, self.max_bytes)
            self._since_scan = 0

    def _path(self, scenario: Scenario, key: str) -> Path:
        assert self.store_dir is not None
        return self.store_dir / f"{scenario.name}-{scenario_key(scenario)}" / f"{key}.npz"

    def close(self) -> None:
        self.inner.close()

    def __enter__(self) -> MemoExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def day_store_dir() -> Path:
    """Where the day store lives: `sumo_days/` under urb-jax's cache root (`core.paths.cache_dir`)."""
    return cache_dir() / STORE_DIR


def day_store(inner: DayExecutor, enabled: bool = True) -> DayExecutor:
    """`inner` behind the day store (`day_store_dir()`, capped at `core.paths.day_store_bytes()`),
    or `inner` itself when the store is off: `enabled` False (`--no-day-store`), a cap of 0
    (`URB_JAX_DAY_STORE_GB=0`), or an executor whose days are not SUMO's (no `simulator`: a test's
    stand-in days must never be served as SUMO's)."""
    if not enabled or getattr(inner, "simulator", None) is None:
        return inner
    cap = day_store_bytes()
    if cap == 0:
        return inner
    return MemoExecutor(inner, store_dir=day_store_dir(), max_bytes=cap)


class LazyExecutor:
    """A `DayExecutor` made by `make()` on its first batch, so that a run whose days are all in the
    day store starts no SUMO process (a pool's workers take seconds to start). `config`: the
    SumoConfig the made executor will run with (part of every day's key before it exists)."""

    def __init__(self, make: Callable[[], DayExecutor], config: SumoConfig) -> None:
        self._make = make
        self.config = config
        self.executor: DayExecutor | None = None

    @property
    def simulator(self) -> str:
        return sumo_version()

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        if self.executor is None:
            self.executor = self._make()
            made = getattr(self.executor, "config", None)
            if made != self.config:
                raise ValueError(f"LazyExecutor: the executor made runs {made}, not {self.config}")
        return self.executor.run_days(scenario, choices, seeds, is_cav)

    def close(self) -> None:
        if self.executor is not None:
            self.executor.close()


def is_stored(executor: DayExecutor) -> bool:
    """Whether `executor` keeps its days in a store on disk (`day_store`, a journal)."""
    return isinstance(executor, MemoExecutor) and executor.stored


def evict(store_dir: Path, max_bytes: int) -> int:
    """Keep `store_dir` under `max_bytes`: when its days take more, remove the least recently used
    (oldest mtime: a read touches) until they take at most LOW_WATER of it; also removes writers'
    temporary files older than STALE_TMP_S. Safe beside other processes: a file another one removed
    first is skipped (and a reader that finds it gone runs the day again). Returns the bytes left."""
    entries: list[tuple[float, int, Path]] = []
    now = time.time()
    with contextlib.suppress(FileNotFoundError):
        for sub in os.scandir(store_dir):
            if not sub.is_dir(follow_symlinks=False):
                continue
            with contextlib.suppress(FileNotFoundError):
                for f in os.scandir(sub.path):
                    try:
                        st = f.stat(follow_symlinks=False)
                    except FileNotFoundError:
                        continue
                    if f.name.endswith(".npz") and not f.name.startswith("."):
                        entries.append((st.st_mtime, st.st_size, Path(f.path)))
                    elif f.name.endswith(".tmp") and now - st.st_mtime > STALE_TMP_S:
                        with contextlib.suppress(FileNotFoundError):
                            os.unlink(f.path)
    total = sum(size for _, size, _ in entries)
    if total <= max_bytes:
        return total
    target = int(max_bytes * LOW_WATER)
    for _, size, path in sorted(entries, key=lambda e: e[0]):
        if total <= target:
            break
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        total -= size
    log.info("SUMO day store %s: least recently used days removed, %d bytes left (cap %d)",
             store_dir, total, max_bytes)
    return total


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
    """One DayResult as an .npz of its fields (atomic; optional fields left out when None), with the
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
        wall_time=float(a["wall_time"]), leave_time=a.get("leave_time"), co2_g=a.get("co2_g"),
        fuel_mg=a.get("fuel_mg"),
    )
