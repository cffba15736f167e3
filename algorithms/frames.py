"""What the value learners replay: real decisions (one row per CAV per day, ours) or URB's TorchRL
frames, rebuilt from each day (`frames="urb"`), to measure what that wiring does to learning.

TorchRL steps URB's AEC env once per CAV turn (URB_REFERENCE §8, §12.6), so a day is C frames in
the CAVs' turn order (departure time, stable), and every frame carries a row for every CAV:
  - its observation then: the reset vector (start time, counts 0) before its turn, the one it
    acted on from its turn on;
  - the action the policy emitted for it in that frame; only the turn CAV's is executed, the others
    are fresh epsilon-greedy draws that never reach the road;
  - the reward: 0, except every CAV's day reward on the day's last frame; done only there.
The losses use every row, so a day's reward is credited to the last frame's (mostly un-executed)
actions, and the other frames bootstrap zero-reward targets inside the day.

Both kinds share one interface (`Replay`): what the buffer stores per day, how many Adam steps an
update makes and on how many entries, and how a minibatch is drawn. Frames are stored as the day
plus its emitted actions [C, C] and expanded when sampled, so the buffer stays day-sized.
IPPO and MAPPO build their on-policy frames from the same pieces (`ippo.frame_batch`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.algorithms.buffer import Buffer, buffer_sample
from urb_jax.algorithms.learner import Day
from urb_jax.algorithms.policy import eps_greedy
from urb_jax.algorithms.updates import n_updates, update_plan
from urb_jax.game.env import RoutingEnv

_EMIT_STREAM = 0x5EED  # fold_in tag for the frame draws: days mode's keys stay as they were

QFn = Callable[[jnp.ndarray], jnp.ndarray]  # obs [..., C, D] -> Q values [..., C, K]


class FrameDay(NamedTuple):
    """A stored day in frame mode."""

    day: Day
    frame_actions: jnp.ndarray  # [C(frames), C] action emitted for each CAV in each frame


def turn_positions(env: RoutingEnv) -> np.ndarray:
    """[C] each CAV's position in the day's turn order (departure time; ties keep CAV order)."""
    depart = np.asarray(env.scenario.agent_depart)[env.cav_index]
    order = np.argsort(depart, kind="stable")
    turn = np.empty(len(order), np.int32)
    turn[order] = np.arange(len(order), dtype=np.int32)
    return turn


def unacted(obs: jnp.ndarray, k: int) -> jnp.ndarray:
    """The reset observation a CAV shows before its turn: every route count 0 (they are the last K
    columns of each observation type), the start time kept."""
    return obs.at[..., obs.shape[-1] - k:].set(0.0)


def frame_obs(obs: jnp.ndarray, turn: jnp.ndarray, frame: jnp.ndarray, k: int) -> jnp.ndarray:
    """obs [..., C, D] acted-on observations, frame [...] -> every CAV's observation in that frame."""
    acted = turn <= frame[..., None]  # [..., C]
    return jnp.where(acted[..., None], obs, unacted(obs, k))


def emit_frame_actions(key: jax.Array, q_fn: QFn, mask: jnp.ndarray, eps: jnp.ndarray, day: Day,
                       turn: jnp.ndarray, k: int) -> jnp.ndarray:
    """[M, C, C] the actions the epsilon-greedy policy emits in each frame of M days (day arrays
    [M, C, ...]): the executed action at a CAV's turn, a fresh draw in every other frame. A CAV's
    frame observation is one of two (before / from its turn), so two Q evaluations per CAV suffice."""
    frames = jnp.arange(turn.shape[0])[:, None]  # [C(frames), 1]
    q_acted = q_fn(day.obs)[:, None]  # [M, 1, C, K]
    q_before = q_fn(unacted(day.obs, k))[:, None]
    q = jnp.where((turn <= frames)[..., None], q_acted, q_before)  # [M, C(frames), C, K]
    drawn = eps_greedy(key, q, mask, eps)
    return jnp.where(turn == frames, day.action[:, None, :], drawn).astype(jnp.int32)


def expand_frames(stored: FrameDay, frame: jnp.ndarray, turn: jnp.ndarray, k: int) -> Day:
    """Frame `frame` [M] of each of M stored days -> Day rows [M, C] as TorchRL's loss sees them."""
    day = stored.day
    c = turn.shape[0]
    last = frame == c - 1  # [M]
    action = jnp.take_along_axis(stored.frame_actions, frame[:, None, None], axis=1)[:, 0]  # [M, C]
    return Day(frame_obs(day.obs, turn, frame, k), action,
               jnp.where(last[:, None], day.reward, 0.0),
               jnp.broadcast_to(last[:, None], day.done.shape),
               frame_obs(day.obs, turn, jnp.minimum(frame + 1, c - 1), k),
               day.time_cav, day.time_human)


def sample_frames(buf: Buffer, key: jax.Array, n: int, turn: jnp.ndarray, k: int) -> Day:
    """n distinct stored frames, uniformly (no replacement, as TorchRL's sampler), expanded."""
    cap = jax.tree_util.tree_leaves(buf.data)[0].shape[0]
    c = turn.shape[0]
    scores = jnp.where(jnp.arange(cap * c) < buf.size * c, jax.random.uniform(key, (cap * c,)), -1.0)
    _, idx = jax.lax.top_k(scores, n)
    stored = jax.tree_util.tree_map(lambda d: d[idx // c], buf.data)
    return expand_frames(stored, idx % c, turn, k)


class Replay(NamedTuple):
    """store(key, q_fn, eps, days[M]) -> buffer entries; plan(days collected) -> (Adam steps per
    epoch, entries per minibatch); sample(buffer, key, n) -> Day batch; ready(buffer, n)."""

    example: Callable[[Day], Any]
    store: Callable[[jax.Array, QFn, jnp.ndarray, Day], Any]
    plan: Callable[[int], tuple[int, int]]
    sample: Callable[[Buffer, jax.Array, int], Day]
    ready: Callable[[Buffer, int], jnp.ndarray]


def make_replay(frames: str, env: RoutingEnv, num_minibatches: int, minibatch_size: int,
                capacity_days: int) -> Replay:
    n_cav, k = env.n_cavs, env.n_actions
    if frames == "days":
        return Replay(
            example=lambda day: day,
            store=lambda key, q_fn, eps, days: days,
            plan=lambda days: update_plan(num_minibatches, minibatch_size, days, n_cav, capacity_days),
            sample=buffer_sample,
            ready=lambda buf, n: buf.size >= n)
    turn = jnp.asarray(turn_positions(env))
    mask = jnp.asarray(env.action_mask)

    def store(key: jax.Array, q_fn: QFn, eps: jnp.ndarray, days: Day) -> FrameDay:
        emitted = emit_frame_actions(jax.random.fold_in(key, _EMIT_STREAM), q_fn, mask, eps, days, turn, k)
        return FrameDay(days, emitted)

    return Replay(
        example=lambda day: FrameDay(day, jnp.zeros((n_cav, n_cav), jnp.int32)),
        store=store,
        plan=lambda days: (n_updates(1, days, n_cav, minibatch_size),
                           min(minibatch_size, capacity_days * n_cav)),
        sample=lambda buf, key, n: sample_frames(buf, key, n, turn, k),
        ready=lambda buf, n: buf.size * n_cav >= n)
