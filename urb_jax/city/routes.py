"""K candidate routes per OD pair, generated with JanuX exactly as URB does (URB_REFERENCE §3).

The route graph has one node per normal SUMO edge and an arc u->v for every connection, with
JanuX's `travel_time` attribute (length/speed/60 of u's first lane). Each OD pair gets its own
`ExtendedPathGenerator` seeded with the env seed, as RouteRL's per-OD worker does, so the route
sets (and their order = action index) match URB's for the same seed.

Deviation, behind `passenger_only` (default True): arcs whose lanes admit no passenger car are
dropped, because SUMO cannot drive such routes. On the URB networks we checked (saint_arnoult,
provins, ingolstadt_custom) every connection admits passenger cars, so the graphs are identical.
"""

from __future__ import annotations

import bisect
import os
import pickle
import signal
import subprocess
import sys
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import networkx as nx
import numpy as np

from urb_jax.city.netxml import NetData
from urb_jax.core.errors import RouteError


@dataclass(frozen=True)
class RouteParams:
    """URB env-config route parameters (env config1 values by default)."""

    number_of_paths: int = 4
    beta: float = -5.0
    num_samples: int = 10
    max_path_length: int = 200
    passenger_only: bool = True
    tolerate_num_iterations: int = 200
    shift_by: float = 5.0
    # Safety net JanuX lacks: an OD with fewer distinct routes than K would loop forever.
    # JanuX's adaptive schedule reaches beta = -0.01 after ~24k attempts; we allow 4x that.
    max_attempts: int = 100_000


def build_route_graph(net: NetData, passenger_only: bool = True) -> nx.DiGraph:
    """JanuX's graph: nodes are edge ids, arcs are connections, weight travel_time (min)."""
    index = net.index()
    graph = nx.DiGraph()
    arcs = net.passenger_connections if passenger_only else frozenset(net.connections)
    for u, v in net.connections:  # keep file order for reproducibility
        if (u, v) not in arcs or u not in index or v not in index:
            continue
        i = index[u]
        graph.add_edge(u, v, travel_time=net.length[i] / net.speed[i] / 60.0)
    return graph


@dataclass(frozen=True)
class ODRoutes:
    routes: tuple[tuple[str, ...], ...]  # exactly K, padded by repeating the last distinct one
    n_distinct: int


class _Sampler:
    """JanuX 1.1.0 ExtendedPathGenerator for one OD, re-implemented for speed.

    Same graph walk, same adaptive schedule, same RNG draws (numpy `Generator.choice` with `p`
    is `cdf = cumsum(p); cdf /= cdf[-1]; bisect_right(cdf, rng.random())`), so the output is
    identical to JanuX's (tests/test_routes.py checks this against JanuX itself). JanuX spends
    most of its time in `rng.choice` per step and an O(n^2) `set()` per sample. Weights are kept
    per node until beta shifts, and a step with one option only makes its draw (its cdf is [1.0]):
    ~20% faster than computing both per step, byte-identical routes on all of mantes_la_jolie.
    """

    def __init__(self, succ: dict[str, list[str]], potentials: dict[str, int], beta: float,
                 max_path_length: float, rng: np.random.Generator) -> None:
        self.succ = succ
        self.pot = potentials
        self.max_path_length = max_path_length
        self.rng = rng
        self.beta = beta

    @property
    def beta(self) -> float:
        return self._beta

    @beta.setter
    def beta(self, value: float) -> None:
        """A new beta (JanuX's adaptive shift) starts new weight tables."""
        self._beta = value
        self._by_pot: dict[int, float] = {}
        self._by_node: dict[str, float] = {}

    def _weight(self, node: str) -> float:
        """exp(beta * potential), computed as JanuX does (numpy on one float), once per node."""
        pot = self.pot.get(node)
        value: float | None
        if pot is None:
            value = 0.0  # np.exp(beta * inf) == 0: a dead end
        else:
            value = self._by_pot.get(pot)
            if value is None:
                value = self._by_pot[pot] = float(np.exp(self._beta * pot))
        self._by_node[node] = value
        return value

    def sample(self, origin: str, destination: str) -> tuple[str, ...] | None:
        succ, by_node, rand = self.succ, self._by_node, self.rng.random
        path: list[str] = []
        on_path: set[str] = set()
        current = origin
        while True:
            path.append(current)
            on_path.add(current)
            options = [n for n in succ.get(current, ()) if n not in on_path]
            if destination in options:
                return (*path, destination)
            if not options or len(path) > self.max_path_length:
                return None
            numerators = [by_node[n] if n in by_node else self._weight(n) for n in options]
            total = 0.0
            for x in numerators:
                total += x
            if not total > 0.0 or total == float("inf"):
                return None  # numpy raises on NaN probabilities; JanuX returns None
            if len(options) == 1:  # cdf == [x / x] == [1.0] > any draw in [0, 1): the draw is still made
                rand()
                current = options[0]
                continue
            cdf: list[float] = []
            acc = 0.0
            for x in numerators:
                acc += x / total
                cdf.append(acc)
            last = cdf[-1]
            cdf = [c / last for c in cdf]
            current = options[bisect.bisect_right(cdf, rand())]


