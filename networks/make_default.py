"""Regenerate the embedded default network `urb_grid` (run: python -m urb_jax.networks.make_default).

A 6x4 grid (300 m blocks) with one fast arterial row, entries on the west and north fringes and
exits on the east and south fringes, and 400 seeded synthetic drivers departing over 20 minutes,
peaking at minute 10. Drivers from the west must trade the short-but-busy arterial against
parallel side streets, so route choice matters. The files are written in URB's format
(`urb_grid.net.xml`, `agents.csv`, `od_urb_grid.txt`) and built with SUMO's own netconvert
(eclipse-sumo wheel), so the output is deterministic for a SUMO version. It is the smallest of
the synthetic cities (`networks/synthetic.py`, `URB_GRID`); files whose content is unchanged
(the net apart from netconvert's dated header) are left as they are.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from urb_jax.networks.synthetic import URB_GRID, generate

NAME = URB_GRID.name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    print(generate(URB_GRID, parser.parse_args().out))


if __name__ == "__main__":
    main()
