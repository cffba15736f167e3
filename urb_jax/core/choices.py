"""The names the command line offers (argparse choices and defaults), in a module that imports nothing.

`urb-jax --help` and every `urb-jax CMD --help` build their parsers from these without importing
JAX, flax, pandas or SUMO (tests/test_cli_help.py); the modules that implement the names import
them from here, so each list has one definition.
"""

from __future__ import annotations

DEFAULT_NETWORK = "urb_grid"  # the embedded network a command uses without --net

# urb-jax algorithm id -> URB's algorithm (its config/algo_config folder) whose config files it reads;
# urb_jax.algorithms.registry.ALGORITHMS builds each one's learner, in this order.
ALGORITHM_URB_NAMES: dict[str, str] = {
    "iql": "iql_torchrl",
    "ippo": "ippo_torchrl",
    "mappo": "mappo_torchrl",
    "qmix": "qmix_torchrl",
    "vdn": "vdn_torchrl",
    "iql_star": "iql",
    "ippo_star": "ippo",
}
# URB's names accepted as --alg where they name one urb-jax algorithm. URB's bandit `iql` / `ippo`
# are not among them: `iql` / `ippo` have always been urb-jax's TorchRL-style IQL / IPPO (their URB
# names are iql_torchrl / ippo_torchrl); the bandit ones are `iql_star` / `ippo_star` (docs/algorithms.md).
URB_ALIASES: dict[str, str] = {urb: name for name, urb in ALGORITHM_URB_NAMES.items()
                               if urb not in ALGORITHM_URB_NAMES}

BASELINE_MODELS = ("aon", "random", "human")  # urb_jax.algorithms.baselines.BASELINES, in this order
MODES = ("hybrid", "sumo", "surrogate")  # how `urb-jax train` trains (urb_jax.training.hybrid.plan)
EXECUTORS = ("pool", "ray")  # where a train run's SUMO days run (urb_jax.runs.train.make_executor)
LOGGERS = ("tensorboard",)  # `urb-jax train --log` (urb_jax.runs.round_log)
TRAIN_SECTIONS = ("task", "env", "alg", "hybrid")  # --set SECTION.KEY=VALUE of `urb-jax train`
BASELINE_SECTIONS = ("task", "env", "alg")  # --set SECTION.KEY=VALUE of `urb-jax baseline`
STUCK_RULES = ("urb", "routerl", "sumo")  # urb_jax.sumo_bridge.config.SumoConfig.stuck_rule
STUCK_PENALTIES = ("elapsed", "urb")  # SumoConfig.stuck_penalty
