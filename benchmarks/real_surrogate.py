"""The calibrated surrogate as the benchmarks' travel-time model (what the hybrid trainer uses).

`surrogate_travel_fn(scn)` fits `surrogate.fit_params` on `n_days` varied SUMO days
(`surrogate.data.make_choices`: free-flow, random, equilibrium-like and mixed days, the kinds
`urb-jax validate-surrogate` calibrates on), run through sumo_bridge and cached on disk by
`surrogate.sumo_days`, so a second call costs only the fit. Not a product module.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.surrogate import SumoSample, build_static, fit_params, init_params, predict
from urb_jax.surrogate.calibrate import FitConfig
from urb_jax.surrogate.data import make_choices
from urb_jax.surrogate.sumo_days import sumo_days


def surrogate_travel_fn(scn: Scenario, n_days: int = 40, choice_seed: int = 1, sumo_seed: int = 42,
                        steps: int = 1000, verbose: bool = True, params_file: Path | None = None):
    """travel_time_fn(choices[N]) -> minutes [N] of the surrogate calibrated on n_days SUMO days.

    `params_file`: the fitted parameters are read from it when it exists, else written to it, so a
    machine without SUMO (a GPU box) times the very surrogate fitted here."""
    static = build_static(scn)
    if params_file is not None and params_file.is_file():
        with np.load(params_file) as z:
            params = {k: jnp.asarray(z[k]) for k in z.files}
        if verbose:
            print(f"surrogate: fitted parameters read from {params_file}", flush=True)
    else:
        params = _fit(scn, static, n_days, choice_seed, sumo_seed, steps, verbose)
        if params_file is not None:
            params_file.parent.mkdir(parents=True, exist_ok=True)
            np.savez(params_file, **{k: np.asarray(v) for k, v in params.items()})

    def travel_times(choices: jnp.ndarray) -> jnp.ndarray:
        return predict(params, static, choices)

    return travel_times


def _fit(scn: Scenario, static, n_days: int, choice_seed: int, sumo_seed: int, steps: int, verbose: bool):
    t0 = time.perf_counter()
    p0 = init_params(static)
    if n_days == 0:  # uncalibrated: the same computation (for timing), parameters at their start values
        return p0
    choices, _ = make_choices(scn, static, p0, n_days, seed=choice_seed)
    days = sumo_days(scn, choices, sumo_seed, workers=2)
    t1 = time.perf_counter()
    params = fit_params(p0, static, SumoSample.from_days(choices, days), FitConfig(steps=steps))
    params = jax.tree_util.tree_map(jnp.asarray, jax.block_until_ready(params))
    if verbose:
        print(f"surrogate: {n_days} SUMO days ({t1 - t0:.0f} s, cached after the first run), "
              f"fit {time.perf_counter() - t1:.0f} s", flush=True)
    return params
