"""Synthetic grid cities in URB's format, from the 400-agent `urb_grid` up to tens of thousands of agents.

    python -m urb_jax.networks.synthetic --agents 10000 --name synth_10k --out DIR

A C x R grid of two-way streets (`block_m` blocks, 40 km/h, one lane) with faster arterials
(70 km/h, `arterial_lanes` lanes) every `row_arterial_every` rows and `col_arterial_every`
columns (starting at row/column 1). Fringe entries on the west and north, exits on the east and
south (every row; every odd column). Interior zones every `zone_every` blocks in both directions,
each an origin edge (the eastbound street leaving its node) and a destination edge (the westbound
street arriving at it). Demand, seeded: a share `interior_share` of drivers travel zone to zone
to a zone at most `trip_zones` zones away in each direction (so the number of OD pairs grows with
the zones, not with the agents squared); the rest cross the city from the fringe (75% west->east,
the arterial's customers, 25% north->south). Departures ~ N(window/2, window/4), clipped to the
window. Built with SUMO's netconvert (eclipse-sumo wheel), so the output is deterministic for a
SUMO version; `urb_grid` is `URB_GRID` (networks/make_default.py), byte for byte.

`city_for_agents(n)` sizes the grid so that the agents per lane-km stay those of `DENSITY`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import re
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SLOW = (11.11, 5)  # side street: m/s, netconvert priority (vertical side streets: priority 4)
FAST = (19.44, 10)  # arterial
FRINGE = (13.89, 6)  # entry and exit links
WEST_EAST_SHARE = 0.75  # of fringe trips; the rest north -> south
DENSITY = 12.0  # agents per lane-km of city_for_agents' grids (urb_grid: ~14.6 on one-lane streets)


@dataclass(frozen=True)
class CityConfig:
    """One synthetic city; every field changes the files, so it is all the generator needs."""

    name: str = "urb_grid"
    cols: int = 6
    rows: int = 4
    block_m: float = 300.0
    row_arterial_every: int = 4  # arterial rows 1, 1+every, ...; 0: none
    col_arterial_every: int = 0  # arterial columns likewise; 0: none
    arterial_lanes: int = 1
    zone_every: int = 0  # interior zones every this many blocks; 0: fringe trips only
    interior_share: float = 0.0  # share of drivers travelling zone to zone
    trip_zones: int = 1  # an interior trip ends at most this many zones away (each direction)
    fringe_reach: int = 0  # a fringe trip exits at most this many rows/columns off its entry; 0: any
    agents: int = 400
    window_s: int = 1200  # departures within [0, window_s]
    seed: int = 2025


URB_GRID = CityConfig()


def city_for_agents(agents: int, name: str, seed: int = 2025, density: float = DENSITY) -> CityConfig:
    """A 3:2 grid with about `density` agents per lane-km, arterials every 4 blocks, zones every 3."""
    base = dataclasses.replace(URB_GRID, name=name, agents=agents, seed=seed, row_arterial_every=4,
                               col_arterial_every=4, arterial_lanes=2, zone_every=3,
                               interior_share=0.8, fringe_reach=6, window_s=1800)
    rows = max(4, round(math.sqrt(agents / density / (1.5 * _lane_km_per_node(base)))))
    cols = max(6, round(1.5 * rows))
    return dataclasses.replace(base, cols=cols, rows=rows)


def _lane_km_per_node(cfg: CityConfig) -> float:
    """Lane-km per grid node of an unbounded grid (two directions per street, arterial lanes)."""
    share_h = 1 / cfg.row_arterial_every if cfg.row_arterial_every else 0.0
    share_v = 1 / cfg.col_arterial_every if cfg.col_arterial_every else 0.0
    lanes = (1 + share_h * (cfg.arterial_lanes - 1)) + (1 + share_v * (cfg.arterial_lanes - 1))
    return 2 * lanes * cfg.block_m / 1000


def _is_arterial(i: int, every: int) -> bool:
    return every > 0 and i % every == 1 % every


def lane_km(cfg: CityConfig) -> float:
    """Lane-km of the grid's streets (fringe links left out)."""
    km = cfg.block_m / 1000
    extra = cfg.arterial_lanes - 1
    lanes_h = cfg.rows + extra * sum(_is_arterial(r, cfg.row_arterial_every) for r in range(cfg.rows))
    lanes_v = cfg.cols + extra * sum(_is_arterial(c, cfg.col_arterial_every) for c in range(cfg.cols))
    return 2 * km * ((cfg.cols - 1) * lanes_h + (cfg.rows - 1) * lanes_v)


def zones(cfg: CityConfig) -> list[tuple[int, int]]:
    """Interior zone nodes (c, r): every `zone_every` blocks, centred, with an eastbound street."""
    if cfg.zone_every <= 0:
        return []
    off = cfg.zone_every // 2
    return [(c, r) for c in range(off, cfg.cols - 1, cfg.zone_every)
            for r in range(off, cfg.rows, cfg.zone_every)]


