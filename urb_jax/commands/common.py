"""Flags shared by several subcommands, so they read the same everywhere.

Every command module imports only this, argparse and urb_jax.core.choices at its top: building the
parser (`urb-jax --help`, `urb-jax CMD --help`) imports no JAX, flax, pandas or SUMO; a command's
handler imports what it runs (tests/test_cli_help.py).
"""

from __future__ import annotations

import argparse

from urb_jax.core.choices import DEFAULT_NETWORK
from urb_jax.core.paths import CACHE_ENV, DAY_STORE_ENV, NETWORKS_ENV


def add_network_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--net", default=DEFAULT_NETWORK,
                        help=f"network name or folder (default: the embedded '{DEFAULT_NETWORK}')")
    add_networks_dir(parser)
    parser.add_argument("--env-seed", type=int, default=42,
                        help="seeds routes, humans, mutation and SUMO (default 42)")
    parser.add_argument("--drop-unroutable", action="store_true",
                        help="leave out agents whose OD pair has no passenger-car route (default: stop "
                             "and name them, as URB stops on them); recorded in exp_config.json")


def add_set_flag(parser: argparse.ArgumentParser, sections: tuple[str, ...]) -> None:
    """--set SECTION.KEY=VALUE, repeatable: one config key without a new JSON file."""
    parser.add_argument("--set", action="append", dest="overrides", default=None,
                        metavar="SECTION.KEY=VALUE",
                        help=f"override one key of the {'/'.join(sections)} config (repeatable), typed and "
                             "checked like the file's keys, URB's key names included; VALUE is JSON "
                             "(1e-3, 8, true, [64,64], \"text\"), a bare word is text; recorded in "
                             "exp_config.json, e.g. --set alg.lr=1e-3 --set hybrid.num_envs=8")


def add_networks_dir(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--networks-dir", default=None,
                        help=f"folder of URB networks (searched before ${NETWORKS_ENV} "
                             "and the embedded networks)")


def add_day_store_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--no-day-store", action="store_true",
                        help=f"run every SUMO day in SUMO: neither read nor write the SUMO day store shared "
                             f"by every run (${CACHE_ENV}/sumo_days; {DAY_STORE_ENV}=0 turns it off for "
                             "every command; docs/sumo_bridge.md)")
