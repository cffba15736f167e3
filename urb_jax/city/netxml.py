"""Read the parts of a SUMO net.xml that routing, the surrogate and SUMO runs share."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from urb_jax.core.errors import NetworkError

# Capacity per lane (veh/h) by speed limit (m/s): the speed-based branch of SUMO marouter's
# table (ROMAAssignments::getCapacity, PTV-Validate / VISUM-Cologne). marouter selects a branch by
# -priority; OSM imports carry positive priorities and fall through to its 800 veh/h default for
# every road, so we use the speed-based branch for all edges.
_CAPACITY_BREAKS = np.array([5.0, 7.0, 9.0, 11.0, 13.0, 16.0, 18.0, 22.0, 26.0])
_CAPACITY_PER_LANE = np.array(
    [200.0, 412.5, 600.0, 800.0, 1125.0, 1583.0, 1100.0, 1200.0, 1300.0, 1400.0]
)


def capacity_per_lane(speed: np.ndarray) -> np.ndarray:
    """marouter's per-lane capacity (veh/h) for the given speed limits (m/s)."""
    idx = np.searchsorted(_CAPACITY_BREAKS, np.asarray(speed, dtype=float), side="left")
    return _CAPACITY_PER_LANE[idx]


def _passenger_allowed(lane: ET.Element) -> bool:
    allow = lane.get("allow")
    if allow is not None:
        classes = allow.split()
        return "passenger" in classes or "all" in classes
    disallow = lane.get("disallow")
    if disallow is not None:
        classes = disallow.split()
        return "passenger" not in classes and "all" not in classes
    return True


@dataclass(frozen=True)
class NetData:
    """Normal (non-internal) edges and edge-to-edge connections of a SUMO network."""

    path: Path
    edge_ids: tuple[str, ...]
    from_node: tuple[str, ...]
    to_node: tuple[str, ...]
    length: np.ndarray  # m, first lane (as JanuX reads it)
    speed: np.ndarray  # m/s, first lane
    lanes: np.ndarray  # lane count
    priority: np.ndarray
    road_type: tuple[str, ...]
    passenger: np.ndarray  # bool: some lane admits passenger cars
    connections: tuple[tuple[str, str], ...]  # unique (from edge, to edge), any lanes
    passenger_connections: frozenset[tuple[str, str]]  # lane pair admits passenger cars

    @property
    def capacity(self) -> np.ndarray:
        """Estimated capacity per edge, veh/h."""
        return self.lanes * capacity_per_lane(self.speed)

    def index(self) -> dict[str, int]:
        return {e: i for i, e in enumerate(self.edge_ids)}


def read_net(path: str | Path) -> NetData:
    """Parse a net.xml; raises NetworkError naming the file when it is not a SUMO network."""
    path = Path(path)
    if not path.is_file():
        raise NetworkError(path, "network file not found.", "check the networks path and name.")
    edge_ids: list[str] = []
    from_node: list[str] = []
    to_node: list[str] = []
    length: list[float] = []
    speed: list[float] = []
    lanes: list[int] = []
    priority: list[int] = []
    road_type: list[str] = []
    passenger: list[bool] = []
    lane_passenger: dict[str, bool] = {}
    connections: dict[tuple[str, str], None] = {}
    pconn: set[tuple[str, str]] = set()
    raw_conns: list[tuple[str, str, str, str]] = []
    saw_net = False
    try:
        for _, elem in ET.iterparse(path, events=("end",)):
            tag = elem.tag
            if tag == "edge":
                eid = elem.get("id", "")
                if elem.get("function") in (None, "normal") and not eid.startswith(":"):
                    lane_elems = elem.findall("lane")
                    if not lane_elems:
                        raise NetworkError(path, f"edge '{eid}' has no <lane>.")
                    first = lane_elems[0]
                    edge_ids.append(eid)
                    from_node.append(elem.get("from", ""))
                    to_node.append(elem.get("to", ""))
                    length.append(float(first.get("length")))
                    speed.append(float(first.get("speed")))
                    lanes.append(len(lane_elems))
                    priority.append(int(elem.get("priority", "-1")))
                    road_type.append(elem.get("type", ""))
                    flags = [_passenger_allowed(lane) for lane in lane_elems]
                    for li, ok in enumerate(flags):
                        lane_passenger[f"{eid}_{li}"] = ok
                    passenger.append(any(flags))
                elem.clear()
            elif tag == "connection":
                f, t = elem.get("from", ""), elem.get("to", "")
                if not f.startswith(":") and not t.startswith(":"):
                    connections[(f, t)] = None
                    raw_conns.append((f, t, elem.get("fromLane", "0"), elem.get("toLane", "0")))
                elem.clear()
            elif tag == "net":
                saw_net = True
    except ET.ParseError as exc:
        raise NetworkError(path, f"not valid XML ({exc}).", "re-export it with netconvert.") from exc
    if not saw_net or not edge_ids:
        raise NetworkError(path, "no SUMO <net> with edges found.", "pass a SUMO .net.xml file.")
    for f, t, fl, tl in raw_conns:
        if lane_passenger.get(f"{f}_{fl}", False) and lane_passenger.get(f"{t}_{tl}", False):
            pconn.add((f, t))
    return NetData(
        path=path,
        edge_ids=tuple(edge_ids),
        from_node=tuple(from_node),
        to_node=tuple(to_node),
        length=np.asarray(length, dtype=np.float64),
        speed=np.asarray(speed, dtype=np.float64),
        lanes=np.asarray(lanes, dtype=np.int32),
        priority=np.asarray(priority, dtype=np.int32),
        road_type=tuple(road_type),
        passenger=np.asarray(passenger, dtype=bool),
        connections=tuple(connections),
        passenger_connections=frozenset(pconn),
    )