def _netconvert() -> str:
    try:
        import sumo  # the eclipse-sumo wheel

        return str(Path(sumo.SUMO_HOME) / "bin" / "netconvert")
    except ImportError:
        return "netconvert"


def _plain_xml(cfg: CityConfig, tmp: Path) -> tuple[list[str], list[str]]:
    """Write netconvert's node and edge files; return the origin and destination edge ids."""
    cols, rows, block = cfg.cols, cfg.rows, cfg.block_m
    nodes = [f'  <node id="n{c}_{r}" x="{c * block}" y="{r * block}" type="priority"/>'
             for c in range(cols) for r in range(rows)]
    edges: list[str] = []

    def edge(eid: str, a: str, b: str, speed: float, prio: int, lanes: int = 1) -> None:
        edges.append(f'  <edge id="{eid}" from="{a}" to="{b}" numLanes="{lanes}" '
                     f'speed="{speed}" priority="{prio}"/>')

    for r in range(rows):
        fast = _is_arterial(r, cfg.row_arterial_every)
        (speed, prio), lanes = (FAST, cfg.arterial_lanes) if fast else (SLOW, 1)
        for c in range(cols - 1):
            edge(f"h{c}_{r}", f"n{c}_{r}", f"n{c + 1}_{r}", speed, prio, lanes)
            edge(f"h{c + 1}_{r}r", f"n{c + 1}_{r}", f"n{c}_{r}", speed, prio, lanes)
    for c in range(cols):
        fast = _is_arterial(c, cfg.col_arterial_every)
        (speed, prio), lanes = (FAST, cfg.arterial_lanes) if fast else ((SLOW[0], 4), 1)
        for r in range(rows - 1):
            edge(f"v{c}_{r}", f"n{c}_{r}", f"n{c}_{r + 1}", speed, prio, lanes)
            edge(f"v{c}_{r + 1}d", f"n{c}_{r + 1}", f"n{c}_{r}", speed, prio, lanes)
    origins: list[str] = []
    destinations: list[str] = []
    for r in range(rows):  # west entries, east exits
        nodes.append(f'  <node id="w{r}" x="{-block}" y="{r * block}" type="priority"/>')
        nodes.append(f'  <node id="e{r}" x="{cols * block}" y="{r * block}" type="priority"/>')
        edge(f"in_w{r}", f"w{r}", f"n0_{r}", *FRINGE)
        edge(f"out_e{r}", f"n{cols - 1}_{r}", f"e{r}", *FRINGE)
        origins.append(f"in_w{r}")
        destinations.append(f"out_e{r}")
    for c in range(1, cols, 2):  # north entries, south exits
        nodes.append(f'  <node id="N{c}" x="{c * block}" y="{rows * block}" type="priority"/>')
        nodes.append(f'  <node id="S{c}" x="{c * block}" y="{-block}" type="priority"/>')
        edge(f"in_n{c}", f"N{c}", f"n{c}_{rows - 1}", *FRINGE)
        edge(f"out_s{c}", f"n{c}_0", f"S{c}", *FRINGE)
        origins.append(f"in_n{c}")
        destinations.append(f"out_s{c}")
    for c, r in zones(cfg):  # leave eastbound from the zone's node, arrive westbound at it
        origins.append(f"h{c}_{r}")
        destinations.append(f"h{c + 1}_{r}r")
    (tmp / "g.nod.xml").write_text("<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n")
    (tmp / "g.edg.xml").write_text("<edges>\n" + "\n".join(edges) + "\n</edges>\n")
    return origins, destinations


def _demand(cfg: CityConfig, origins: list[str], destinations: list[str]) -> list[tuple[int, int, int, int]]:
    """(agent, origin index, destination index, departure s) per driver, seeded by `cfg.seed`."""
    rng = np.random.default_rng(cfg.seed)
    west = [i for i, o in enumerate(origins) if o.startswith("in_w")]
    north = [i for i, o in enumerate(origins) if o.startswith("in_n")]
    east = [i for i, d in enumerate(destinations) if d.startswith("out_e")]
    south = [i for i, d in enumerate(destinations) if d.startswith("out_s")]
    zone_list = zones(cfg)
    first_zone = len(origins) - len(zone_list)  # zone z is origin/destination first_zone + z
    reach = _zone_neighbours(zone_list, cfg.zone_every * cfg.trip_zones)
    east_of = _near(origins, destinations, west, east, "in_w", "out_e", cfg.fringe_reach)
    south_of = _near(origins, destinations, north, south, "in_n", "out_s", cfg.fringe_reach)
    rows = []
    for agent in range(cfg.agents):
        if cfg.interior_share > 0 and rng.random() < cfg.interior_share:
            z = int(rng.integers(len(zone_list)))
            o, d = first_zone + z, first_zone + int(rng.choice(reach[z]))
        elif rng.random() < WEST_EAST_SHARE:  # west -> east commuters, the arterials' customers
            o = int(rng.choice(west))
            d = int(rng.choice(east_of[o]))
        else:  # north -> south crossing traffic
            o = int(rng.choice(north))
            d = int(rng.choice(south_of[o]))
        depart = int(np.clip(rng.normal(cfg.window_s / 2, cfg.window_s / 4), 0, cfg.window_s))
        rows.append((agent, o, d, depart))
    return rows


