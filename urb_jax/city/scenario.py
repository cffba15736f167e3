"""The Scenario: one immutable set of arrays per (network, route parameters, env seed).

Every layer reads it: the surrogate, SUMO days, the environment and the metrics all index the
same route arrays, so the routes the surrogate prices are the routes SUMO drives.

Agent order: agents are sorted by departure second (stable, ties by agents.csv row order);
`agent_id[i]` maps position i back to the URB id. Choices are route indices k in [0, K) per agent
in this order.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import networkx as nx
import numpy as np

from urb_jax.city.network import Demand, NetworkFiles, find_network, read_demand
from urb_jax.city.netxml import NetData, read_net
from urb_jax.city.routes import (
    ODRoutes,
    RouteParams,
    build_route_graph,
    free_flow_times,
    generate_routes,
    unroutable,
)
from urb_jax.core.atomic import write_npz
from urb_jax.core.choices import DEFAULT_NETWORK
from urb_jax.core.errors import NetworkError, RouteError
from urb_jax.core.paths import cache_dir
from urb_jax.core.version import __version__

log = logging.getLogger(__name__)
CACHE_FORMAT = 2  # 2: the drop-unroutable choice in the key, `dropped_unroutable` stored


@dataclass(frozen=True, eq=False)
class Scenario:
    """Arrays describing one URB scenario; N agents, E edges, O OD pairs, K routes, L max edges."""

    name: str
    net_file: str
    env_seed: int
    route_params: RouteParams
    # edges [E]
    edge_ids: tuple[str, ...]
    edge_length: np.ndarray  # m
    edge_speed: np.ndarray  # m/s (speed limit)
    edge_lanes: np.ndarray
    edge_priority: np.ndarray
    edge_type: tuple[str, ...]
    edge_capacity: np.ndarray  # veh/h, see netxml.capacity_per_lane
    # OD pairs [O]
    od_origin: np.ndarray  # index into origins of the od file
    od_destination: np.ndarray
    od_origin_edge: tuple[str, ...]
    od_destination_edge: tuple[str, ...]
    # routes [O, K, L] edge indices, -1 padded
    od_routes: np.ndarray
    od_route_len: np.ndarray  # [O, K] edges per route
    od_route_valid: np.ndarray  # [O, K] False for padding repeats (fewer than K distinct routes)
    od_fft: np.ndarray  # [O, K] URB free-flow time (destination edge excluded), minutes
    od_fft_full: np.ndarray  # [O, K] free-flow time over every edge, minutes
    od_route_length: np.ndarray  # [O, K] metres, every edge
    # agents [N], sorted by departure
    agent_id: np.ndarray
    agent_od: np.ndarray  # index into OD arrays
    agent_origin: np.ndarray
    agent_destination: np.ndarray
    agent_depart: np.ndarray  # int seconds
    agent_kind: tuple[str, ...]  # 'Human' or 'AV' as given in agents.csv
    # [D] ids of agents.csv rows left out because their OD pair has no route (drop_unroutable)
    dropped_unroutable: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def n_agents(self) -> int:
        return int(self.agent_id.shape[0])

    @property
    def n_edges(self) -> int:
        return len(self.edge_ids)

    @property
    def n_od(self) -> int:
        return int(self.od_origin.shape[0])

    @property
    def k(self) -> int:
        return int(self.od_routes.shape[1])

    @property
    def simulation_timesteps(self) -> int:
        """URB's `simulation_timesteps`: the latest departure second."""
        return int(self.agent_depart.max())

    # Per-agent views (gathered from the OD arrays).
    @property
    def routes(self) -> np.ndarray:
        """[N, K, L] edge indices of each agent's K routes."""
        return self.od_routes[self.agent_od]

    @property
    def route_len(self) -> np.ndarray:
        return self.od_route_len[self.agent_od]

    @property
    def route_valid(self) -> np.ndarray:
        return self.od_route_valid[self.agent_od]

    @property
    def fft(self) -> np.ndarray:
        """[N, K] URB free-flow times, minutes."""
        return self.od_fft[self.agent_od]

    @property
    def fft_full(self) -> np.ndarray:
        return self.od_fft_full[self.agent_od]

    def route_edge_ids(self, od: int, k: int) -> list[str]:
        n = int(self.od_route_len[od, k])
        return [self.edge_ids[e] for e in self.od_routes[od, k, :n]]

    def with_agents(self, idx: np.ndarray, **overrides: Any) -> Scenario:
        """The same network and routes with agents `idx`, in that order (a subset, a resampled
        demand); `overrides` replace per-agent fields afterwards (e.g. new ids for copies)."""
        arrays = ("agent_id", "agent_od", "agent_origin", "agent_destination", "agent_depart")
        picked: dict[str, Any] = {f: getattr(self, f)[idx] for f in arrays}
        picked["agent_kind"] = tuple(self.agent_kind[i] for i in idx)
        return replace(self, **{**picked, **overrides})

    def summary(self) -> dict[str, object]:
        return {
            "network": self.name,
            "agents": self.n_agents,
            "od_pairs": self.n_od,
            "edges": self.n_edges,
            "routes_per_od": self.k,
            "ods_with_fewer_distinct_routes": int((~self.od_route_valid).any(axis=1).sum()),
            "max_route_edges": int(self.od_route_len.max()),
            "departures_s": [int(self.agent_depart.min()), int(self.agent_depart.max())],
            "mean_min_fft_min": float(self.fft.min(axis=1).mean()),
            "env_seed": self.env_seed,
            "dropped_unroutable_agents": int(self.dropped_unroutable.shape[0]),
        }

    def dropped_record(self) -> dict[str, object]:
        """exp_config.json's `dropped_unroutable_agents`: how many agents and which."""
        ids = [int(i) for i in self.dropped_unroutable]
        return {"count": len(ids), "ids": ids}


