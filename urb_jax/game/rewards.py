"""CAV reward profiles (URB_REFERENCE §6): R_i = a*t_own + b*T_cav + c*T_human + d*T_all.

Travel times in minutes; group means over CAVs / humans / everyone (0 for an empty group).
Pure jax.numpy, so it runs inside jitted environments and on numpy SUMO days alike.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.core.errors import ConfigError

BEHAVIOURS: dict[str, tuple[float, float, float, float]] = {
    "selfish": (-1.0, 0.0, 0.0, 0.0),
    "competitive": (-2.0, 0.0, 1.0, 0.0),
    "collaborative": (-0.5, -0.5, 0.0, 0.0),
    "cooperative": (0.0, -1.0, 0.0, 0.0),
    "social": (-0.5, 0.0, 0.0, -0.5),
    "altruistic": (0.0, 0.0, 0.0, -1.0),
    "malicious": (0.0, 0.0, 1.0, 0.0),
    "collectivist": (-0.1, -0.9, 0.0, 0.0),
    "militant": (0.0, -2.0, 1.0, 0.0),
}


def behaviour_coefficients(behaviour: str | Sequence[float]) -> tuple[float, float, float, float]:
    """(own, CAV group, humans, everyone) weights for a named profile or a custom 4-tuple."""
    if isinstance(behaviour, str):
        if behaviour not in BEHAVIOURS:
            raise ConfigError(
                f"unknown av_behavior '{behaviour}'. Fix: use one of {', '.join(BEHAVIOURS)} "
                "or a list of 4 numbers [own, cav_group, humans, all]."
            )
        return BEHAVIOURS[behaviour]
    coeffs = tuple(float(x) for x in behaviour)
    if len(coeffs) != 4:
        raise ConfigError(f"custom av_behavior needs 4 numbers [own, cav_group, humans, all], got {coeffs}")
    return coeffs


def _masked_mean(x: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    count = mask.sum(axis=-1)
    total = jnp.where(mask, x, 0.0).sum(axis=-1)
    return jnp.where(count > 0, total / jnp.maximum(count, 1), 0.0)


def group_means(times: jnp.ndarray, is_cav: jnp.ndarray, travelled: jnp.ndarray | None = None
                ) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """(mean over CAVs, mean over humans, mean over all) along the last axis; `travelled` [..., N]
    (None: everyone): only the drivers who travelled that day count."""
    is_cav = jnp.asarray(is_cav, dtype=bool)
    if travelled is not None:
        return (_masked_mean(times, is_cav & travelled), _masked_mean(times, ~is_cav & travelled),
                _masked_mean(times, travelled))
    all_mask = jnp.ones_like(is_cav)
    return _masked_mean(times, is_cav), _masked_mean(times, ~is_cav), _masked_mean(times, all_mask)


def cav_rewards(
    times: jnp.ndarray, is_cav: jnp.ndarray, coefficients: Sequence[float],
    travelled: jnp.ndarray | None = None,
) -> jnp.ndarray:
    """Reward of every agent as if it were a CAV (use it for CAVs); works batched [..., N].
    `travelled` [..., N] (None: everyone): the group means cover those who travelled that day."""
    a, b, c, d = (float(v) for v in coefficients)
    t_cav, t_hum, t_all = group_means(times, is_cav, travelled)
    shared = b * t_cav + c * t_hum + d * t_all
    return a * times + shared[..., None]


def fleet_rewards(times: jnp.ndarray, cav_fleet: np.ndarray, coefficients: Sequence[Sequence[float]],
                  ) -> jnp.ndarray:
    """Competing fleets' rewards [..., N]: a member of fleet f is paid its fleet's behaviour,
    R_i = a_f t_i + b_f T_f + c_f T_HDV + d_f T_all, where T_f is fleet f's mean (its own CAVs,
    not the other fleets'), T_HDV the humans' and T_all everyone's; a human's entry is 0.
    `cav_fleet` [N]: each agent's fleet, -1 for a human (`game.mutation.split_fleets`)."""
    cav_fleet = np.asarray(cav_fleet)
    humans = jnp.asarray(cav_fleet < 0)
    t_hum = _masked_mean(times, humans)
    t_all = _masked_mean(times, jnp.ones_like(humans))
    out = jnp.zeros_like(times)
    for f, coeffs in enumerate(coefficients):
        a, b, c, d = (float(v) for v in coeffs)
        member = jnp.asarray(cav_fleet == f)
        reward = a * times + (b * _masked_mean(times, member) + c * t_hum + d * t_all)[..., None]
        out = jnp.where(member, reward, out)
    return out


