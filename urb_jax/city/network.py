"""URB network folders: find them on the search path, read and validate their files.

A network is a folder `<name>/` holding `<name>.net.xml`, `agents.csv` and `od_<name>.txt`
(URB's format; see docs/networks.md). Every check names the file, the row and the field.
"""

from __future__ import annotations

import ast
import io
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from urb_jax.city.netxml import NetData, read_net
from urb_jax.core.errors import NetworkError
from urb_jax.core.paths import NETWORKS_ENV, networks_search_path

DAY_LIMIT_S = 6 * 3600  # a simulated day ends here (SumoConfig.max_sim_time_s): departures must come before
AGENT_COLUMNS = ("id", "origin", "destination", "start_time", "kind")
AGENT_KINDS = ("Human", "AV")
MAX_INT = 2**31  # ids, indices and start times (seconds) are stored as int32


@dataclass(frozen=True)
class NetworkFiles:
    name: str
    folder: Path
    net: Path
    agents: Path
    od: Path


@dataclass(frozen=True)
class Demand:
    """Validated demand, in agents.csv row order."""

    agent_id: np.ndarray  # int64
    origin: np.ndarray  # index into origins
    destination: np.ndarray  # index into destinations
    start_time: np.ndarray  # int64 seconds
    kind: tuple[str, ...]
    origins: tuple[str, ...]  # edge ids
    destinations: tuple[str, ...]

    def subset(self, keep: np.ndarray) -> Demand:
        """The rows where `keep` [N] is True, in file order (the od lists stay whole, so indices
        still point into them)."""
        rows = np.flatnonzero(keep)
        return replace(self, agent_id=self.agent_id[rows], origin=self.origin[rows],
                       destination=self.destination[rows], start_time=self.start_time[rows],
                       kind=tuple(self.kind[r] for r in rows))


def network_files(folder: Path) -> NetworkFiles:
    name = folder.name
    return NetworkFiles(
        name=name,
        folder=folder,
        net=folder / f"{name}.net.xml",
        agents=folder / "agents.csv",
        od=folder / f"od_{name}.txt",
    )


def _is_network_folder(folder: Path) -> bool:
    return folder.is_dir() and (folder / f"{folder.name}.net.xml").is_file()


def find_network(name: str, networks_dir: str | os.PathLike | None = None) -> NetworkFiles:
    """Resolve a network by name (or by a folder path) on the search path."""
    as_path = Path(name).expanduser()
    if as_path.is_dir():
        return _checked(network_files(as_path.resolve()))
    searched = networks_search_path(networks_dir)
    for root in searched:
        if _is_network_folder(root / name):
            return _checked(network_files(root / name))
    available = sorted({p.name for root in searched if root.is_dir() for p in root.iterdir()
                        if _is_network_folder(p)})
    raise NetworkError(
        name,
        f"no network folder '{name}' (with {name}.net.xml) in "
        + ", ".join(str(r) for r in searched) + ".",
        f"pass --networks-dir DIR or set ${NETWORKS_ENV}; available: {', '.join(available)}.",
    )


def _checked(files: NetworkFiles) -> NetworkFiles:
    for path, what in ((files.net, "SUMO network"), (files.agents, "demand"), (files.od, "OD list")):
        if not path.is_file():
            raise NetworkError(
                path, f"missing {what} file.",
                f"network '{files.name}' needs {files.net.name}, agents.csv and {files.od.name}.",
            )
    return files


def available_networks(networks_dir: str | os.PathLike | None = None) -> list[NetworkFiles]:
    """Every network on the search path; an earlier directory shadows a later one."""
    found: dict[str, NetworkFiles] = {}
    for root in networks_search_path(networks_dir):
        if not root.is_dir():
            continue
        for folder in sorted(root.iterdir()):
            if _is_network_folder(folder) and folder.name not in found:
                found[folder.name] = network_files(folder)
    return list(found.values())


def read_od(path: Path) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The od file is a Python literal dict (URB writes single quotes), not JSON."""
    text = _utf8_text(path, "write {'origins': [...], 'destinations': [...]}")
    try:
        data = ast.literal_eval(text)
    except (ValueError, SyntaxError) as exc:
        raise NetworkError(path, f"is not a Python literal dict ({exc}).",
                           "write {'origins': [...], 'destinations': [...]}.") from exc
    if not isinstance(data, dict):
        raise NetworkError(path, "must hold a dict.", "write {'origins': [...], 'destinations': [...]}.")
    out = []
    for key in ("origins", "destinations"):
        if key not in data:
            raise NetworkError(path, f"field '{key}' is missing.", f"add a '{key}' list of edge ids.")
        values = data[key]
        if not isinstance(values, list | tuple) or not all(isinstance(v, str) for v in values):
            raise NetworkError(path, f"field '{key}' must be a list of edge id strings.")
        out.append(tuple(values))
    return out[0], out[1]


def _utf8_text(path: Path, what: str) -> str:
    """The file's text, or an error that names the first byte that is not UTF-8."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise NetworkError(path, f"is not UTF-8 text (byte 0x{data[exc.start]:02x} on line {line}).",
                           f"save it as UTF-8; {what}.") from None


