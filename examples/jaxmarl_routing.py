"""urb-jax's surrogate routing game through JaxMARL's interface (docs/jaxmarl.md).

    pip install 'urb-jax[jaxmarl]'
    python examples/jaxmarl_routing.py                       # embedded urb_grid, uncalibrated surrogate
    python examples/jaxmarl_routing.py --run results/RUN     # a finished `urb-jax train` run's network,
                                                             # humans and calibrated surrogate
    python examples/jaxmarl_routing.py --run results/RUN --sumo   # + the learned policy on SUMO test days

JaxMARL-style: vmapped `reset`/`step` of `JaxMARLRoutingEnv` inside one `lax.scan`, behind JaxMARL's
`LogWrapper`. The learner is deliberately tiny (each CAV keeps a running mean reward per route and
acts epsilon-greedily, i.e. it ignores its observation); JaxMARL's own baselines take the env the
same way, e.g. its IPPO script with `jaxmarl.make` pointed at the env (docs/jaxmarl.md).
"""

from __future__ import annotations

import argparse
from typing import Any

import jax
import jax.numpy as jnp
from jaxmarl.wrappers.baselines import LogWrapper

from urb_jax.interop.jaxmarl import JaxMARLRoutingEnv


def grid_env() -> Any:
    """The embedded urb_grid with URB's config1 task, fresh humans and the uncalibrated surrogate."""
    from urb_jax.city.scenario import load_scenario
    from urb_jax.game.config import EnvConfig, TaskConfig
    from urb_jax.game.humans import init_humans
    from urb_jax.game.mutation import draw_cavs
    from urb_jax.surrogate import build_static, uncalibrated
    from urb_jax.training.hybrid.trainer import routing_env_kwargs, surrogate_env

    scn, task = load_scenario("urb_grid"), TaskConfig()
    static = build_static(scn)
    humans = init_humans(jax.random.PRNGKey(0), jnp.asarray(scn.fft), jnp.asarray(scn.route_valid),
                         task.human_params())
    is_cav = draw_cavs(42, scn.n_agents, task.ratio_machines, agent_id=scn.agent_id)
    kwargs = routing_env_kwargs(task, EnvConfig(), 42)  # env seed 42: the draw above
    return surrogate_env(scn, is_cav, static, humans, uncalibrated(static), kwargs)


def train(env: JaxMARLRoutingEnv, days: int, n_envs: int, key: jax.Array, eps: float = 0.2
          ) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """(value table [C, K], mean day reward per day [days] while learning, of random routes [days])."""
    log = LogWrapper(env)
    C, K = env.num_agents, env.action_space(env.agents[0]).n
    k_reset, k_days = jax.random.split(key)
    _, states = jax.vmap(log.reset)(jax.random.split(k_reset, n_envs))

    def day(carry, key):
        states, q, n = carry
        k_explore, k_route, k_step = jax.random.split(key, 3)
        explore = jax.random.uniform(k_explore, (n_envs, C)) < eps
        routes = jnp.where(explore, jax.random.randint(k_route, (n_envs, C), 0, K),
                           jnp.argmax(q, -1))  # [B, C]
        actions = {a: routes[:, i] for i, a in enumerate(env.agents)}
        _, states, rewards, _, info = jax.vmap(log.step)(jax.random.split(k_step, n_envs), states, actions)
        r = jnp.stack([rewards[a] for a in env.agents], axis=-1)  # [B, C]
        hit = jax.nn.one_hot(routes, K)  # [B, C, K]
        n = n + hit.sum(0)
        q = q + (hit * (r[..., None] - q)).sum(0) / jnp.maximum(n, 1.0)
        random_day = jnp.where(explore, r, jnp.nan)
        return (states, q, n), (info["returned_episode_returns"].mean(), jnp.nanmean(random_day))

    q0 = jnp.zeros((C, K))  # optimistic against negative rewards: every route gets tried
    (_, q, _), (learning, random) = jax.lax.scan(day, (states, q0, jnp.zeros((C, K))),
                                                 jax.random.split(k_days, days))
    return q, learning, random


def greedy_day(env: JaxMARLRoutingEnv, q: jnp.ndarray, key: jax.Array) -> float:
    """Mean CAV travel time (minutes) of one surrogate day with every CAV on its best route."""
    _, state = env.reset(key)
    routes = jnp.argmax(q, -1)
    _, _, _, _, info = env.step(key, state, {a: routes[i] for i, a in enumerate(env.agents)})
    return float(info["travel_time"].mean())


def main(argv: list[str] | None = None) -> dict[str, float]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", help="a finished `urb-jax train` run folder (default: urb_grid, no SUMO)")
    ap.add_argument("--days", type=int, default=60, help="surrogate days per env")
    ap.add_argument("--envs", type=int, default=8, help="envs side by side (vmap)")
    ap.add_argument("--sumo", action="store_true", help="evaluate the greedy policy on SUMO test days")
    ap.add_argument("--results-dir", default="results")
    args = ap.parse_args(argv)
    if args.run:
        from urb_jax.interop.outside import surrogate_env_from_run
        game = surrogate_env_from_run(args.run).env
    else:
        game = grid_env()
    env = JaxMARLRoutingEnv(game)
    run = jax.jit(train, static_argnums=(0, 1, 2))
    q, learning, random = run(env, args.days, args.envs, jax.random.PRNGKey(0))
    out = {"first_days": float(learning[:5].mean()), "last_days": float(learning[-5:].mean()),
           "random_routes": float(jnp.nanmean(random)),
           "greedy_time": greedy_day(env, q, jax.random.PRNGKey(1))}
    print(f"{env.num_agents} CAVs, {args.envs} envs x {args.days} surrogate days: mean day reward "
          f"{out['first_days']:.4f} -> {out['last_days']:.4f} (random routes {out['random_routes']:.4f}); "
          f"greedy day, mean CAV time {out['greedy_time']:.4f} min")
    if args.sumo:
        if not args.run:
            ap.error("--sumo needs --run (the human phase it replays)")
        from urb_jax.interop.outside import evaluate_on_sumo
        res = evaluate_on_sumo(bandit_policy(q), args.run, name="jaxmarl_bandit",
                               results_dir=args.results_dir, overwrite=True)
        out |= {f"sumo_{k}": v for k, v in res.metrics.items()}
        print(f"SUMO test days: t_CAV {res.metrics['t_CAV']:.4f}, t_pre {res.metrics['t_pre']:.4f} "
              f"({res.folder})")
    return out


def bandit_policy(q: jnp.ndarray) -> Any:
    """The value table as urb-jax's Policy(key, obs [n, D], idx): the rows of the CAVs acting."""
    def policy(key: jax.Array, obs: jnp.ndarray, idx: jnp.ndarray | None = None) -> jnp.ndarray:
        return jnp.argmax(q if idx is None else q[idx], -1)

    return policy


if __name__ == "__main__":
    main()
