"""Typed configs of the algorithm families (URB's keys plus our vectorisation options)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from urb_jax.core.errors import ConfigError
from urb_jax.core.ranges import ENVS, FRACTION, SIZE, STEPS, Range, above, between, check_ranges

LR = above(0, 10, "URB's configs: 1e-4 to 1e-2")
MEMORY = between(1, 100_000_000)  # replay samples
FRAME_KINDS = ("days", "urb")  # what the value learners replay (algorithms/frames.py)


def check_frames(frames: str, num_minibatches: int) -> None:
    if frames not in FRAME_KINDS:
        raise ConfigError(f"key 'frames' is {frames!r}. Fix: use 'days' (real decisions) or 'urb' "
                          "(URB's TorchRL frames).")
    if frames == "urb" and num_minibatches > 0:
        raise ConfigError("key 'frames' is 'urb' with 'num_minibatches' > 0: URB's frames come with URB's "
                          "update count. Fix: set num_minibatches to 0, or frames to 'days'.")


@dataclass(frozen=True)
class TorchRLCommon:
    """Keys shared by URB's TorchRL configs (URB_REFERENCE §8) plus our vectorisation options."""

    agent_frames_per_batch: int = 20  # days collected per env per iteration
    n_iters: int = 200
    num_epochs: int = 2
    minibatch_size: int = 256  # samples (CAV decisions); taken as whole days
    mlp_depth: int = 4
    mlp_cells: int = 256
    lr: float = 5e-4
    gamma: float = 0.95  # only matters across days when dones are not all true (see docs)
    max_grad_norm: float = 1.0
    od_embedding_dim: int = 8  # 0 disables the OD embedding
    shared_parameters: bool = True  # URB: shared; False = one network per CAV (leading axis)
    normalize_obs: bool = True  # URB feeds raw seconds; we scale (see obs_scale)
    num_envs: int = 1
    # 0 = URB's update count (frames // minibatch_size steps per epoch, B times as many with B envs);
    # > 0 = PureJaxRL: this many Adam steps per epoch, each on 1/num_minibatches of the iteration's
    # days (minibatches grow with B instead of the step count). See update_plan.
    num_minibatches: int = 0

    RANGES: ClassVar[dict[str, Range]] = {
        "agent_frames_per_batch": between(1, 100_000), "n_iters": between(1, STEPS),
        "num_epochs": between(1, 10_000), "minibatch_size": between(1, 10_000_000),
        "mlp_depth": between(1, 64), "mlp_cells": between(1, SIZE), "lr": LR, "gamma": FRACTION,
        "max_grad_norm": above(0, 1e6), "od_embedding_dim": between(0, SIZE, "0: no OD embedding"),
        "num_envs": between(1, ENVS), "num_minibatches": between(0, 100_000, "0: URB's update count"),
    }

    def __post_init__(self) -> None:
        check_ranges(self)


@dataclass(frozen=True)
class IQLConfig(TorchRLCommon):
    memory_size: int = 20000  # samples
    eps_init: float = 1.0
    eps_end: float = 0.1
    exploration_fraction: float = 0.5
    target_eps: float = 0.99  # URB key `eps`: target <- eps*target + (1-eps)*online, once per epoch
    # "days": replay real decisions, one row per CAV per day (ours). "urb": URB's TorchRL frames,
    # one per CAV turn with every CAV's row, reward on the day's last frame only (algorithms/frames.py)
    frames: str = "days"

    RANGES: ClassVar[dict[str, Range]] = {
        **TorchRLCommon.RANGES, "memory_size": MEMORY, "eps_init": FRACTION, "eps_end": FRACTION,
        "exploration_fraction": FRACTION, "target_eps": FRACTION,
    }

    def __post_init__(self) -> None:
        check_ranges(self)
        check_frames(self.frames, self.num_minibatches)


@dataclass(frozen=True)
class PPOConfig(TorchRLCommon):
    """IPPO and MAPPO."""

    clip_epsilon: float = 0.2
    lmbda: float = 0.9
    entropy_eps: float = 1e-3
    normalize_advantage: bool = True
    critic_coef: float = 1.0
    critic_depth: int = 4
    critic_cells: int = 256
    frames: str = "days"  # as IQLConfig.frames: "urb" trains on URB's TorchRL frames (GAE across them)

    RANGES: ClassVar[dict[str, Range]] = {
        **TorchRLCommon.RANGES, "clip_epsilon": above(0, 10), "lmbda": FRACTION,
        "entropy_eps": between(0, 100),
        "critic_coef": between(0, 1e6), "critic_depth": between(1, 64), "critic_cells": between(1, SIZE),
    }

    def __post_init__(self) -> None:
        check_ranges(self)
        check_frames(self.frames, self.num_minibatches)


