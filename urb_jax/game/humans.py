"""Human route choice and day-to-day learning (URB paper HLM; URB_REFERENCE §4), vectorised.

State: expected travel time C[i, k] (minutes, positive) per human and route, initialised to the
free-flow time. The paper's general model, each term off by default (= the paper's default):

* learning:  C_a <- (1 - alpha) C_a + alpha * t_hat  on the chosen route a only (Gawron);
             skipped when |t_hat - C_a| <= gamma_u * C_a (update threshold, bounded rationality);
* perception noise: t_hat = t * (1 + epsilon * z), z ~ N(0, 1);
* choice, deterministic: a = argmin_k C_k, but keep yesterday's route unless the best is better
  by more than gamma_c * C_yesterday (switching threshold); stochastic: p_k ∝ exp(-|beta_i| C_k);
* exploration: with probability delta a uniformly random route.

beta_i ~ U(beta - r, beta + r) per driver. Humans minimise expected time whatever the sign of
beta. `routerl_literal=True` reproduces RouteRL 2.0.0: utilities exp(beta_i * c) on negative
costs c = -C, argmax / softmax, so URB's beta = -1.5 picks the *slowest* route (URB issue #54).

Models: `gawron` (above), `culo` (cumulative: C_a <- C_a + alpha * t_hat), `weighted` (C_a is a
1/(j+1)-weighted mean of the last `remember` experiences — RouteRL adds alpha*r on top and drifts,
§12.13; we blend instead: C_a <- (1-alpha) * mean_w + alpha * t_hat), `random` (uniform), `aon`
(always the minimum free-flow route).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.core.errors import ConfigError

HUMAN_MODELS = ("gawron", "culo", "weighted", "random", "aon")


@dataclass(frozen=True)
class HumanParams:
    model: str = "gawron"
    alpha: float = 0.2
    beta: float = -1.5
    beta_randomness: float = 0.1
    deterministic: bool = True
    gamma_c: float = 0.0  # switching threshold (relative)
    gamma_u: float = 0.0  # update threshold (relative)
    epsilon: float = 0.0  # perception noise (relative std)
    delta: float = 0.0  # exploration probability
    remember: int = 5  # `weighted` memory length
    routerl_literal: bool = False

    def __post_init__(self) -> None:
        if self.model not in HUMAN_MODELS:
            raise ConfigError(
                f"human_model '{self.model}' is unknown. Fix: use one of {', '.join(HUMAN_MODELS)}."
            )
        if not 0.0 <= self.alpha <= 1.0 and self.model != "culo":
            raise ConfigError(f"human_alpha must be in [0, 1], got {self.alpha}.")
        if not 0.0 <= self.delta <= 1.0:
            raise ConfigError(f"human exploration delta must be in [0, 1], got {self.delta}.")


class HumanState(NamedTuple):
    cost: jnp.ndarray  # [N, K] expected travel time, minutes (inf on masked routes)
    beta: jnp.ndarray  # [N] personal beta
    last_action: jnp.ndarray  # [N] int32, yesterday's route (-1 before the first day)
    memory: jnp.ndarray  # [N, K, remember] last experiences (weighted model), nan = empty


def init_humans(key: jax.Array, fft: jnp.ndarray, valid: jnp.ndarray, params: HumanParams) -> HumanState:
    n, k = fft.shape
    beta = jax.random.uniform(
        key, (n,), minval=params.beta - params.beta_randomness, maxval=params.beta + params.beta_randomness
    )
    cost = jnp.where(valid, jnp.asarray(fft, dtype=jnp.float32), jnp.inf)
    memory = jnp.full((n, k, max(params.remember, 1)), jnp.nan, dtype=jnp.float32)
    return HumanState(cost, beta, jnp.full((n,), -1, dtype=jnp.int32), memory)


def aon_routes(fft: np.ndarray | jax.Array, valid: np.ndarray | jax.Array) -> np.ndarray | jax.Array:
    """[N] each row's minimum free-flow route (the first on ties, padding repeats excluded): URB's
    all-or-nothing choice. numpy in, numpy out (float64 fft, exact); jax in, jax out (traceable)."""
    xp = np if isinstance(fft, np.ndarray) and isinstance(valid, np.ndarray) else jnp
    return xp.argmin(xp.where(valid, fft, xp.inf), axis=1).astype(xp.int32)


def _scores(state: HumanState, params: HumanParams) -> jnp.ndarray:
    """Higher is preferred. Paper: -|beta| C. RouteRL literal: beta * c with c = -C."""
    cost = state.cost
    if params.routerl_literal:
        finite = jnp.where(jnp.isfinite(cost), cost, 0.0)
        s = -state.beta[:, None] * finite
        return jnp.where(jnp.isfinite(cost), s, -jnp.inf)
    return -jnp.abs(state.beta)[:, None] * cost


def act(
    key: jax.Array, state: HumanState, params: HumanParams, fft: jnp.ndarray | None = None
) -> jnp.ndarray:
    """Today's route of every human, [N] int32."""
    n = state.cost.shape[0]
    valid = jnp.isfinite(state.cost)
    k_choice, k_explore, k_uniform = jax.random.split(key, 3)
    if params.model == "aon":
        return cast(jax.Array, aon_routes(fft if fft is not None else state.cost, valid))  # jax in, jax out
    uniform = jax.random.categorical(k_uniform, jnp.where(valid, 0.0, -jnp.inf), axis=1)
    if params.model == "random":
        return uniform.astype(jnp.int32)
    scores = _scores(state, params)
    if params.deterministic:
        best = jnp.argmax(scores, axis=1)  # first index on ties, like RouteRL's argmax
        if params.gamma_c > 0.0 and not params.routerl_literal:
            last = state.last_action
            has_last = last >= 0
            c_last = jnp.take_along_axis(state.cost, jnp.maximum(last, 0)[:, None], axis=1)[:, 0]
            c_best = jnp.take_along_axis(state.cost, best[:, None], axis=1)[:, 0]
            keep = has_last & (c_best >= c_last * (1.0 - params.gamma_c))
            best = jnp.where(keep, last, best)
        choice = best
    else:
        choice = jax.random.categorical(k_choice, scores, axis=1)
    if params.delta > 0.0:
        explore = jax.random.uniform(k_explore, (n,)) < params.delta
        choice = jnp.where(explore, uniform, choice)
    return choice.astype(jnp.int32)


