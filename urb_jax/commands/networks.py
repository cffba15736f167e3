"""`urb-jax networks list`: what networks are available, and where they were found."""

from __future__ import annotations

import argparse

from urb_jax.commands.common import add_networks_dir


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("networks", help="list available networks")
    inner = parser.add_subparsers(dest="networks_command", required=True)
    lister = inner.add_parser("list", help="print each network with agents, OD pairs and edges")
    add_networks_dir(lister)
    lister.set_defaults(func=run_list)


def run_list(args: argparse.Namespace) -> int:
    from urb_jax.city.network import available_networks, describe
    from urb_jax.core.errors import UrbJaxError
    from urb_jax.core.paths import networks_search_path

    print("search path: " + " -> ".join(str(p) for p in networks_search_path(args.networks_dir)))
    rows = [("network", "agents", "OD pairs", "edges", "found in")]
    for files in available_networks(args.networks_dir):
        try:
            info = describe(files)
            rows.append((info.name, str(info.agents), str(info.od_pairs), str(info.edges),
                         str(info.folder.parent)))
        except UrbJaxError as exc:
            rows.append((files.name, "-", "-", "-", f"INVALID: {exc}"))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    for r in rows:
        cells = [r[0].ljust(widths[0])] + [c.rjust(w) for c, w in zip(r[1:4], widths[1:], strict=True)]
        print("  ".join(cells) + "  " + r[4])
    return 0