def _hop_potentials(pred: dict[str, list[str]], target: str) -> dict[str, int]:
    """Hop distance to `target` (what JanuX gets: arcs carry no 'time' attribute, so weight 1)."""
    dist = {target: 0}
    queue = deque([target])
    while queue:
        node = queue.popleft()
        for p in pred.get(node, ()):
            if p not in dist:
                dist[p] = dist[node] + 1
                queue.append(p)
    return dist


def generate_od_routes(
    graph: nx.DiGraph, origin: str, destination: str, params: RouteParams, seed: int,
    adjacency: tuple[dict[str, list[str]], dict[str, list[str]]] | None = None,
) -> ODRoutes:
    """K routes for one OD pair, seeded per OD like RouteRL's workers."""
    if origin not in graph or destination not in graph:
        missing = origin if origin not in graph else destination
        raise RouteError(f"edge '{missing}' has no connection in the route graph")
    succ, pred = adjacency if adjacency is not None else graph_adjacency(graph)
    potentials = _hop_potentials(pred, destination)
    if origin not in potentials:
        raise RouteError(f"no path from edge '{origin}' to edge '{destination}'")
    rng = np.random.default_rng(seed)
    max_len = float("inf") if params.max_path_length is None else params.max_path_length
    sampler = _Sampler(succ, potentials, params.beta, max_len, rng)
    k = params.number_of_paths
    samples: list[tuple[str, ...]] = []
    distinct: set[tuple[str, ...]] = set()
    iteration = attempts = 0
    while len(samples) < params.num_samples or len(distinct) < k:
        if iteration > params.tolerate_num_iterations:  # JanuX's adaptive shift
            sampler.beta = min(sampler.beta * (100 - params.shift_by) / 100, -0.01)
            if sampler.max_path_length != float("inf"):
                sampler.max_path_length = int(sampler.max_path_length * (100 + params.shift_by) / 100)
            iteration = 0
        if attempts >= params.max_attempts:
            break
        path = sampler.sample(origin, destination)
        attempts += 1
        if path is not None:
            samples.append(path)
            distinct.add(path)
        iteration += 1
    if not samples:
        raise RouteError(f"no route sampled from '{origin}' to '{destination}'")
    as_str = np.array([",".join(r) for r in samples])
    unique, counts = np.unique(as_str, return_counts=True)
    n_pick = min(k, len(unique))
    picked = rng.choice(unique, size=n_pick, p=counts / counts.sum(), replace=False)
    routes = [tuple(str(r).split(",")) for r in picked]
    routes += [routes[-1]] * (k - n_pick)
    return ODRoutes(tuple(routes), n_pick)


def unroutable(graph: nx.DiGraph, od_edges: Sequence[tuple[str, str]]) -> dict[int, str]:
    """{index: reason} of the OD pairs with no path in the route graph, found before any sampling.

    Reachability on the condensation (one node per strongly connected component): a pair inside
    one component is routable without a search, and the few others search a graph of components.
    One reverse search per destination on the full graph took 15 s on mantes_la_jolie (4,143
    pairs); this takes well under a second.
    """
    dag = nx.condensation(graph)
    comp: dict[str, int] = dag.graph["mapping"]
    reach: dict[int, set[int]] = {}
    bad: dict[int, str] = {}
    for i, (origin, destination) in enumerate(od_edges):
        if origin not in graph or destination not in graph:
            missing = origin if origin not in graph else destination
            bad[i] = f"edge '{missing}' has no connection in the route graph"
            continue
        if origin == destination:  # JanuX's walk never revisits its start: it would loop forever
            bad[i] = f"origin and destination are the same edge '{origin}'"
            continue
        o, d = comp[origin], comp[destination]
        if o == d:
            continue
        if d not in reach:
            reach[d] = nx.ancestors(dag, d)
        if o not in reach[d]:
            bad[i] = f"no path from edge '{origin}' to edge '{destination}'"
    return bad


