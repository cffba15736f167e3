"""Fit the surrogate's parameters to SUMO days with optax.

Loss: squared relative error per arrived agent-day, plus the squared relative error of each day's
mean (what the mean-travel-time metric sees), plus a Gaussian prior pulling per-edge deviations
toward their class value (and, in `refit`, every parameter toward the previous fit).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import optax

from urb_jax.city.scenario import Scenario
from urb_jax.sumo_bridge.types import ARRIVED, DayResult
from urb_jax.surrogate.model import (
    JUNCTION_CLASSES,
    Static,
    SurrogateConfig,
    build_static,
    init_params,
    predict_bucketed,
    predict_days,
)
from urb_jax.surrogate.queue import init_queue_params

Params = dict[str, jax.Array]


def start_queue(static: Static) -> Params:
    """The queue model's own parameters at their start."""
    assert static.queue is not None
    return init_queue_params(static.queue, len(JUNCTION_CLASSES))


@dataclass(frozen=True)
class SumoSample:
    """Joint actions and the SUMO travel times they produced: choices/travel_time [D, N]."""

    choices: np.ndarray
    travel_time: np.ndarray  # minutes
    arrived: np.ndarray  # bool; removed (stuck) vehicles carry a penalty, not a travel time
    # [D, N] float32 seconds each driver left off its schedule that day (departures that move day
    # to day); None: every day as scheduled (zeros)
    shift: np.ndarray | None = None

    @staticmethod
    def from_days(choices: np.ndarray, days: Sequence[DayResult], shift: np.ndarray | None = None
                  ) -> SumoSample:
        return SumoSample(
            choices=np.asarray(choices, dtype=np.int32),
            travel_time=np.stack([d.travel_time for d in days]).astype(np.float32),
            arrived=np.stack([d.status == ARRIVED for d in days]),
            shift=None if shift is None else np.asarray(shift, dtype=np.float32),
        )

    def shifts(self) -> np.ndarray:
        """[D, N] the days' departure shifts (zeros for scheduled days)."""
        return self.shift if self.shift is not None else np.zeros(self.choices.shape, np.float32)

    def __add__(self, other: SumoSample) -> SumoSample:
        moved = self.shift is not None or other.shift is not None
        return SumoSample(
            np.concatenate([self.choices, other.choices]),
            np.concatenate([self.travel_time, other.travel_time]),
            np.concatenate([self.arrived, other.arrived]),
            np.concatenate([self.shifts(), other.shifts()]) if moved else None,
        )

    def __len__(self) -> int:
        return int(self.choices.shape[0])

    def days(self, rows: Sequence[int] | np.ndarray) -> SumoSample:
        """The sample of these days only."""
        return SumoSample(self.choices[rows], self.travel_time[rows], self.arrived[rows],
                          None if self.shift is None else self.shift[rows])


@dataclass(frozen=True)
class FitConfig:
    """Optimiser and loss weights."""

    steps: int = 1000
    learning_rate: float = 0.05
    mean_weight: float = 1.0  # weight of the per-day mean error term
    edge_prior: float = 1e-5  # L2 weight on per-edge log-deviations (prior toward the class value)
    agent_prior: float = 1e-3  # L2 weight on per-agent log speed factors (prior toward 1)
    anchor: float = 0.0  # L2 weight toward the starting parameters (refit)
    frozen: tuple[str, ...] = ()  # parameter names kept at their starting value (ablations)
    queue_steps: int = 300  # `calibrate` of the queue model: steps of the joint fit after the BPR fit


REFIT = FitConfig(steps=150, anchor=1e-2)
ROUTE_BIAS_PRIOR_DAYS = 2.0  # route_bias() shrinkage: residual x count / (count + prior days)
EDGE_KEYS = ("log_speed_e", "log_a_e", "log_junc_e")


def loss_fn(params: Params, static: Static, sample: dict[str, jax.Array], anchor_params: Params,
            fit: FitConfig) -> jax.Array:
    pred = predict_days(params, static, sample["choices"], sample.get("shift"))
    y, m = sample["travel_time"], sample["arrived"]
    rel = jnp.where(m, (pred - y) / y, 0.0)
    agent_term = (rel**2).sum() / jnp.maximum(m.sum(), 1)
    pm = jnp.where(m, pred, 0.0).sum(1) / jnp.maximum(m.sum(1), 1)
    ym = jnp.where(m, y, 0.0).sum(1) / jnp.maximum(m.sum(1), 1)
    mean_term = (((pm - ym) / ym) ** 2).mean()
    prior = fit.edge_prior * sum((params[k] ** 2).sum() for k in EDGE_KEYS)
    prior = prior + fit.agent_prior * (params["log_agent"] ** 2).sum()
    if "log_cap_e" in params:  # the queue model: per-edge capacity deviations, toward the class
        prior = prior + fit.edge_prior * (params["log_cap_e"] ** 2).sum()
    anchor = sum(((params[k] - anchor_params[k]) ** 2).sum() for k in params)
    return agent_term + fit.mean_weight * mean_term + prior + fit.anchor * anchor


def fit_params(params: Params, static: Static, sample: SumoSample, fit: FitConfig | None = None) -> Params:
    """Adam on the full sample (a few hundred jitted steps; each is one batched surrogate day + grad)."""
    fit = fit or FitConfig()
    data = {
        "choices": jnp.asarray(sample.choices, jnp.int32),
        "travel_time": jnp.asarray(np.where(sample.arrived, sample.travel_time, 1.0), jnp.float32),
        "arrived": jnp.asarray(sample.arrived),
    }
    if sample.shift is not None:
        data["shift"] = jnp.asarray(sample.shift, jnp.float32)
    anchor = jax.tree.map(jnp.asarray, params)
    p, _ = _run_fit(anchor, static, data, fit)
    return p