def _file_digest(paths: list[Path]) -> str:
    h = hashlib.sha256()
    for p in paths:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def _cache_key(files: NetworkFiles, params: RouteParams, env_seed: int, drop_unroutable: bool) -> str:
    h = hashlib.sha256()
    h.update(_file_digest([files.net, files.agents, files.od]).encode())
    h.update(json.dumps(asdict(params), sort_keys=True).encode())
    h.update(f"seed={env_seed};drop_unroutable={drop_unroutable};format={CACHE_FORMAT}".encode())
    return h.hexdigest()[:24]


_ARRAY_FIELDS = [f.name for f in fields(Scenario) if f.type in ("np.ndarray",)]
_TUPLE_FIELDS = [f.name for f in fields(Scenario) if f.type.startswith("tuple")]


def _save(scn: Scenario, path: Path) -> None:
    meta = {
        "name": scn.name, "net_file": scn.net_file, "env_seed": scn.env_seed,
        "route_params": asdict(scn.route_params), "version": __version__,
        **{k: list(getattr(scn, k)) for k in _TUPLE_FIELDS},
    }
    arrays = {k: getattr(scn, k) for k in _ARRAY_FIELDS}
    write_npz(path, _meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)


def _load(path: Path) -> Scenario:
    with np.load(path) as data:
        meta = json.loads(data["_meta"].tobytes().decode())
        arrays = {k: data[k] for k in _ARRAY_FIELDS}
    tuples: dict[str, Any] = {k: tuple(meta[k]) for k in _TUPLE_FIELDS}
    return Scenario(
        name=meta["name"], net_file=meta["net_file"], env_seed=meta["env_seed"],
        route_params=RouteParams(**meta["route_params"]), **tuples, **arrays,
    )


def load_scenario(
    network: str = DEFAULT_NETWORK,
    *,
    networks_dir: str | os.PathLike | None = None,
    env_seed: int = 42,
    route_params: RouteParams | None = None,
    use_cache: bool = True,
    workers: int | None = None,
    drop_unroutable: bool = False,
) -> Scenario:
    """Build (or load from cache) the Scenario of a network for an env seed.

    Agents whose OD pair has no route stop the build with a NetworkError naming them (URB stops on
    them too, see docs/networks.md); `drop_unroutable` leaves them out instead and records their
    ids in `Scenario.dropped_unroutable`.
    """
    params = route_params or RouteParams()
    files = find_network(network, networks_dir)
    cache_file = _cache_file(files, params, env_seed, drop_unroutable)
    scn = _cached(cache_file, files) if use_cache else None
    if scn is None and use_cache:
        # Where no agent is unroutable, both drop choices build the same scenario: either entry serves.
        other = _cached(_cache_file(files, params, env_seed, not drop_unroutable), files)
        scn = other if other is not None and other.dropped_unroutable.size == 0 else None
    if scn is None:
        scn = build_scenario(files, params, env_seed, workers=workers, drop_unroutable=drop_unroutable)
        if use_cache:
            _save(scn, cache_file)
    if scn.dropped_unroutable.size:
        log.warning("%s: left out %d agent(s) whose OD pair has no route (--drop-unroutable): ids %s",
                    files.name, scn.dropped_unroutable.size, " ".join(map(str, scn.dropped_unroutable)))
    return scn


