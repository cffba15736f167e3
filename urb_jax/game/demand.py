"""Demand that varies day to day (the task's `day_participation`): which drivers travel today.

The URB paper's demand is fixed in OD pairs and departure times. With `day_participation = p < 1`
each driver travels on a given day with probability p, independently of the other drivers and of
the other days. Who travels is a pure function of (env seed, day index, agent): a uniform draw from
`fold_in(fold_in(PRNGKey(env seed), DEMAND_STREAM), day)`, so a SUMO day and a surrogate day with
the same index see the same drivers, a resumed run replays the same days, and the learners' random
streams are untouched. A driver who stays home chooses `ABSENT` (-1) in the day's joint choices:
SUMO inserts no vehicle for it, the surrogate gives it no flow, no CAV observes it, it does not
learn that day, and it is left out of the day's means.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from urb_jax.city.demand import ABSENT

DEMAND_STREAM = 0xDA7D  # fold_in tag of the participation draws: no other stream of the run uses it

__all__ = ["ABSENT", "DEMAND_STREAM", "DayDemand", "present_on", "travelled"]


@dataclass(frozen=True)
class DayDemand:
    """Who travels each day: every driver with probability `participation`, drawn from `seed`."""

    seed: int  # the run's env seed
    participation: float  # in (0, 1]; 1 is URB's fixed demand

    def present(self, day: jax.Array | int, n: int) -> jax.Array:
        """[N] bool: the drivers who travel on day `day` (jittable; `day` may be traced)."""
        return present_on(self.seed, self.participation, day, n)


def present_on(seed: int, participation: float, day: jax.Array | int, n: int) -> jax.Array:
    """[N] bool, uniform(fold_in(fold_in(PRNGKey(seed), DEMAND_STREAM), day))[i] < participation.
    Element i depends on (seed, day, i) only (JAX's partitionable threefry), not on other agents."""
    key = jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(seed), DEMAND_STREAM),
                             jnp.asarray(day, jnp.uint32))
    return jax.random.uniform(key, (n,)) < participation


def travelled(choices: jax.Array) -> jax.Array:
    """[..., N] bool: who travelled on a day of joint `choices` [..., N] (ABSENT: stayed home)."""
    return choices != ABSENT