def without_bias(params: Params) -> Params:
    """The smooth model's parameters (the per-route residual is not fitted by gradient)."""
    return {k: v for k, v in params.items() if k != "route_bias"}


def uncalibrated(static: Static) -> Params:
    """The surrogate before any SUMO day: textbook parameters, no route residual (a trainer's start)."""
    return {**init_params(static), "route_bias": jnp.zeros((static.n, static.k), jnp.float32)}


def fit_with_bias(start: Params, static: Static, sub: SumoSample, fit: FitConfig, full: SumoSample,
                  prior_days: float | None, removed: bool = False) -> Params:
    """Gradient fit of the smooth model on `sub`, then the per-route residual (`route_bias`, with
    `removed`) on every day of `full`; `prior_days` None: no residual correction (zeros)."""
    fitted = fit_params(without_bias(start), static, sub, fit)
    bias = (route_bias(fitted, static, full, prior_days, removed) if prior_days is not None
            else jnp.zeros((static.n, static.k), jnp.float32))
    return {**fitted, "route_bias": bias}


def route_bias(params: Params, static: Static, sample: SumoSample, prior_days: float,
               removed: bool = False) -> jax.Array:
    """[N, K] minutes: each (agent, route)'s mean SUMO residual over the days it was driven,
    shrunk toward 0 as `count / (count + prior_days)`.

    The smooth model cannot represent every queue SUMO forms; a policy trained on it keeps
    choosing routes whose SUMO time it underestimates. Correcting exactly the (agent, route)
    pairs SUMO has measured makes those routes look as they drove, while unseen routes keep the
    model's estimate (so the policy still tries them, and the next SUMO days measure them).
    `removed`: a day the vehicle was removed as stuck counts too, at the time charged for it (what
    the metrics count), so a route that gets its drivers stuck looks as costly as it is scored;
    otherwise only arrivals count (the smooth model's fit never sees removals)."""
    pred = predict_bucketed(without_bias(params), static, sample.choices, sample.shift)  # [D, N], D grows
    # a removed vehicle has a finite charged time, a driver at home NaN
    drove = np.isfinite(sample.travel_time) & (sample.choices >= 0) if removed else sample.arrived
    res = np.where(drove, sample.travel_time - pred, 0.0)
    n, k = static.n, static.k
    sums = np.zeros((n, k))
    counts = np.zeros((n, k))
    agents = np.broadcast_to(np.arange(n), sample.choices.shape)
    np.add.at(sums, (agents, sample.choices), res)
    np.add.at(counts, (agents, sample.choices), drove)
    denom = counts + prior_days
    out = np.divide(sums, denom, out=np.zeros_like(sums), where=denom > 0)  # undriven routes: 0
    return jnp.asarray(out, jnp.float32)


@partial(jax.jit, static_argnames="fit")
def _run_fit(p0: Params, static: Static, data: dict[str, jax.Array], fit: FitConfig):
    """`fit.steps` Adam steps in one scan; jitted once per (shapes, FitConfig), so periodic refits
    on same-sized samples do not recompile."""
    opt = optax.adam(fit.learning_rate)

    def step(carry, _):
        p, s = carry
        loss, g = jax.value_and_grad(loss_fn)(p, static, data, p0, fit)
        g = {k: jnp.zeros_like(v) if k in fit.frozen else v for k, v in g.items()}
        upd, s = opt.update(g, s, p)
        return (optax.apply_updates(p, upd), s), loss

    (p, _), losses = jax.lax.scan(step, (p0, opt.init(p0)), None, length=fit.steps)
    return p, losses


def calibrate(
    scenario: Scenario, sumo_days: SumoSample, *, config: SurrogateConfig | None = None,
    fit: FitConfig | None = None, static: Static | None = None,
    route_bias_prior_days: float | None = ROUTE_BIAS_PRIOR_DAYS,
) -> Params:
    """Parameters fitted to SUMO days from the textbook start, then each (agent, route)'s residual on
    the same days, as a training run calibrates its surrogate (`route_bias_prior_days` None: no
    residual, the smooth model alone)."""
    static = static if static is not None else build_static(scenario, config or SurrogateConfig())
    fit = fit or FitConfig()
    start = uncalibrated(static)
    if static.queue is not None:  # the queue model: the BPR part fitted first, then all of it
        bpr = replace(static, queue=None)
        start = {**fit_params(without_bias(uncalibrated(bpr)), bpr, sumo_days, fit), **start_queue(static),
                 "route_bias": start["route_bias"]}
        fit = replace(fit, steps=fit.queue_steps)
    return fit_with_bias(start, static, sumo_days, fit, sumo_days, route_bias_prior_days)


def refit(
    params: Params, scenario: Scenario, new_days: SumoSample, *, config: SurrogateConfig | None = None,
    fit: FitConfig = REFIT, static: Static | None = None, all_days: SumoSample | None = None,
    route_bias_prior_days: float | None = ROUTE_BIAS_PRIOR_DAYS,
) -> Params:
    """Incremental update, as a training run's rounds refit: warm start from `params`, fit the new
    days staying near the previous fit, then the route residual over `all_days` (default: the new
    days; a trainer passes every SUMO day so far)."""
    static = static if static is not None else build_static(scenario, config or SurrogateConfig())
    return fit_with_bias(params, static, new_days, fit, all_days if all_days is not None else new_days,
                         route_bias_prior_days)
