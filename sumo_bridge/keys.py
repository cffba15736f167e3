"""What identifies a SUMO day: the one scenario key and the one day key.

The scenario key hashes the content SUMO sees (network file bytes, route table, agents), not a
path or an object id, so it names a loaded scenario in a worker, the route file on /dev/shm and
cached days on disk alike. The day key adds everything else that changes a day: the choices, the
CAV mask, the seed, every SumoConfig option but where files live (with the bytes of its additional
files), which SUMO runs it (`sumo_version`), and the source of the modules that turn a SUMO run
into a DayResult (`DAY_CODE`), so that a changed SUMO or a changed day never reads a stored one.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import importlib.metadata
import weakref
from pathlib import Path

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.sumo_bridge.batch import cav_mask, check_choices
from urb_jax.sumo_bridge.config import SumoConfig

# Hashing reads the network file (megabytes on real networks): once per Scenario object.
_SCENARIO_KEYS: weakref.WeakKeyDictionary[Scenario, str] = weakref.WeakKeyDictionary()
_ROUTES_KEYS: weakref.WeakKeyDictionary[Scenario, str] = weakref.WeakKeyDictionary()


def scenario_key(scenario: Scenario) -> str:
    """Content hash of a Scenario as SUMO sees it: network file bytes, edge ids, the route table and
    the agents (ids, OD rows, departures, kinds)."""
    key = _SCENARIO_KEYS.get(scenario)
    if key is None:
        h = hashlib.sha256(routes_key(scenario).encode())
        for arr in (scenario.agent_id, scenario.agent_od, scenario.agent_depart):
            a = np.ascontiguousarray(arr)
            h.update(f";{a.dtype.str}{a.shape};".encode())
            h.update(a.tobytes())
        h.update("\n".join(scenario.agent_kind).encode())
        key = h.hexdigest()[:16]
        _SCENARIO_KEYS[scenario] = key
    return key


def routes_key(scenario: Scenario) -> str:
    """Content hash of what a Scenario's route file and network hold: the network file's bytes, the
    edge ids and the route table (not the agents: a day's departures do not change it)."""
    key = _ROUTES_KEYS.get(scenario)
    if key is None:
        key = _routes_digest(scenario)
        _ROUTES_KEYS[scenario] = key
    return key


def _routes_digest(scenario: Scenario) -> str:
    h = hashlib.sha256(_file_digest(str(scenario.net_file), *_stat(scenario.net_file)).encode())
    h.update("\n".join(scenario.edge_ids).encode())
    for arr in (scenario.od_routes, scenario.od_route_len):
        a = np.ascontiguousarray(arr)
        h.update(f";{a.dtype.str}{a.shape};".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def _stat(path: str | Path) -> tuple[int, int]:
    st = Path(path).stat()
    return st.st_size, st.st_mtime_ns


@functools.lru_cache(maxsize=64)
def _file_digest(path: str, size: int, mtime_ns: int) -> str:
    """sha256 of a file's bytes, read once per (path, size, mtime): Scenarios that differ only in their
    agents (a day's departures) share their network."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


# The modules whose code decides a day's DayResult from the inputs above (insertion, stuck rule,
# tripinfo parsing, the stored file's fields): an edit to their code starts fresh keys.
DAY_MODULES = ("sim.py", "tripinfo.py", "config.py", "types.py", "batch.py", "memo.py")


@functools.cache
def day_code() -> str:
    """Hash of the code of `DAY_MODULES` (`code_text`; read once per process)."""
    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for name in DAY_MODULES:
        h.update(name.encode() + b"\0" + code_text((here / name).read_text()).encode() + b"\0")
    return h.hexdigest()[:16]


def code_text(source: str) -> str:
    """A module's code without what cannot change a day: comments, docstrings, layout (its syntax
    tree, docstrings dropped). So editing a comment keeps the stored days; editing a statement does not."""
    tree = ast.parse(source)
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree)


@functools.cache
def sumo_version() -> str:
    """The SUMO that runs days in this process: libsumo's package version (read from its metadata,
    without importing it), else the version libsumo reports."""
    try:
        return f"libsumo {importlib.metadata.version('libsumo')}"
    except importlib.metadata.PackageNotFoundError:  # a libsumo built from source, on SUMO_HOME
        from urb_jax.sumo_bridge.sim import import_libsumo

        return str(import_libsumo().simulation.getVersion()[1])


def day_key(scenario: Scenario, choices: np.ndarray, seed: int, is_cav: np.ndarray | None,
            config: SumoConfig | None, simulator: str | None = None) -> str:
    """Hash of everything that changes a SUMO day: the scenario key, choices [N], the CAV mask [N]
    (None = the Scenario's agent kinds, so both spellings share a key), the seed, the SumoConfig
    (None: not known to the caller) with its additional files' bytes, what runs the day
    (`simulator`: `sumo_version()` for SUMO's executors; None: not known) and `day_code()`."""
    h = hashlib.sha256(scenario_key(scenario).encode())
    h.update(check_choices(scenario, choices).tobytes())  # [N] int64
    h.update(cav_mask(scenario, is_cav).tobytes())  # [N] bool
    h.update(f";seed={int(seed)};config={_config_text(config)};simulator={simulator or '?'}"
             f";code={day_code()}".encode())
    return h.hexdigest()[:32]


@functools.lru_cache(maxsize=16)
def _config_text(config: SumoConfig | None) -> str:
    if config is None:
        return "?"
    text = repr(dataclasses.replace(config, shm_dir=""))  # where files live does not change a day
    for path in config.additional_files:  # what they hold does
        text += f";{hashlib.sha256(Path(path).read_bytes()).hexdigest()}"
    return text
