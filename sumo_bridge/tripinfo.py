"""SUMO files we read or write: tripinfo parsing and the per-scenario route file."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.atomic import write_text

# A <tripinfo> element and, with SUMO's emission device, the <emissions .../> child that follows it
# (without the device the element closes itself and the next one starts: the group stays empty).
_TRIP = re.compile(r"<tripinfo\s([^>]*)>(?:\s*<emissions\s([^>]*)/>)?")
_ATTR = re.compile(r'([A-Za-z0-9_]+)="([^"]*)"')
TRIP_FIELDS = ("depart", "departDelay", "arrival", "duration", "routeLength", "timeLoss")
EMISSION_FIELDS = ("CO2_abs", "fuel_abs")  # mg each (SUMO's units: fuel in mg unless volumetric)


def parse_tripinfo(path: str | os.PathLike) -> dict[str, dict[str, object]]:
    """{vehicle id: {field: float, 'vaporized': str}} for every <tripinfo> element; with the emission
    device also 'CO2_abs' and 'fuel_abs' (mg, the totals up to arrival or removal)."""
    text = Path(path).read_text()
    out: dict[str, dict[str, object]] = {}
    for m in _TRIP.finditer(text):
        attrs = dict(_ATTR.findall(m.group(1)))
        rec: dict[str, object] = {k: float(attrs[k]) for k in TRIP_FIELDS}
        rec["vaporized"] = attrs.get("vaporized", "")
        if m.group(2) is not None:
            emitted = dict(_ATTR.findall(m.group(2)))
            rec.update({k: float(emitted[k]) for k in EMISSION_FIELDS})
        out[attrs["id"]] = rec
    return out


def route_id(od: int, k: int) -> str:
    return f"{int(od)}_{int(k)}"


def write_routes_file(path: str | os.PathLike, scenario: Scenario) -> None:
    """vTypes Human/AV (SUMO defaults, as URB) and one route per (od, k), id '{od}_{k}'."""
    lines = ["<routes>", '    <vType id="Human"/>', '    <vType id="AV"/>']
    for od in range(scenario.n_od):
        for k in range(scenario.k):
            edges = " ".join(scenario.route_edge_ids(od, k))
            lines.append(f'    <route id="{route_id(od, k)}" edges="{edges}"/>')
    lines.append("</routes>\n")
    write_text(path, "\n".join(lines))


def insertion_order(depart: np.ndarray, is_cav: np.ndarray) -> np.ndarray:
    """RouteRL's order: by departure second, humans before CAVs, then Scenario order."""
    return np.lexsort((np.arange(depart.shape[0]), is_cav.astype(np.int8), depart))
