"""What a run's exp_config.json tells URB's own tools: its names and its phases.

URB's leaderboard generator (leaderboard/generate_leaderboard.py) averages runs as reruns when
(exp_type, env_config, task_config, network, algorithm, script, alg_config) agree, and links
config/algo_config/<algorithm>/<alg_config>.json (a baseline: `baseline_model`, no `algorithm`,
config/algo_config/baseline/). URB's analysis/metrics.py slices days by human_learning_episodes,
experience_collecting_episodes and training_eps. So a urb-jax run says:

* `algorithm`: URB's name of what ran (its config/algo_config folder: `iql_torchrl` for `--alg
  iql`, `iql` for `--alg iql_star`), `null` for a baseline (as URB's baselines.py, whose runs
  carry `baseline_model`); `alg`: urb-jax's id (`--alg`, or `baseline_<model>`);
* `script`: how urb-jax ran it (`urb-jax train --mode M --hybrid-conf H --train-days D`,
  `urb-jax baseline`), never a URB script, so a urb-jax row never merges with a URB row and
  runs of other trainers or budgets never merge with each other;
* `script` ends with the run's `--set` overrides (`... --set hybrid.sumo_days_per_round=16`), so
  runs that differ in them are never averaged as reruns; `torch_seed`: the run's seed (URB's seed
  column; a baseline has none);
* `alg_config`: URB's config name where the file is URB's (so the link is that file);
* `training_eps`, `test_eps`, `phase_days`: what the records hold (a train run's SUMO training
  days, not the task config's 200).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from urb_jax.algorithms.registry import ALGORITHMS, urb_algorithm
from urb_jax.core.errors import UrbJaxError

# URB's leaderboard generator: runs that agree on these are one row (reruns, averaged).
URB_COLLAPSE_FIELDS = ("exp_type", "env_config", "task_config", "network", "algorithm", "script",
                       "alg_config")
BASELINE_SCRIPT = "urb-jax baseline"
TRAIN_SCRIPT = "urb-jax train"
# URB's config/algo_config/baseline/*.json: each is one training_eps value.
URB_BASELINE_CONFIGS = {200: "config1", 10: "test"}


def train_script(mode: str, hybrid_config: str, train_days: int) -> str:
    """The `script` of a train run: the trainer and the settings that make it a different
    experiment from a URB script's or another budget's (no '/': URB keeps the last path part)."""
    return f"{TRAIN_SCRIPT} --mode {mode} --hybrid-conf {hybrid_config} --train-days {int(train_days)}"


def alg_config_name(given: str) -> str:
    """URB's name of an algorithm config: a file in URB's layout (config/algo_config/<alg>/X.json)
    is X; an id of urb-jax's configs/algo/<alg>/ stays the id; any other file, its path."""
    path = Path(given)
    if path.suffix == ".json" and path.parent.parent.name == "algo_config":
        return path.stem
    return given


def baseline_alg_config(training_eps: int) -> str:
    """URB's baseline config with this training_eps (config1: 200, test: 10), else a name that
    says it is none of URB's."""
    return URB_BASELINE_CONFIGS.get(int(training_eps), f"training_eps_{int(training_eps)}")


def train_names(alg: str, mode: str, hybrid_config: str, train_days: int, alg_conf: str) -> dict[str, Any]:
    return {"algorithm": urb_algorithm(alg), "alg": alg,
            "script": train_script(mode, hybrid_config, train_days), "alg_config": alg_config_name(alg_conf)}


def baseline_names(model: str, training_eps: int) -> dict[str, Any]:
    return {"algorithm": None, "alg": f"baseline_{model}", "baseline_model": model,
            "script": BASELINE_SCRIPT, "alg_config": baseline_alg_config(training_eps)}


def is_urb_jax(cfg: dict[str, Any]) -> bool:
    return str(cfg.get("script", "")).startswith("urb-jax")


def names_of(cfg: dict[str, Any]) -> dict[str, Any]:
    """The naming fields of a urb-jax run's exp_config.json, also for runs written before they
    existed (`algorithm` was our id, `script` just "urb-jax train" / "urb-jax baseline"): its
    `script` with its `--set` overrides (runs that differ in them are different experiments, never
    merged as reruns) and, for a seeded run, its seed as URB's `torch_seed` column."""
    names = _names_of(cfg)
    names["script"] = with_overrides(str(names.get("script") or ""), overrides_of(cfg))
    if cfg.get("seed") is not None:
        names["torch_seed"] = cfg["seed"]
    return names


