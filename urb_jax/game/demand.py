"""Demand that varies day to day: which drivers travel today (the task's `day_participation`) and
when they leave (`day_departure_jitter_s`).

The URB paper's demand is fixed in OD pairs and departure times. With `day_participation = p < 1`
each driver travels on a given day with probability p, independently of the other drivers and of
the other days. Who travels is a pure function of (env seed, day index, agent): a uniform draw from
`fold_in(fold_in(PRNGKey(env seed), DEMAND_STREAM), day)`, so a SUMO day and a surrogate day with
the same index see the same drivers, a resumed run replays the same days, and the learners' random
streams are untouched. A driver who stays home chooses `ABSENT` (-1) in the day's joint choices:
SUMO inserts no vehicle for it, the surrogate gives it no flow, no CAV observes it, it does not
learn that day, and it is left out of the day's means.

With `day_departure_jitter_s = J > 0` each driver leaves on a given day at its scheduled second plus
an offset drawn uniformly from the integers in [-J, J] (never before second 0), a pure function of
(env seed, day index) under its own stream (`DEPART_STREAM`). SUMO's day inserts every vehicle at
its jittered second, and URB's travel time counts from it. The surrogate's day of the same index
places every route entry, and the insertion load, by the same departures (`DepartureJitter.shift`,
drawn in the program from the traced day index), and it is refitted on SUMO days with their own
departures. CAVs observe the scheduled departures (the jitter is noise around a plan they know).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.demand import ABSENT
from urb_jax.city.scenario import Scenario

DEMAND_STREAM = 0xDA7D  # fold_in tag of the participation draws: no other stream of the run uses it
DEPART_STREAM = 0xDE9A  # fold_in tag of the departure-jitter draws

__all__ = ["ABSENT", "DEMAND_STREAM", "DEPART_STREAM", "DayDemand", "DepartureJitter", "jittered_departures",
           "present_on", "scenario_on_day", "travelled"]


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


@dataclass(frozen=True)
class DepartureJitter:
    """When each driver leaves each day: its scheduled second plus a uniform integer offset in
    [-jitter_s, jitter_s], drawn from `seed` (the run's env seed) and the day index."""

    seed: int  # the run's env seed
    jitter_s: int  # > 0; 0 is URB's fixed departures (no DepartureJitter at all)

    def departures(self, day: int, scheduled: np.ndarray) -> np.ndarray:
        """[N] int64 seconds: day `day`'s departures of drivers scheduled at `scheduled` [N]."""
        return jittered_departures(self.seed, self.jitter_s, day, scheduled)

    def shift(self, day: jax.Array | int, scheduled: np.ndarray) -> jax.Array:
        """[N] float32 seconds each driver leaves off its schedule `scheduled` [N] on day `day`
        (jittable; `day` may be traced): `departures(day, scheduled) - scheduled`, what the
        surrogate's day is placed by."""
        sched = jnp.asarray(scheduled, jnp.int32)
        offset = _offsets(self.seed, self.jitter_s, day, sched.shape)
        return (jnp.maximum(sched + offset, 0) - sched).astype(jnp.float32)

    def scenario_on(self, scenario: Scenario, day: int) -> Scenario:
        """`scenario` with day `day`'s departures (the same agents, in the same order, and routes):
        what SUMO runs that day."""
        depart = self.departures(day, scenario.agent_depart)
        return dataclasses.replace(scenario, agent_depart=depart)


def jittered_departures(seed: int, jitter_s: int, day: int, scheduled: np.ndarray) -> np.ndarray:
    """[N] int64, max(0, scheduled + randint(fold_in(fold_in(PRNGKey(seed), DEPART_STREAM), day),
    [-jitter_s, jitter_s])): a pure function of its arguments, so every run with the same env seed
    sees the same departures on a day of the same index."""
    scheduled = np.asarray(scheduled, dtype=np.int64)
    offset = np.asarray(_offsets(seed, jitter_s, day, scheduled.shape), dtype=np.int64)
    return np.maximum(scheduled + offset, 0)


def _offsets(seed: int, jitter_s: int, day: jax.Array | int, shape: tuple[int, ...]) -> jax.Array:
    """int32 offsets in [-jitter_s, jitter_s], the one draw of day `day`'s departures."""
    key = jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(seed), DEPART_STREAM),
                             jnp.asarray(day, jnp.uint32))
    return jax.random.randint(key, shape, -jitter_s, jitter_s + 1)


def scenario_on_day(scenario: Scenario, jitter: DepartureJitter | None, day: int) -> Scenario:
    """What SUMO runs on day index `day`: `scenario` itself, or with that day's departures."""
    return scenario if jitter is None else jitter.scenario_on(scenario, day)
