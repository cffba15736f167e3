"""URB's routes.csv, so route sets can be compared with a URB run line by line."""

from __future__ import annotations

import os

import pandas as pd

from urb_jax.city.scenario import Scenario
from urb_jax.core.atomic import write_text


def routes_table(scn: Scenario) -> pd.DataFrame:
    """One row per (OD, k) sorted by (origin, destination) then k, as URB writes it."""
    rows = []
    for od in range(scn.n_od):
        for k in range(scn.k):
            rows.append({
                "origins": int(scn.od_origin[od]),
                "destinations": int(scn.od_destination[od]),
                "path": " ".join(scn.route_edge_ids(od, k)),
                "free_flow_time": float(scn.od_fft[od, k]),
            })
    return pd.DataFrame(rows)


def write_routes_csv(scn: Scenario, path: str | os.PathLike) -> None:
    write_text(path, routes_table(scn).to_csv(index=False))