def overrides_of(cfg: dict[str, Any]) -> list[str]:
    """A run's `--set` items as given (train_args, or exp_config.json's `overrides`)."""
    given = (cfg.get("train_args") or {}).get("overrides") or (cfg.get("overrides") or {}).get("given")
    return [str(x) for x in given or []]


def with_overrides(script: str, overrides: list[str]) -> str:
    """`script` + ' --set ITEM' per override, once (idempotent); a '/' in an item is written %2F, as
    URB's generator keeps only a script's last path part."""
    suffix = "".join(f" --set {o.replace('/', '%2F')}" for o in overrides)
    return script if not suffix or script.endswith(suffix) else script + suffix


def _names_of(cfg: dict[str, Any]) -> dict[str, Any]:
    if cfg.get("alg"):  # written with them
        keys = ("algorithm", "alg", "script", "alg_config", "baseline_model")
        return {k: cfg.get(k) for k in keys if k != "baseline_model" or cfg.get(k)}
    if cfg.get("baseline_model"):
        T = cfg.get("training_days", cfg.get("training_eps", 0))
        return baseline_names(cfg["baseline_model"], int(T))
    alg = cfg.get("alg") or cfg.get("algorithm")
    if alg not in ALGORITHMS:
        raise UrbJaxError(f"exp_config.json: algorithm {alg!r} is no urb-jax algorithm. Fix: pass a run "
                          "folder written by `urb-jax train` or `urb-jax baseline`.")
    days = cfg.get("hybrid_train_days") or cfg.get("train_args", {}).get("train_days") or 0
    return train_names(alg, cfg.get("mode", "hybrid"), str(cfg.get("hybrid_config", "default")), days,
                       str(cfg.get("alg_config", "config1")))


def leaderboard_fields(cfg: dict[str, Any]) -> dict[str, Any]:
    """A run's fields as URB's leaderboard generator derives them (its collapse key, plus `alg`,
    urb-jax's id, empty for a run URB made): urb-jax runs by their current names."""
    if is_urb_jax(cfg):
        cfg = {**cfg, **names_of(cfg)}
    return {
        "exp_type": cfg.get("exp_type", "normal"), "env_config": cfg.get("env_config"),
        "task_config": cfg.get("task_config"), "network": cfg.get("network"),
        "algorithm": cfg.get("algorithm") or cfg.get("baseline_model") or cfg.get("policy") or "",
        "script": script_name(str(cfg.get("script") or "")),
        "alg_config": (cfg.get("alg_config") or cfg.get("algorithm_config")
                       or cfg.get("algorithm_configuration") or ""),
        "alg": cfg.get("alg", "") if is_urb_jax(cfg) else "",
        "torch_seed": cfg.get("torch_seed"),  # URB's seed column (a urb-jax run's seed, `names_of`)
    }


def script_name(script: str) -> str:
    """The last part of a script path, as URB's generator shows `script` (scripts/iql.py -> iql.py)."""
    parts = [p for p in script.strip().replace("\\", "/").split("/") if p and p != "."]
    return parts[-1] if parts else ""


def phase_keys(records: pd.DataFrame, human_days: int) -> dict[str, Any]:
    """URB's phase keys for what `records` hold: human_learning_episodes H, training_eps T (the
    SUMO training days recorded), test_eps E, experience_collecting_episodes 0, and `phase_days`,
    each phase's first and last recorded day. Raises UrbJaxError where the recorded days do not
    follow URB's layout (train days H+1..H+T, test days H+T+1..H+T+E)."""
    by_phase = records.groupby("phase")["day"].unique()
    days = {p: sorted(int(d) for d in by_phase.get(p, [])) for p in ("human", "train", "test")}
    H = int(human_days)
    T, E = len(days["train"]), len(days["test"])
    if (days["human"] and days["human"][-1] != H) or days["train"] != list(range(H + 1, H + T + 1)) \
            or days["test"] != list(range(H + T + 1, H + T + E + 1)):
        raise UrbJaxError(f"the records' days do not follow URB's phases (human 1..{H}, then training, "
                          "then test days, one after another), so URB's phase keys cannot describe them.")
    return {"human_learning_episodes": H, "experience_collecting_episodes": 0, "training_eps": T,
            "test_eps": E, "phase_days": {p: [d[0], d[-1]] if d else None for p, d in days.items()}}
