"""Policies trained outside urb-jax: the surrogate env they train on, and their SUMO test days.

A finished `urb-jax train` run holds everything such a policy needs and nothing it should pay for
again: the network, configs and env seed (`exp_config.json`), the human phase's SUMO days and
learned humans, and the calibration days (`human_phase.npz`). `surrogate_env_from_run` rebuilds the
run's surrogate env at round 0 (the human phase replayed from the records, the surrogate
calibrated as the trainer calibrates it) without a SUMO day; `evaluate_on_sumo` plays the frozen
policy on URB's test days in SUMO after the same human phase (replayed, not re-simulated) and
writes the usual results folder and metric files (t_CAV, t_pre, ...).

The JaxMARL interface over the env lives in `urb_jax.interop.jaxmarl` (optional extra).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from urb_jax.algorithms.baselines import FixedPolicy
from urb_jax.core.errors import UrbJaxError
from urb_jax.game.env import RoutingEnv
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.rollout import Policy
from urb_jax.runs.baseline import run_policy
from urb_jax.runs.folder import read_train_config
from urb_jax.runs.request import BaselineRequest
from urb_jax.runs.setup import RunResult, TrainSetup, recorded_setup
from urb_jax.surrogate import build_static
from urb_jax.surrogate.calibrate import uncalibrated
from urb_jax.training.human_phase import HumanPhase, calibrate, reuse_human_phase
from urb_jax.training.hybrid.trainer import routing_env_kwargs, surrogate_env


class RunEnv(NamedTuple):
    """A finished run's surrogate env (its calibrated surrogate as `env.default_params`)."""

    env: RoutingEnv
    setup: TrainSetup
    human: HumanPhase
    source: Path


def surrogate_env_from_run(run: str | Path) -> RunEnv:
    """The surrogate env of `run` at round 0: its scenario, CAVs, trained humans and the surrogate
    calibrated on its human phase's calibration days (no SUMO day is run)."""
    folder = Path(run).expanduser().resolve()
    config = read_train_config(folder)
    _, setup = recorded_setup([config])
    env_seed = int(config["env_seed"])
    human = reuse_human_phase(folder, config, setup.scn, setup.task, setup.hyb, env_seed, calibrate=True)
    if not len(human.calib_choices):
        raise UrbJaxError(f"{folder}: the run recorded no calibration days (--mode sumo). Fix: use a hybrid "
                          "or surrogate run.")
    if setup.task.fleets:
        raise UrbJaxError(f"{folder}: the run's task has fleets (key 'fleets'), each with its own learner; "
                          "an outside policy stands for one fleet of every CAV. Fix: use a run without "
                          "fleets.")
    static = build_static(setup.scn, setup.hyb.surrogate_config)
    params = calibrate(uncalibrated(static), static, human, setup.hyb)
    is_cav = draw_cavs(env_seed, setup.scn.n_agents, setup.task.ratio_machines, agent_id=setup.scn.agent_id)
    kwargs = routing_env_kwargs(setup.task, setup.env, env_seed)
    env = surrogate_env(setup.scn, is_cav, static, human.humans, params, kwargs)
    return RunEnv(env, setup, human, folder)


def evaluate_on_sumo(policy: Policy, run: str | Path, *, name: str = "outside", exp_id: str | None = None,
                     results_dir: str = "results", overwrite: bool = False, progress: bool = True
                     ) -> RunResult:
    """URB's test days in SUMO for a frozen `policy(key, obs [n, D], idx [n] | None) -> routes [n]`
    (raw observations of the env, CAVs acting in departure order) after `run`'s human phase,
    replayed from its records; no training day. Returns the run with its metrics (t_CAV, t_pre, ...)
    in results_dir/exp_id/ (default id: name_<network>_<task>_s<env seed>)."""
    folder = Path(run).expanduser().resolve()
    args = read_train_config(folder)["train_args"]
    req = BaselineRequest(net=args["net"], task_conf=args["task_conf"], env_conf=args["env_conf"],
                          env_seed=int(args["env_seed"]), exp_id=exp_id, networks_dir=args["networks_dir"],
                          human_phase_from=str(folder),
                          drop_unroutable=bool(args.get("drop_unroutable", False)),
                          results_dir=results_dir, overwrite=overwrite, progress=progress)
    return run_policy(FixedPolicy(policy, name), req, task_overrides={"training_eps": 0})