@dataclass(frozen=True)
class MixerConfig(TorchRLCommon):
    """QMIX and VDN."""

    memory_size: int = 30000
    tau: float = 0.01  # soft target update after every gradient step
    eps_init: float = 1.0
    eps_end: float = 0.1
    exploration_fraction: float = 0.6
    mixing_embed_dim: int = 192  # QMIX only
    hypernet_hidden: int = 0  # QMIX only: 0 = URB's single linear hypernetwork; > 0 = pymarl's two layers
    # "team" (URB): Q_tot = mixer(q) on the mean CAV reward, so a CAV's Q, and the gap between its
    # routes, is 1/C of its own travel time. "own": the mixer sees q / C, so each CAV's Q lives on
    # its own travel-time scale, which Adam resolves with hundreds of CAVs; Q_tot and the target are
    # unchanged (docs/algorithms.md, "Per-CAV Q scale").
    q_scale: str = "team"
    # Weight of a per-CAV TD term (Q_i toward the CAV's own day reward) next to the mixer's team TD:
    # with reward_credit "marginal" each CAV's Q then learns its own marginal effect, which the team
    # mean alone cannot teach it (docs/algorithms.md, "Per-CAV credit"). 0: URB's loss.
    agent_credit: float = 0.0
    frames: str = "days"  # as IQLConfig.frames

    RANGES: ClassVar[dict[str, Range]] = {
        **TorchRLCommon.RANGES, "memory_size": MEMORY, "tau": above(0, 1), "eps_init": FRACTION,
        "eps_end": FRACTION, "exploration_fraction": FRACTION, "mixing_embed_dim": between(1, SIZE),
        "hypernet_hidden": between(0, SIZE, "0: URB's single linear hypernetwork"),
        "agent_credit": between(0, 1e6, "0: URB's loss"),
    }

    def __post_init__(self) -> None:
        check_ranges(self)
        check_frames(self.frames, self.num_minibatches)
        if self.q_scale not in ("team", "own"):
            raise ConfigError(f"key 'q_scale' is {self.q_scale!r}. Fix: use 'team' (URB) or 'own'.")


@dataclass(frozen=True)
class IQLStarConfig:
    """URB scripts/iql.py: one Q network per CAV, a bandit on its own day reward."""

    num_episodes: int = 4000  # training days (per env)
    eps_init: float = 1.0
    eps_decay: float = 0.9985
    eps_min: float = 0.0
    buffer_size: int = 2048
    batch_size: int = 32
    lr: float = 1e-3
    num_epochs: int = 1
    widths: tuple[int, ...] = (64, 64)
    update_every: int = 1
    normalize_obs: bool = True
    num_envs: int = 1

    RANGES: ClassVar[dict[str, Range]] = {
        "num_episodes": between(1, STEPS), "eps_init": FRACTION, "eps_decay": FRACTION, "eps_min": FRACTION,
        "buffer_size": MEMORY, "batch_size": between(1, 10_000_000), "lr": LR,
        "num_epochs": between(1, 10_000),
        "widths": between(1, SIZE), "update_every": between(1, STEPS), "num_envs": between(1, ENVS),
    }

    def __post_init__(self) -> None:
        check_ranges(self)


@dataclass(frozen=True)
class IPPOStarConfig:
    """URB scripts/ippo.py: one policy per CAV, PPO-clip on its own (standardised) day reward."""

    num_episodes: int = 4000
    batch_size: int = 64
    update_every: int = 2
    lr: float = 3e-4
    num_epochs: int = 3
    widths: tuple[int, ...] = (64, 64)
    clip_eps: float = 0.2
    normalize_advantage: bool = True
    entropy_coef: float = 0.01
    max_grad_norm: float = 1.0
    normalize_obs: bool = True
    num_envs: int = 1

    RANGES: ClassVar[dict[str, Range]] = {
        "num_episodes": between(1, STEPS), "batch_size": between(1, 10_000_000),
        "update_every": between(1, STEPS), "lr": LR, "num_epochs": between(1, 10_000),
        "widths": between(1, SIZE), "clip_eps": above(0, 10), "entropy_coef": between(0, 100),
        "max_grad_norm": above(0, 1e6), "num_envs": between(1, ENVS),
    }

    def __post_init__(self) -> None:
        check_ranges(self)


@dataclass(frozen=True)
class BaselineConfig:
    """URB scripts/baselines.py's algo config: how many CAV days a baseline runs before testing
    (`urb-jax baseline --alg-conf`; it sets the task's training_eps)."""

    training_eps: int = 200

    RANGES: ClassVar[dict[str, Range]] = {"training_eps": between(0, 10_000_000)}

    def __post_init__(self) -> None:
        check_ranges(self)
