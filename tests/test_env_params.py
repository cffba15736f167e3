"""Travel-time parameters ride in the env state, so a refit needs no recompilation."""

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.game.env import RoutingEnv
from urb_jax.game.mutation import draw_cavs


def test_params_from_state_change_times_without_retracing(grid_scenario):
    scn = grid_scenario
    fft = jnp.asarray(scn.fft_full)
    traces = []

    def tt(params, choices):
        traces.append(1)
        return fft[jnp.arange(scn.n_agents), choices] * params["scale"]

    env = RoutingEnv(scn, draw_cavs(0, scn.n_agents, 0.4), tt, travel_params={"scale": jnp.asarray(1.0)})
    _, state = env.reset(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    actions = jnp.zeros((env.n_cavs,), jnp.int32)
    _, _, r1, _, info1 = step(jax.random.PRNGKey(1), state, actions)
    state2 = RoutingEnv.with_travel_params(state, {"scale": jnp.asarray(2.0)})
    _, _, r2, _, info2 = step(jax.random.PRNGKey(1), state2, actions)
    assert np.allclose(np.asarray(info2["times"]), 2 * np.asarray(info1["times"]))
    assert np.allclose(np.asarray(r2), 2 * np.asarray(r1))  # selfish: reward = -own time
    assert len(traces) == 1

    batched = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 3))[1]
    swapped = RoutingEnv.with_travel_params(batched, {"scale": jnp.asarray(3.0)})
    assert swapped.travel_params["scale"].shape == (3,)