def _near(origins: list[str], destinations: list[str], entries: list[int], exits: list[int],
          entry_prefix: str, exit_prefix: str, reach: int) -> dict[int, list[int]]:
    """For each fringe entry, the exits at most `reach` rows (columns) away; every exit when 0."""
    pos = {i: int(origins[i].removeprefix(entry_prefix)) for i in entries}
    out = {}
    for i in entries:
        near = [j for j in exits if abs(int(destinations[j].removeprefix(exit_prefix)) - pos[i]) <= reach]
        out[i] = near if reach > 0 else exits
    return out


def _zone_neighbours(zone_list: list[tuple[int, int]], blocks: int) -> list[np.ndarray]:
    """For each zone, the other zones within `blocks` blocks in both directions."""
    xy = np.array(zone_list, dtype=np.int64).reshape(-1, 2)  # [Z, 2]
    out = []
    for z in range(len(zone_list)):
        near = np.abs(xy - xy[z]).max(axis=1) <= blocks
        near[z] = False
        out.append(np.flatnonzero(near))
    if any(n.size == 0 for n in out):
        raise ValueError("a zone has no other zone within trip_zones: use a larger grid or trip_zones")
    return out


def _same_net(a: Path, b: Path) -> bool:
    """Equal apart from netconvert's header comment (its date and the temporary input paths)."""
    def body(p: Path) -> str:
        return re.sub(r"<!--.*?-->", "", p.read_text(), count=1, flags=re.S)

    return b.is_file() and body(a) == body(b)


def _put(folder: Path, name: str, text: str) -> None:
    """Write `folder/name` unless it already holds `text` (a regenerated network keeps its files)."""
    path = folder / name
    if path.is_file() and path.read_text() == text:
        return
    tmp = folder / f".{name}.tmp"
    tmp.write_text(text)
    os.replace(tmp, path)


def generate(cfg: CityConfig, out_dir: Path) -> Path:
    """Write `out_dir/<name>/` ({name}.net.xml, od_{name}.txt, agents.csv); return the folder."""
    if cfg.interior_share > 0 and not zones(cfg):
        raise ValueError("interior_share > 0 needs zone_every > 0 and a grid large enough for a zone")
    folder = out_dir / cfg.name
    folder.mkdir(parents=True, exist_ok=True)
    net = folder / f"{cfg.name}.net.xml"
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        origins, destinations = _plain_xml(cfg, tmp)
        built = tmp / "out.net.xml"
        subprocess.run(
            [_netconvert(), "-n", str(tmp / "g.nod.xml"), "-e", str(tmp / "g.edg.xml"),
             "--no-turnarounds", "true", "--no-internal-links", "false",
             "--output.street-names", "false", "--junctions.corner-detail", "5",
             "--offset.disable-normalization", "true",
             "--tls.guess", "false", "-o", str(built), "--no-warnings"],
            check=True, capture_output=True, text=True,
        )
        if not _same_net(built, net):
            _put(folder, net.name, built.read_text())
    _put(folder, f"od_{cfg.name}.txt", repr({"origins": origins, "destinations": destinations}) + "\n")
    lines = ["id,origin,destination,start_time,kind"]
    lines += [f"{a},{o},{d},{t},Human" for a, o, d, t in _demand(cfg, origins, destinations)]
    _put(folder, "agents.csv", "\n".join(lines) + "\n")
    return folder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", type=int, required=True)
    parser.add_argument("--name", default=None, help="default: synth_<agents>")
    parser.add_argument("--out", type=Path, required=True, help="the network folder goes in OUT/<name>/")
    parser.add_argument("--seed", type=int, default=URB_GRID.seed)
    parser.add_argument("--density", type=float, default=DENSITY, help="agents per lane-km")
    for f in ("cols", "rows", "row_arterial_every", "col_arterial_every", "arterial_lanes", "zone_every",
              "trip_zones", "window_s"):
        parser.add_argument(f"--{f.replace('_', '-')}", type=int, default=None, help="override the sizing")
    parser.add_argument("--interior-share", type=float, default=None)
    args = parser.parse_args()
    cfg = city_for_agents(args.agents, args.name or f"synth_{args.agents}", args.seed, args.density)
    overrides = {f.name: getattr(args, f.name) for f in dataclasses.fields(CityConfig)
                 if getattr(args, f.name, None) is not None and f.name not in ("name", "agents", "seed")}
    cfg = dataclasses.replace(cfg, **overrides)
    folder = generate(cfg, args.out)
    print(f"{folder}: {cfg.cols}x{cfg.rows} grid, {lane_km(cfg):.0f} lane-km, {cfg.agents} agents "
          f"({cfg.agents / lane_km(cfg):.1f} per lane-km), {len(zones(cfg))} zones")


if __name__ == "__main__":
    main()