def learn(
    key: jax.Array, state: HumanState, actions: jnp.ndarray, times: jnp.ndarray, params: HumanParams,
    learning: jnp.ndarray | bool = True,
) -> HumanState:
    """Update the chosen route's expected time from today's travel times (minutes).

    `learning` ([N] bool or scalar) freezes agents that do not learn (CAVs, frozen humans), which
    still keep `last_action`.
    """
    n = state.cost.shape[0]
    learning = jnp.broadcast_to(jnp.asarray(learning, dtype=bool), (n,))
    t_hat = times
    if params.epsilon > 0.0:
        t_hat = times * (1.0 + params.epsilon * jax.random.normal(key, times.shape))
    rows = jnp.arange(n)
    c_a = state.cost[rows, actions]
    memory = state.memory
    if params.model == "gawron":
        new = (1.0 - params.alpha) * c_a + params.alpha * t_hat
    elif params.model == "culo":
        new = c_a + params.alpha * t_hat
    elif params.model == "weighted":
        mem_a = memory[rows, actions]  # [N, R], most recent first
        weights = 1.0 / (jnp.arange(mem_a.shape[1]) + 1.0)
        have = jnp.isfinite(mem_a)
        w = jnp.where(have, weights, 0.0)
        weighted_sum = (jnp.where(have, mem_a, 0.0) * w).sum(1)
        mean_w = jnp.where(have.any(axis=1), weighted_sum / jnp.maximum(w.sum(1), 1e-9), c_a)
        new = (1.0 - params.alpha) * mean_w + params.alpha * t_hat
        shifted = jnp.concatenate([t_hat[:, None], mem_a[:, :-1]], axis=1)
        memory = memory.at[rows, actions].set(jnp.where(learning[:, None], shifted, mem_a))
    else:  # random, aon: no learning
        new = c_a
    if params.gamma_u > 0.0:
        new = jnp.where(jnp.abs(t_hat - c_a) > params.gamma_u * c_a, new, c_a)
    new = jnp.where(learning, new, c_a)
    cost = state.cost.at[rows, actions].set(new)
    return HumanState(cost, state.beta, actions.astype(jnp.int32), memory)


def end_day(
    key: jax.Array, state: HumanState, choices: jnp.ndarray, times: jnp.ndarray, params: HumanParams,
    is_cav: np.ndarray | jnp.ndarray, learn_today: bool, travelled: jnp.ndarray | None = None,
) -> HumanState:
    """Human knowledge after a day of `choices` [N] and `times` [N] (minutes): the one day-end rule.

    On a learning day the humans (not the CAVs) update their expected times (`learn`); otherwise
    their knowledge is frozen and everyone only remembers today's route (`last_action`, the
    reference of the switching threshold). Whether a day is a learning day is the caller's phase
    rule (the task's `should_humans_adapt`, `RoutingEnv.humans_adapt`). `travelled` ([N] bool,
    None: everyone): the drivers who travelled today (the task's `day_participation`).
    """
    if travelled is not None:
        return _end_day_present(key, state, choices, times, params, is_cav, learn_today, travelled)
    if learn_today:
        return learn(key, state, choices, times, params, learning=~jnp.asarray(is_cav))
    return state._replace(last_action=jnp.asarray(choices, jnp.int32))


def _end_day_present(key: jax.Array, state: HumanState, choices: jnp.ndarray, times: jnp.ndarray,
                     params: HumanParams, is_cav: np.ndarray | jnp.ndarray, learn_today: bool,
                     travelled: jnp.ndarray) -> HumanState:
    """`end_day` when some drivers stayed home (`travelled` [N] False; their choice is ABSENT, -1):
    a driver learns only from a day it travelled, and one who stayed home keeps yesterday's
    route as the switching threshold's reference (its knowledge is untouched)."""
    routes = jnp.where(travelled, choices, state.last_action).astype(jnp.int32)  # [N]
    if learn_today:
        learning = ~jnp.asarray(is_cav) & travelled
        done = learn(key, state, jnp.maximum(routes, 0), times, params, learning=learning)
        return done._replace(last_action=routes)
    return state._replace(last_action=routes)


# Jitted entry points for callers that run day by day outside jit (the SUMO protocol, PettingZoo,
# the human baseline): one compilation per HumanParams, shared by every caller.
init_humans_jit = jax.jit(init_humans, static_argnames=("params",))
act_jit = jax.jit(act, static_argnames=("params",))
learn_jit = jax.jit(learn, static_argnames=("params",))
end_day_jit = jax.jit(end_day, static_argnames=("params", "learn_today"))