def read_agents(path: Path) -> pd.DataFrame:
    text = _utf8_text(path, f"agents.csv has the columns {', '.join(AGENT_COLUMNS)}")
    try:
        df = pd.read_csv(io.StringIO(text), dtype=str, keep_default_na=False)
    except Exception as exc:  # pandas raises many types for malformed CSV
        raise NetworkError(path, f"cannot be read as CSV ({exc}).") from exc
    if df.empty:
        raise NetworkError(path, "holds no agents (a header and no rows).",
                           "add one row per agent: " + ",".join(AGENT_COLUMNS) + ".")
    df.columns = [c.strip() for c in df.columns]
    missing = [c for c in AGENT_COLUMNS if c not in df.columns]
    if missing:
        raise NetworkError(path, f"missing column(s) {', '.join(missing)}.",
                           f"agents.csv needs the columns {', '.join(AGENT_COLUMNS)} (any order).")
    return df


def _int_column(df: pd.DataFrame, col: str, path: Path) -> np.ndarray:
    values = np.empty(len(df), dtype=np.int64)
    for row, raw in enumerate(df[col].tolist()):
        text = str(raw).strip()
        try:
            values[row] = int(text)
            if abs(values[row]) >= MAX_INT:
                raise ValueError
        except (ValueError, OverflowError):
            try:
                as_float = float(text)
            except ValueError:
                as_float = float("nan")
            if as_float.is_integer() and abs(as_float) < MAX_INT:
                values[row] = int(as_float)
            else:
                raise NetworkError(
                    path, f"line {row + 2}, field '{col}': '{raw}' is not an integer below {MAX_INT}.",
                    f"'{col}' must be a whole number" + (" of seconds." if col == "start_time" else "."),
                ) from None
    return values


def read_demand(files: NetworkFiles, net: NetData | None = None) -> Demand:
    """Read and validate agents.csv against the od file (and the net, when given)."""
    origins, destinations = read_od(files.od)
    df = read_agents(files.agents)
    ids = _int_column(df, "id", files.agents)
    origin = _int_column(df, "origin", files.agents)
    dest = _int_column(df, "destination", files.agents)
    start = _int_column(df, "start_time", files.agents)
    kinds = tuple(str(k).strip() for k in df["kind"].tolist())
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        dup = int(uniq[counts > 1][0])
        rows = [int(r) + 2 for r in np.flatnonzero(ids == dup)]
        raise NetworkError(files.agents, f"field 'id': duplicate id {dup} on lines {rows}.",
                           "give every agent a unique id.")
    for name, values, table in (("origin", origin, origins), ("destination", dest, destinations)):
        bad = np.flatnonzero((values < 0) | (values >= len(table)))
        if bad.size:
            r = int(bad[0])
            raise NetworkError(
                files.agents,
                f"line {r + 2}, field '{name}': index {int(values[r])} is out of range "
                f"(the '{name}s' list of {files.od.name} has {len(table)} entries).",
                f"use an index in 0..{len(table) - 1}.",
            )
    bad = np.flatnonzero(start < 0)
    if bad.size:
        r = int(bad[0])
        raise NetworkError(files.agents, f"line {r + 2}, field 'start_time': negative time {start[r]}.")
    late = np.flatnonzero(start >= DAY_LIMIT_S)
    if late.size:
        r = int(late[0])
        raise NetworkError(
            files.agents, f"line {r + 2}, field 'start_time': {start[r]} s is past the end of a simulated "
            f"day ({DAY_LIMIT_S} s; {late.size} agent(s), ids {ids[late[:10]].tolist()}"
            f"{' ...' if late.size > 10 else ''}).", f"give every agent a start_time below {DAY_LIMIT_S}.")
    for row, kind in enumerate(kinds):
        if kind not in AGENT_KINDS:
            raise NetworkError(files.agents, f"line {row + 2}, field 'kind': '{kind}' is unknown.",
                               f"use one of {', '.join(AGENT_KINDS)}.")
    if net is not None:
        known = set(net.edge_ids)
        for key, table in (("origins", origins), ("destinations", destinations)):
            for pos, edge in enumerate(table):
                if edge not in known:
                    raise NetworkError(
                        files.od, f"field '{key}'[{pos}]: edge id '{edge}' is not in {files.net.name}.",
                        "regenerate the od file for this network or fix the edge id.",
                    )
    return Demand(ids, origin, dest, start, kinds, origins, destinations)


@dataclass(frozen=True)
class NetworkInfo:
    name: str
    agents: int
    od_pairs: int
    edges: int
    folder: Path


def describe(files: NetworkFiles) -> NetworkInfo:
    net = read_net(files.net)
    demand = read_demand(files, net)
    pairs = {(int(o), int(d)) for o, d in zip(demand.origin, demand.destination, strict=True)}
    return NetworkInfo(files.name, len(demand.agent_id), len(pairs), len(net.edge_ids), files.folder)
