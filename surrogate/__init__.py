"""The differentiable link-performance model of a URB day and its calibration against SUMO.

    static = build_static(scenario)            # numpy index arrays, once per scenario
    params = calibrate(scenario, sample)       # sample: SumoSample.from_days(choices, sumo_days)
    times = predict(params, static, choices)   # [B, N] ints or [B, N, K] probabilities -> minutes
    params = refit(params, scenario, new_sample)
"""

from urb_jax.surrogate.calibrate import FitConfig, SumoSample, calibrate, fit_params, refit
from urb_jax.surrogate.model import (
    Static,
    SurrogateConfig,
    build_static,
    init_params,
    predict,
    predict_jit,
    route_times_seconds,
)

__all__ = [
    "FitConfig", "Static", "SumoSample", "SurrogateConfig", "build_static", "calibrate",
    "fit_params", "init_params", "predict", "predict_jit", "refit", "route_times_seconds",
]