def graph_adjacency(graph: nx.DiGraph) -> tuple[dict[str, list[str]], dict[str, list[str]]]:
    """Sorted successor lists (JanuX sorts neighbours) and predecessor lists."""
    succ = {n: sorted(graph.successors(n)) for n in graph.nodes}
    pred = {n: list(graph.predecessors(n)) for n in graph.nodes}
    return succ, pred


_WORKER_GRAPH: nx.DiGraph | None = None
_WORKER_ADJ: tuple[dict[str, list[str]], dict[str, list[str]]] | None = None
MIN_PARALLEL = 32  # fewer OD pairs are sampled in this process: a worker's start costs more
Task = tuple[str, str, RouteParams, int]


def _init_worker(graph: nx.DiGraph) -> None:
    global _WORKER_GRAPH, _WORKER_ADJ
    _WORKER_GRAPH = graph
    _WORKER_ADJ = graph_adjacency(graph)


def _worker(task: Task) -> ODRoutes | str:
    origin, destination, params, seed = task
    assert _WORKER_GRAPH is not None
    try:
        return generate_od_routes(_WORKER_GRAPH, origin, destination, params, seed, _WORKER_ADJ)
    except RouteError as exc:
        return str(exc)


def generate_routes(
    graph: nx.DiGraph,
    od_edges: Sequence[tuple[str, str]],
    params: RouteParams,
    seed: int,
    workers: int = 1,
) -> tuple[list[ODRoutes | str], ...]:
    """Routes for every OD; failures come back as messages so the caller can name the agents.

    Each OD's draws come from its own `default_rng(seed)`, so any split over workers gives the
    same routes as one process."""
    tasks = [(o, d, params, seed) for o, d in od_edges]
    if workers <= 1 or len(tasks) < MIN_PARALLEL:
        _init_worker(graph)
        return (list(map(_worker, tasks)),)
    return (_in_worker_interpreters(graph, tasks, workers),)


def _in_worker_interpreters(graph: nx.DiGraph, tasks: list[Task], workers: int) -> list[ODRoutes | str]:
    """`tasks` split over `workers` fresh Python interpreters (`_serve`), fed and answered by pipe.

    Not a multiprocessing pool: its spawn/forkserver children re-run the caller's script, so a
    script without an `if __name__ == "__main__"` guard would crash; and fork could
    deadlock on threads JAX may already run. A fresh interpreter imports only this module."""
    shares = [tasks[i::workers] for i in range(workers)]  # interleaved: slow ODs spread out
    root = str(Path(__file__).resolve().parents[2])  # the folder holding the urb_jax package
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}
    cmd = [sys.executable, "-P", "-c", "from urb_jax.city.routes import _serve; _serve()"]
    procs = [subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env) for _ in shares]
    try:
        for proc, share in zip(procs, shares, strict=True):
            assert proc.stdin is not None
            pickle.dump((graph, share), proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            proc.stdin.close()
        answers = [_answer(proc) for proc in procs]
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
    out: list[ODRoutes | str] = [""] * len(tasks)
    for i, answer in enumerate(answers):
        out[i::workers] = answer
    return out


def _answer(proc: subprocess.Popen) -> list[ODRoutes | str]:
    assert proc.stdout is not None
    try:
        return pickle.load(proc.stdout)
    except EOFError:
        raise RuntimeError(f"a route-sampling worker stopped (exit code {proc.wait()}); its error is "
                           "printed above") from None


def _serve() -> None:
    """A worker interpreter: (graph, tasks) from stdin, their routes to stdout (one pickle each).
    Ctrl-C, SIGTERM and SIGHUP are the parent's to handle: it stops the workers; a parent gone
    (a closed pipe) ends the worker quietly."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # core.interrupt.STOP_SIGNALS
        signal.signal(sig, signal.SIG_IGN)
    try:
        graph, tasks = pickle.load(sys.stdin.buffer)
        _init_worker(graph)
        pickle.dump(list(map(_worker, tasks)), sys.stdout.buffer, protocol=pickle.HIGHEST_PROTOCOL)
        sys.stdout.buffer.flush()
    except (EOFError, BrokenPipeError, ConnectionResetError):
        os._exit(1)  # no traceback, and no flush of the closed stdout at exit


def free_flow_times(
    routes: np.ndarray, length: np.ndarray, speed: np.ndarray, route_len: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(URB free-flow time without the destination edge, full free-flow time), minutes.

    `routes` holds edge indices padded with -1; `route_len` the number of edges per route.
    """
    edge_time = np.append(length / speed / 60.0, 0.0)  # index -1 -> 0
    per_edge = edge_time[routes]
    full = per_edge.sum(axis=-1)
    last = np.take_along_axis(routes, np.maximum(route_len - 1, 0)[..., None], axis=-1)[..., 0]
    return full - edge_time[last], full
