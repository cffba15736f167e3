"""Stand-in congestion model for tests and benchmarks that time the learner, not the environment.

Static BPR on route-edge flows over one departure window: flow_e = number of agents whose route
uses edge e, t_e = t0_e * (1 + alpha * (flow_e / cap_e)^power) with cap_e = capacity (veh/h) x
window, and an agent's time is the sum over its route's edges (minutes). Not a product module.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.game.env import RoutingEnv
from urb_jax.game.mutation import draw_cavs
from urb_jax.game.rewards import behaviour_coefficients


def bpr_travel_time_fn(scn: Scenario, window_h: float = 0.5, alpha: float = 0.15, power: float = 4.0):
    routes = jnp.asarray(scn.routes, dtype=jnp.int32)  # [N, K, L]
    n, n_edges = scn.n_agents, scn.n_edges
    t0 = jnp.asarray(scn.edge_length / np.maximum(scn.edge_speed, 0.1) / 60.0, dtype=jnp.float32)
    cap = jnp.asarray(np.maximum(scn.edge_capacity * window_h, 1.0), dtype=jnp.float32)

    def travel_times(choices: jnp.ndarray) -> jnp.ndarray:
        r = routes[jnp.arange(n), choices]  # [N, L]
        valid = r >= 0
        idx = jnp.where(valid, r, 0)
        flows = jax.ops.segment_sum(valid.astype(jnp.float32).ravel(), idx.ravel(), num_segments=n_edges)
        t_edge = t0 * (1.0 + alpha * (flows / cap) ** power)
        return jnp.where(valid, t_edge[idx], 0.0).sum(-1)

    return travel_times


def make_env(scn: Scenario, cav_share: float = 0.4, behaviour: str = "selfish", seed: int = 42,
             **kwargs) -> RoutingEnv:
    """A RoutingEnv on the stand-in with URB's mutation share and a named CAV behaviour."""
    is_cav = draw_cavs(seed, scn.n_agents, cav_share, agent_id=scn.agent_id)
    return RoutingEnv(scn, is_cav, bpr_travel_time_fn(scn),
                      reward_coefficients=behaviour_coefficients(behaviour), **kwargs)