CREDITS = ("group", "marginal")


def externalities(travel_time: Callable[[jnp.ndarray], jnp.ndarray], choices: jnp.ndarray,
                  is_cav: np.ndarray | jnp.ndarray, k: int) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(externalities [3, N], model times [N]) of a day's choices [N] under a differentiable day
    model `travel_time(probabilities [N, K]) -> minutes [N]`, linear in each agent's own row.

    externalities[g, i] = the delay agent i's trip adds to the members of group g (CAVs, humans,
    everyone) other than itself: d(sum over g of t_j) / d(i's weight on its chosen route) (one
    backward pass per group gives every agent's at once) minus, for a member of g, its own route
    term t_i - t_i(P = 0) (what is left of t_i at zero weights, e.g. an insertion delay, does not
    depend on i's route). Under a congestion model (flows never speed anyone up) they are >= 0."""
    onehot = jax.nn.one_hot(choices, k, dtype=jnp.float32)
    times, vjp = jax.vjp(travel_time, onehot)
    # [N] the route-independent part of each time; the barrier keeps XLA from constant-folding
    # the model at zero flows while compiling (a scatter-add it took > 1 s to fold on ingolstadt)
    base = travel_time(jax.lax.optimization_barrier(jnp.zeros_like(onehot)))
    is_cav = jnp.asarray(is_cav, dtype=bool)
    member = jnp.stack([is_cav, ~is_cav, jnp.ones_like(is_cav)]).astype(times.dtype)  # [3, N]
    grads = jax.vmap(lambda m: vjp(m)[0])(member)  # [3, N, K]
    margins = jnp.take_along_axis(grads, choices.astype(jnp.int32)[None, :, None], axis=2)[..., 0]
    return margins - member * (times - base)[None], times


def credit_rewards(times: jnp.ndarray, is_cav: jnp.ndarray, coefficients: Sequence[float],
                   externality: jnp.ndarray) -> jnp.ndarray:
    """Per-agent credit (`reward_credit: marginal`): each group-mean term of the behaviour
    (b T_CAV + c T_HDV + d T_all) becomes the agent's marginal effect on that group's total time,
    R_i = a t_i + b M_CAV,i + c M_HDV,i + d M_all,i, M_g,i = [i in g] t_i + externality[g, i]:
    the measured own time (SUMO's on a SUMO day) plus the delay the model says i adds to g's other
    members (`externalities`). A cooperative CAV is paid -(t_i + the delay it adds to the other
    CAVs): the linearised difference reward of the team objective, an agent-sized signal where the
    group mean pays every CAV the same number whatever it did."""
    a, b, c, d = (float(v) for v in coefficients)
    is_cav = jnp.asarray(is_cav, dtype=bool)
    member = jnp.stack([is_cav, ~is_cav, jnp.ones_like(is_cav)]).astype(times.dtype)  # [3, N]
    m = member * times[None] + externality
    return a * times + b * m[0] + c * m[1] + d * m[2]


def marginal_cost_rewards(rewards: jnp.ndarray, externality: jnp.ndarray, beta: float) -> jnp.ndarray:
    """URB's marginal-cost task family (`config_marginal_*`, key marginal_cost_coefficient_beta):
    "AVs care about their impact". Each agent's behaviour reward minus beta times the delay its trip
    adds to everyone else (`externalities` row 2, the agent's own time excluded):
    R_i = R_i^behaviour - beta * E_all,i. beta = 0 is the behaviour reward itself."""
    return rewards - beta * externality[2]
