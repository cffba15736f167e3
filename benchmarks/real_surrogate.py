"""The calibrated surrogate as the benchmarks' travel-time model (what the hybrid trainer uses).

`surrogate_travel_fn(scn)` fits `surrogate.fit_params` on `n_days` varied SUMO days
(`surrogate.data.make_choices`: free-flow, random, equilibrium-like and mixed days, the kinds
`urb-jax validate-surrogate` calibrates on), run through sumo_bridge and cached on disk by
`surrogate.sumo_days`, so a second call costs only the fit. Not a product module.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp

from urb_jax.city.scenario import Scenario
from urb_jax.surrogate import SumoSample, build_static, fit_params, init_params, predict
from urb_jax.surrogate.calibrate import FitConfig
from urb_jax.surrogate.data import make_choices
from urb_jax.surrogate.sumo_days import sumo_days


def surrogate_travel_fn(scn: Scenario, n_days: int = 40, choice_seed: int = 1, sumo_seed: int = 42,
                        steps: int = 1000, verbose: bool = True):
    """travel_time_fn(choices[N]) -> minutes [N] of the surrogate calibrated on n_days SUMO days."""
    t0 = time.perf_counter()
    static = build_static(scn)
    p0 = init_params(static)
    choices, _ = make_choices(scn, static, p0, n_days, seed=choice_seed)
    days = sumo_days(scn, choices, sumo_seed, workers=2)
    t1 = time.perf_counter()
    params = fit_params(p0, static, SumoSample.from_days(choices, days), FitConfig(steps=steps))
    params = jax.tree_util.tree_map(jnp.asarray, jax.block_until_ready(params))
    if verbose:
        print(f"surrogate: {n_days} SUMO days ({t1 - t0:.0f} s, cached after the first run), "
              f"fit {time.perf_counter() - t1:.0f} s", flush=True)

    def travel_times(choices: jnp.ndarray) -> jnp.ndarray:
        return predict(params, static, choices)

    return travel_times
