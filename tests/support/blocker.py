"""A vehicle that blocks an edge of a SUMO day (the stuck-vehicle tests of the bridge and the pool)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path


def make_blocker(scn, choices, tmp_path, duration: int = 1500) -> tuple[Path, str]:
    """An extra vehicle stopping `duration` s on the busiest inner edge: its followers stand still.

    (With a permanent blocker the queue behind it drains one vehicle per 600 s under either
    rule, since every removal lets the followers move up and restarts their clocks.)"""
    busy = Counter(e for i in range(scn.n_agents)
                   for e in scn.route_edge_ids(int(scn.agent_od[i]), int(choices[i]))[1:-1])
    edge = busy.most_common(1)[0][0]
    path = tmp_path / "blocker.add.xml"
    path.write_text(
        f'<additional><route id="blocker_route" edges="{edge}"/>'
        f'<vehicle id="blocker" route="blocker_route" depart="0" departPos="stop">'
        f'<stop lane="{edge}_0" endPos="150" duration="{duration}" parking="false"/></vehicle></additional>'
    )
    return path, edge
