"""The differentiable link-performance model of a URB day and its calibration against SUMO.

    static = build_static(scenario)            # numpy index arrays, once per scenario
    params = calibrate(scenario, sample)       # sample: SumoSample.from_days(choices, sumo_days)
    times = predict(params, static, choices)   # [B, N] ints or [B, N, K] probabilities -> minutes
    params = refit(params, scenario, new_sample, all_days=sample + new_sample)

`calibrate` and `refit` are the training runs' own recipes: a gradient fit of the smooth model, then
each (agent, route)'s mean residual over the SUMO days that drove it (`route_bias`); `uncalibrated`
is the start before any SUMO day.
"""

from urb_jax.surrogate.calibrate import FitConfig, SumoSample, calibrate, fit_params, refit, uncalibrated
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
    "fit_params", "init_params", "predict", "predict_jit", "refit", "route_times_seconds", "uncalibrated",
]