def _cache_file(files: NetworkFiles, params: RouteParams, env_seed: int, drop_unroutable: bool) -> Path:
    key = _cache_key(files, params, env_seed, drop_unroutable)
    return cache_dir() / "scenarios" / f"{files.name}-{key}.npz"


def _cached(cache_file: Path, files: NetworkFiles) -> Scenario | None:
    """The cached Scenario, or None when absent or unreadable (a damaged entry is rebuilt, never trusted)."""
    if not cache_file.is_file():
        return None
    try:
        # The key hashes the files' contents, so an identical copy elsewhere shares the entry;
        # SUMO must still read the copy that was asked for, not the one that built the entry.
        return replace(_load(cache_file), net_file=str(files.net))
    except Exception as exc:
        log.warning("scenario cache %s is unreadable (%s): rebuilding it", cache_file, exc)
        return None


def build_scenario(
    files: NetworkFiles, params: RouteParams, env_seed: int, workers: int | None = None,
    drop_unroutable: bool = False,
) -> Scenario:
    """Read the network, check every OD pair on the route graph (seconds), then sample routes."""
    t0 = time.perf_counter()
    net = read_net(files.net)
    graph = build_route_graph(net, passenger_only=params.passenger_only)
    demand, dropped = _routable_demand(files, params, read_demand(files, net), graph, drop_unroutable)
    pairs = _od_pairs(demand)
    od_edges = [(demand.origins[o], demand.destinations[d]) for o, d in pairs]
    if workers is None:
        workers = min(os.cpu_count() or 1, 4)
    (results,) = generate_routes(graph, od_edges, params, env_seed, workers=workers)
    failed = [(i, r) for i, r in enumerate(results) if isinstance(r, str)]  # sampling found none
    _refuse_unroutable(files, params, demand, pairs, failed)
    routes, route_len, valid = _route_arrays([r for r in results if isinstance(r, ODRoutes)], net.index(),
                                             params.number_of_paths)
    n_short = int((~valid).any(axis=1).sum())
    if n_short:
        log.warning(
            "%s: %d OD pair(s) have fewer than %d distinct routes; the last distinct route is "
            "repeated and masked (route_valid=False).", files.name, n_short, params.number_of_paths,
        )
    log.info("built scenario %s in %.1f s", files.name, time.perf_counter() - t0)
    return _assemble(files, params, env_seed, net, demand, pairs, (routes, route_len, valid), dropped)


def _od_pairs(demand: Demand) -> list[tuple[int, int]]:
    """The distinct (origin, destination) index pairs of the demand, sorted (URB's routes.csv order)."""
    return sorted({(int(o), int(d)) for o, d in zip(demand.origin, demand.destination, strict=True)})


def _routable_demand(files: NetworkFiles, params: RouteParams, demand: Demand, graph: nx.DiGraph,
                     drop: bool) -> tuple[Demand, np.ndarray]:
    """(the demand, ids [D] of agents left out): agents whose OD pair has no path in the route
    graph are refused, or with `drop` left out. Found by reachability alone, before sampling."""
    pairs = _od_pairs(demand)
    bad = unroutable(graph, [(demand.origins[o], demand.destinations[d]) for o, d in pairs])
    if not bad:
        return demand, np.zeros(0, dtype=np.int64)
    if not drop:
        _refuse_unroutable(files, params, demand, pairs, list(bad.items()))
    bad_pairs = {pairs[i] for i in bad}
    out = np.array([(int(o), int(d)) in bad_pairs
                    for o, d in zip(demand.origin, demand.destination, strict=True)])  # [N]
    if out.all():
        raise NetworkError(files.agents, f"no agent has a route in {files.net.name}; --drop-unroutable "
                           "would leave none.", "check that the od file belongs to this network.")
    return demand.subset(~out), np.sort(demand.agent_id[out]).astype(np.int64)


