"""Regenerate the embedded default network `urb_grid` (run: python -m urb_jax.networks.make_default).

A 6x4 grid (300 m blocks) with one fast arterial row, entries on the west and north fringes and
exits on the east and south fringes, and 400 seeded synthetic drivers departing over 20 minutes,
peaking at minute 10. Drivers from the west must trade the short-but-busy arterial against
parallel side streets, so route choice matters. The files are written in URB's format
(`urb_grid.net.xml`, `agents.csv`, `od_urb_grid.txt`) and built with SUMO's own netconvert
(eclipse-sumo wheel), so the output is deterministic for a SUMO version.
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np

NAME = "urb_grid"
COLS, ROWS, BLOCK = 6, 4, 300.0
ARTERIAL_ROW = 1
N_AGENTS = 400
SEED = 2025


def _netconvert() -> str:
    try:
        import sumo  # the eclipse-sumo wheel

        return str(Path(sumo.SUMO_HOME) / "bin" / "netconvert")
    except ImportError:
        return "netconvert"


def _plain_xml(tmp: Path) -> tuple[list[str], list[str]]:
    nodes = [f'  <node id="n{c}_{r}" x="{c * BLOCK}" y="{r * BLOCK}" type="priority"/>'
             for c in range(COLS) for r in range(ROWS)]
    edges: list[str] = []

    def edge(eid: str, a: str, b: str, speed: float, prio: int, lanes: int = 1) -> None:
        edges.append(f'  <edge id="{eid}" from="{a}" to="{b}" numLanes="{lanes}" '
                     f'speed="{speed}" priority="{prio}"/>')

    for r in range(ROWS):
        fast = r == ARTERIAL_ROW
        speed, prio = (19.44, 10) if fast else (11.11, 5)
        for c in range(COLS - 1):
            edge(f"h{c}_{r}", f"n{c}_{r}", f"n{c + 1}_{r}", speed, prio)
            edge(f"h{c + 1}_{r}r", f"n{c + 1}_{r}", f"n{c}_{r}", speed, prio)
    for c in range(COLS):
        for r in range(ROWS - 1):
            edge(f"v{c}_{r}", f"n{c}_{r}", f"n{c}_{r + 1}", 11.11, 4)
            edge(f"v{c}_{r + 1}d", f"n{c}_{r + 1}", f"n{c}_{r}", 11.11, 4)
    origins: list[str] = []
    destinations: list[str] = []
    for r in range(ROWS):  # west entries, east exits
        nodes.append(f'  <node id="w{r}" x="{-BLOCK}" y="{r * BLOCK}" type="priority"/>')
        nodes.append(f'  <node id="e{r}" x="{COLS * BLOCK}" y="{r * BLOCK}" type="priority"/>')
        edge(f"in_w{r}", f"w{r}", f"n0_{r}", 13.89, 6)
        edge(f"out_e{r}", f"n{COLS - 1}_{r}", f"e{r}", 13.89, 6)
        origins.append(f"in_w{r}")
        destinations.append(f"out_e{r}")
    for c in (1, 3, 5):  # north entries, south exits
        nodes.append(f'  <node id="N{c}" x="{c * BLOCK}" y="{ROWS * BLOCK}" type="priority"/>')
        nodes.append(f'  <node id="S{c}" x="{c * BLOCK}" y="{-BLOCK}" type="priority"/>')
        edge(f"in_n{c}", f"N{c}", f"n{c}_{ROWS - 1}", 13.89, 6)
        edge(f"out_s{c}", f"n{c}_0", f"S{c}", 13.89, 6)
        origins.append(f"in_n{c}")
        destinations.append(f"out_s{c}")
    (tmp / "g.nod.xml").write_text("<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n")
    (tmp / "g.edg.xml").write_text("<edges>\n" + "\n".join(edges) + "\n</edges>\n")
    return origins, destinations


def _demand(origins: list[str], destinations: list[str]) -> list[tuple[int, int, int, int]]:
    rng = np.random.default_rng(SEED)
    west = [i for i, o in enumerate(origins) if o.startswith("in_w")]
    north = [i for i, o in enumerate(origins) if o.startswith("in_n")]
    east = [i for i, d in enumerate(destinations) if d.startswith("out_e")]
    south = [i for i, d in enumerate(destinations) if d.startswith("out_s")]
    rows = []
    for agent in range(N_AGENTS):
        if rng.random() < 0.75:  # west -> east commuters, the arterial's customers
            o, d = int(rng.choice(west)), int(rng.choice(east))
        else:  # north -> south crossing traffic
            o, d = int(rng.choice(north)), int(rng.choice(south))
        depart = int(np.clip(rng.normal(600.0, 300.0), 0, 1200))
        rows.append((agent, o, d, depart))
    return rows


def generate(out_dir: Path) -> Path:
    folder = out_dir / NAME
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        origins, destinations = _plain_xml(tmp)
        subprocess.run(
            [_netconvert(), "-n", str(tmp / "g.nod.xml"), "-e", str(tmp / "g.edg.xml"),
             "--no-turnarounds", "true", "--no-internal-links", "false",
             "--output.street-names", "false", "--junctions.corner-detail", "5",
             "--offset.disable-normalization", "true",
             "--tls.guess", "false", "-o", str(folder / f"{NAME}.net.xml"), "--no-warnings"],
            check=True, capture_output=True, text=True,
        )
    od = {"origins": origins, "destinations": destinations}
    (folder / f"od_{NAME}.txt").write_text(repr(od) + "\n")
    lines = ["id,origin,destination,start_time,kind"]
    lines += [f"{a},{o},{d},{t},Human" for a, o, d, t in _demand(origins, destinations)]
    (folder / "agents.csv").write_text("\n".join(lines) + "\n")
    return folder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    print(generate(parser.parse_args().out))


if __name__ == "__main__":
    main()
