"""`urb-jax` entry point: subcommands live in urb_jax/commands/.

Building the parser imports argparse-level modules only (each command's handler imports what it
runs), so `urb-jax --help`, `urb-jax CMD --help` and a bad argument answer without loading JAX
(tests/test_cli_help.py).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from urb_jax.commands import COMMANDS
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.version import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="urb-jax",
        description="JAX surrogate-plus-SUMO trainer for the Urban Routing Benchmark.",
    )
    parser.add_argument("--version", action="version", version=f"urb-jax {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    from urb_jax.core.compile_cache import enable_compile_cache  # imports JAX: after parsing
    from urb_jax.core.interrupt import InterruptedRunError, handle_interrupts, leave_interrupted, stop_cause

    with handle_interrupts():
        try:
            enable_compile_cache()  # every command compiles once per machine, not once per process
            return int(args.func(args) or 0)
        except InterruptedRunError as exc:
            leave_interrupted(str(exc))  # no interpreter teardown around an XLA call in flight
        except KeyboardInterrupt:
            leave_interrupted(f"stopped by {stop_cause()}.")
        except UrbJaxError as exc:
            print(f"urb-jax: error: {exc}", file=sys.stderr)
            return 2


if __name__ == "__main__":
    sys.exit(main())
