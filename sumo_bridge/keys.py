"""What identifies a SUMO day: the one scenario key and the one day key.

The scenario key hashes the content SUMO sees (network file bytes, route table, agents), not a
path or an object id, so it names a loaded scenario in a worker, the route file on /dev/shm and
cached days on disk alike. The day key adds everything else that changes a day.
"""

from __future__ import annotations

import dataclasses
import hashlib
import weakref
from pathlib import Path

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.sumo_bridge.batch import cav_mask, check_choices
from urb_jax.sumo_bridge.config import SumoConfig

# Hashing reads the network file (megabytes on real networks): once per Scenario object.
_SCENARIO_KEYS: weakref.WeakKeyDictionary[Scenario, str] = weakref.WeakKeyDictionary()


def scenario_key(scenario: Scenario) -> str:
    """Content hash of a Scenario as SUMO sees it: network file bytes, edge ids, the route table and
    the agents (ids, OD rows, departures, kinds)."""
    key = _SCENARIO_KEYS.get(scenario)
    if key is None:
        h = hashlib.sha256(Path(scenario.net_file).read_bytes())
        h.update("\n".join(scenario.edge_ids).encode())
        for arr in (scenario.od_routes, scenario.od_route_len, scenario.agent_id, scenario.agent_od,
                    scenario.agent_depart):
            a = np.ascontiguousarray(arr)
            h.update(f";{a.dtype.str}{a.shape};".encode())
            h.update(a.tobytes())
        h.update("\n".join(scenario.agent_kind).encode())
        key = h.hexdigest()[:16]
        _SCENARIO_KEYS[scenario] = key
    return key


def day_key(scenario: Scenario, choices: np.ndarray, seed: int, is_cav: np.ndarray | None,
            config: SumoConfig | None) -> str:
    """Hash of everything that changes a SUMO day: the scenario key, choices [N], the CAV mask [N]
    (None = the Scenario's agent kinds, so both spellings share a key), the seed, and the
    SumoConfig (None: not known to the caller)."""
    h = hashlib.sha256(scenario_key(scenario).encode())
    h.update(check_choices(scenario, choices).tobytes())  # [N] int64
    h.update(cav_mask(scenario, is_cav).tobytes())  # [N] bool
    h.update(f";seed={int(seed)};config={_config_text(config)}".encode())
    return h.hexdigest()[:24]


def _config_text(config: SumoConfig | None) -> str:
    if config is None:
        return "?"
    return repr(dataclasses.replace(config, shm_dir=""))  # where files live does not change a day