def _route_arrays(ok: list[ODRoutes], index: dict[str, int], k: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(routes [O, K, L] edge indices -1 padded, route_len [O, K], valid [O, K])."""
    max_len = max(len(route) for r in ok for route in r.routes)
    routes = np.full((len(ok), k, max_len), -1, dtype=np.int32)
    route_len = np.zeros((len(ok), k), dtype=np.int32)
    valid = np.zeros((len(ok), k), dtype=bool)
    for o, r in enumerate(ok):
        valid[o, : r.n_distinct] = True
        for j, route in enumerate(r.routes):
            routes[o, j, : len(route)] = [index[e] for e in route]
            route_len[o, j] = len(route)
    return routes, route_len, valid


def _assemble(files: NetworkFiles, params: RouteParams, env_seed: int, net: NetData, demand: Demand,
              pairs: list[tuple[int, int]], route_arrays: tuple[np.ndarray, np.ndarray, np.ndarray],
              dropped: np.ndarray) -> Scenario:
    """The Scenario from its parts; agents sorted by departure (stable)."""
    routes, route_len, valid = route_arrays
    fft, fft_full = free_flow_times(routes, net.length, net.speed, route_len)
    od_lookup = {p: i for i, p in enumerate(pairs)}
    agent_od_rows = np.array(
        [od_lookup[(int(o), int(d))] for o, d in zip(demand.origin, demand.destination, strict=True)],
        dtype=np.int32,
    )
    order = np.argsort(demand.start_time, kind="stable")
    return Scenario(
        name=files.name,
        net_file=str(files.net),
        env_seed=env_seed,
        route_params=params,
        edge_ids=net.edge_ids,
        edge_length=net.length,
        edge_speed=net.speed,
        edge_lanes=net.lanes,
        edge_priority=net.priority,
        edge_type=net.road_type,
        edge_capacity=net.capacity,
        od_origin=np.array([p[0] for p in pairs], dtype=np.int32),
        od_destination=np.array([p[1] for p in pairs], dtype=np.int32),
        od_origin_edge=tuple(demand.origins[o] for o, _ in pairs),
        od_destination_edge=tuple(demand.destinations[d] for _, d in pairs),
        od_routes=routes,
        od_route_len=route_len,
        od_route_valid=valid,
        od_fft=fft,
        od_fft_full=fft_full,
        od_route_length=np.append(net.length, 0.0)[routes].sum(axis=-1),
        agent_id=demand.agent_id[order],
        agent_od=agent_od_rows[order],
        agent_origin=demand.origin[order].astype(np.int32),
        agent_destination=demand.destination[order].astype(np.int32),
        agent_depart=demand.start_time[order],
        agent_kind=tuple(demand.kind[i] for i in order),
        dropped_unroutable=dropped,
    )


def _refuse_unroutable(files: NetworkFiles, params: RouteParams, demand: Demand, pairs: list[tuple[int, int]],
                       failures: list[tuple[int, str]]) -> None:
    """A NetworkError naming every agent whose OD pair has no route (the first 10 pairs in full)."""
    if not failures:
        return
    lines, agents = [], []
    for n, (i, msg) in enumerate(failures):
        o, d = pairs[i]
        rows = np.flatnonzero((demand.origin == o) & (demand.destination == d))
        ids = [int(demand.agent_id[r]) for r in rows]
        agents += ids
        if n < 10:
            lines.append(f"origin {o} -> destination {d} (agents {', '.join(map(str, ids[:5]))}"
                         + (", ..." if len(ids) > 5 else "") + f"): {msg}")
    raise NetworkError(
        files.agents,
        f"{len(failures)} OD pair(s) have no route in {files.net.name}"
        + (" for passenger cars" if params.passenger_only else "") + f", {len(agents)} agent(s):\n  "
        + "\n  ".join(lines) + f"\n  all agent ids: {' '.join(map(str, sorted(agents)))}\n",
        "fix the origin/destination indices of these agents, remove them from agents.csv, or pass "
        "--drop-unroutable to leave them out (recorded in exp_config.json; URB itself stops on them).",
    )


def check_routes_exist(scn: Scenario) -> None:
    """Raise RouteError if any agent's OD lacks a route (defensive; build guarantees it)."""
    if (scn.od_route_len[scn.agent_od] == 0).any():
        raise RouteError("an agent has an empty route")
