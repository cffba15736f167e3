"""One module per `urb-jax` subcommand; each exposes `register(subparsers)`.

To add a command, write a module here with `register` and list it in `COMMANDS`.
"""

COMMANDS = [
    "urb_jax.commands.networks",
    "urb_jax.commands.scenario",
    "urb_jax.commands.sumo_day",
    "urb_jax.commands.validate_surrogate",
    "urb_jax.commands.baseline",
    "urb_jax.commands.leaderboard",
    "urb_jax.commands.export_day",
    "urb_jax.commands.export_urb",
    "urb_jax.commands.headroom",
    "urb_jax.commands.metrics",
    "urb_jax.commands.train",
    "urb_jax.commands.optimum",
    "urb_jax.commands.snapshots",
    "urb_jax.commands.suite",
]
