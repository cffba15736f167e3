"""Reuse a train run's human phase (`urb-jax train --human-phase-from EXP_ID`).

The human phase (H SUMO days, the learned human state and the calibration days) depends only on
the network, routes, env seed, human model, demand and calibration settings, not on the
algorithm, so a sweep of algorithms can pay for it once. Every train run saves
`human_phase.npz` (learned human state + calibration days); a reuse replays the recorded human
days through `train_humans` (each day's human choices must equal the recorded ones, as in
`urb-jax baseline --human-phase-from`), checks the replayed human state against the saved one,
and takes the calibration days from the file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.errors import UrbJaxError
from urb_jax.experiment.hybrid import HumanPhase, HybridConfig
from urb_jax.experiment.protocol import train_humans
from urb_jax.experiment.replay import MUST_MATCH, ReplayHumanPhase
from urb_jax.game.config import TaskConfig
from urb_jax.game.humans import HumanState
from urb_jax.results.records import read_records

HUMAN_FILE = "human_phase.npz"
# Beyond the baseline replay's keys: the phase's length and the calibration days it recorded.
TRAIN_MUST_MATCH = (*MUST_MATCH, "human_learning_episodes", "hybrid_calib_human_days",
                    "hybrid_calib_varied_days")


def save_human_phase(folder: Path, human: HumanPhase) -> None:
    """human_phase.npz: the learned human state and the calibration days (atomic)."""
    from urb_jax.experiment.hybrid import _atomic_npz

    _atomic_npz(folder / HUMAN_FILE, calib_choices=human.calib_choices, calib_times=human.calib_times,
                calib_arrived=human.calib_arrived,
                **{f"humans_{k}": np.asarray(v) for k, v in human.humans._asdict().items()})


def reuse_human_phase(source: Path, config: dict[str, Any], scn: Scenario, task: TaskConfig,
                      cfg: HybridConfig, env_seed: int, calibrate: bool = True) -> HumanPhase:
    """The HumanPhase of the earlier train run in `source`, after checking that its inputs match
    `config` (this run's exp_config keys); raises UrbJaxError naming the mismatch otherwise."""
    cfg_path = source / "exp_config.json"
    if not cfg_path.is_file():
        raise UrbJaxError(f"{cfg_path}: not found. Fix: --human-phase-from takes the experiment id of an "
                          "earlier `urb-jax train` run in --results-dir.")
    src = json.loads(cfg_path.read_text())
    diff = [f"{k} (source {src.get(k)!r}, this run {config.get(k)!r})" for k in TRAIN_MUST_MATCH
            if src.get(k) != config.get(k)]
    if diff:
        raise UrbJaxError(f"{cfg_path}: its human phase differs from this run's: {'; '.join(diff)}. "
                          "Fix: reuse a run with the same network, configs and env seed, or drop "
                          "--human-phase-from.")
    path = source / HUMAN_FILE
    if not path.is_file():
        raise UrbJaxError(f"{path}: not found (only `urb-jax train` runs save their human phase). "
                          "Fix: pick a train run, or drop --human-phase-from.")
    z = np.load(path)
    calib = (z["calib_choices"], z["calib_times"], z["calib_arrived"])
    want = (cfg.calib_human_days + cfg.calib_varied_days) if calibrate else 0
    if len(calib[0]) < want:
        raise UrbJaxError(f"{path}: mode (the source recorded {len(calib[0])} calibration days, this run "
                          f"needs {want}; a --mode sumo run records none). Fix: reuse a hybrid or "
                          "surrogate run.")
    if not calibrate:
        calib = tuple(x[:0] for x in calib)

    H = task.human_learning_episodes
    replay = ReplayHumanPhase(read_records(source, columns=["day", "agent", *_FIELDS_NEEDED]),
                              scn.agent_id, H, _no_more_days)
    records: list[Any] = []

    def simulate(day: int, phase: str, choices: np.ndarray, is_cav: np.ndarray) -> Any:
        return replay(scn, choices, seed=env_seed, is_cav=None)

    humans = train_humans(scn, task.human_params(), H, env_seed=env_seed, simulate=simulate,
                          sink=records.append)
    saved = HumanState(**{k: jnp.asarray(z[f"humans_{k}"]) for k in HumanState._fields})
    same = jax.tree_util.tree_map(lambda a, b: bool(np.array_equal(np.asarray(a), np.asarray(b),
                                                                   equal_nan=True)), humans, saved)
    if not all(jax.tree_util.tree_leaves(same)):
        raise UrbJaxError(f"{path}: replaying the recorded human days does not give the saved human "
                          "state (different code or human model?). Fix: drop --human-phase-from.")
    return HumanPhase(humans, records, *calib)


_FIELDS_NEEDED = ("action", "travel_time", "route_length", "speed", "duration", "time_loss",
                  "depart_delay", "status")


def _no_more_days(*_: Any, **__: Any) -> Any:
    raise UrbJaxError("human phase replay: asked for more days than the source's human phase.")
