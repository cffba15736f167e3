"""The surrogate leg's clock: how long a round and the whole training will take, said early.

A URB config whose update count grows with the data (the TorchRL family's config1 for QMIX on a
mid-size network) can spend many minutes on one round of jitted `lax.scan`, where Python cannot
print. So a round runs as equal chunks of one compiled scan (`run_chunks`), compiled before the
clock starts, and `IterationClock` is told from the host as each chunk starts: after the first
chunk of the first round the run says what the training will cost on this machine, and a long
round still prints a line every few minutes. The clock used to be a host callback inside the
scan; JAX's persistent compilation cache does not store a program with a callback, so every run
and every `--resume` compiled the round again.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any, cast

import jax
import numpy as np

from urb_jax.algorithms.learner import Learner
from urb_jax.training.hybrid.memory import check_program_fits, tree_size

LINE_EVERY_S = 300.0
SLOW_S = 3600.0  # a surrogate training estimated longer than this gets the --alg-conf hybrid hint
# A learner with more parameters than this is timed on one environment before training, so the
# estimate comes in a minute or two, not after a first iteration that can take 20 minutes (URB's
# QMIX config1: the mixer's hypernetwork grows as CAVs squared, 7.4 M parameters on saint_arnoult's
# 88 CAVs, about 80 M on nemours' 291).
PROBE_PARAMS = 10_000_000


def fmt_duration(seconds: float) -> str:
    """'42 s', '12.5 min' or '3.2 h'."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h"


class IterationClock:
    """Called with the iteration index i as each chunk of a round's iterations starts, and with the
    round's iteration count when it ends (a repeated index is ignored). `n_iters` a full round's
    iterations; `last_iters` the last round's (a budget that is not whole rounds), default n_iters."""

    def __init__(self, n_iters: int, n_rounds: int, hint: str = "",
                 note: Callable[[str], None] = print, clock: Callable[[], float] = time.monotonic,
                 last_iters: int | None = None) -> None:
        self.n_iters, self.n_rounds, self.hint = n_iters, n_rounds, hint
        self.last_iters = n_iters if last_iters is None else last_iters
        self.note, self.clock = note, clock
        self.round = 0
        self.estimated = False
        self._seen, self._t0, self._last = -1, 0.0, 0.0

    def start_round(self, r: int) -> None:
        self.round, self._seen = r, -1

    def iters_of(self, r: int) -> int:
        """Round r's iterations (the last round's may be fewer)."""
        return self.last_iters if r == self.n_rounds - 1 else self.n_iters

    def iters_left(self) -> int:
        """The iterations of this round and the rounds after it."""
        return sum(self.iters_of(r) for r in range(self.round, self.n_rounds))

    def __call__(self, i: int) -> None:
        if i <= self._seen:
            return
        self._seen, now = i, self.clock()
        if i == 0:
            self._t0 = self._last = now
            return
        per_iter = (now - self._t0) / i
        if not self.estimated:
            self.estimated = True
            self.note(self.estimate(per_iter))
        elif now - self._last >= LINE_EVERY_S and i < (n := self.iters_of(self.round)):
            self._last = now
            left = fmt_duration(per_iter * (n - i))
            self.note(f"round {self.round + 1}/{self.n_rounds}: surrogate iteration {i}/{n}, "
                      f"{fmt_duration(per_iter)} each, round ETA {left}")

    def before_training(self, per_iter: float, envs: int) -> None:
        """The estimate from a probe: one environment's iteration timed, times the `envs`
        environments (seeds x envs) of a real iteration."""
        self.note(self.estimate(per_iter, head=f"estimate before training (one environment's iteration "
                                                f"timed here, times the {envs} of an iteration)"))

    def estimate(self, per_iter: float, head: str = "estimate") -> str:
        """The surrogate training's cost on this machine, from one measured iteration."""
        rounds_left = self.n_rounds - self.round
        total = per_iter * self.iters_left()
        text = (f"{head}: one surrogate iteration takes {fmt_duration(per_iter)} here, so a round's "
                f"{self.n_iters} iterations take about {fmt_duration(per_iter * self.n_iters)} and the "
                f"{rounds_left} round(s) left about {fmt_duration(total)} (plus their SUMO days)")
        if total > SLOW_S and self.hint:
            text += f". {self.hint}"
        return text


def needs_probe(params: Any) -> bool:
    """Whether a learner with these parameters (arrays or shapes) is big enough to time first."""
    return tree_size(params) > PROBE_PARAMS


def probe_seconds(learner: Learner, key: jax.Array) -> float:
    """Seconds one iteration of `learner` (built for one environment) takes here; the compilation
    is not timed. Its own runner and key: the training's state and keys are untouched."""
    runner = jax.jit(learner.init)(key)
    step = jax.jit(learner.iteration).lower(runner, key).compile()
    t0 = time.perf_counter()
    jax.block_until_ready(step(runner, key))
    return time.perf_counter() - t0


CHUNKS = 8  # a round runs as at least this many chunks where its iteration count allows


def chunk_len(n_iters: int, chunks: int = CHUNKS) -> int:
    """The longest chunk that cuts a round's `n_iters` iterations into at least `chunks` equal
    parts: every chunk of every round is then one compiled program."""
    cap = max(1, n_iters // chunks)
    return max(d for d in range(1, cap + 1) if n_iters % d == 0)


def leg_chunk_len(n_iters: int, round_iters: int, last_iters: int) -> int:
    """The chunk length of a leg of `n_iters` in a plan of full rounds of `round_iters` iterations and
    a last round of `last_iters`: where one length cuts both into equal chunks without more than
    halving the full rounds' (`chunk_len`), that one, so one compiled program serves the short last
    round too (a cold run compiles the round once); otherwise each leg's own `chunk_len`."""
    full = chunk_len(round_iters) if round_iters else 1
    common = math.gcd(round_iters, last_iters) if last_iters else full  # what divides both legs
    shared = max(d for d in range(1, full + 1) if common % d == 0)
    if 2 * shared >= full and n_iters % shared == 0:
        return shared
    return chunk_len(n_iters)


Carry = tuple[Any, ...]


def run_chunks(fn: Callable[..., tuple[Any, ...]], carry: Carry, keys: jax.Array, clock: IterationClock,
               programs: dict[Any, Any], chunk: int | None = None) -> tuple[Carry, dict[str, np.ndarray]]:
    """`fn(*carry, keys[:, chunk]) -> (*carry, metrics)` over the iterations' keys [S, n, 2] in equal
    chunks of `chunk` iterations (default `chunk_len(n)`; it must divide n), the clock told as each
    chunk starts and when the last ends. The chunk program is compiled ahead (`programs` keeps it,
    keyed by fn and argument types), so the clock times the iterations, not the compilation.
    Returns the carry and the metrics [S, n, ...] as numpy."""
    n = keys.shape[1]
    L = chunk or chunk_len(n)
    if n % L:
        raise ValueError(f"a chunk of {L} iterations does not divide the leg's {n}")
    parts: list[dict[str, Any]] = []
    for start in range(0, n, L):
        part = keys[:, start:start + L]
        program = _compiled(fn, (*carry, part), programs)
        clock(start)
        *out, metrics = program(*carry, part)
        carry = tuple(jax.block_until_ready(out))
        parts.append(metrics)
    clock(n)
    return carry, {k: np.concatenate([np.asarray(p[k]) for p in parts], axis=1) for k in parts[0]}


def _compiled(fn: Callable[..., Any], args: tuple[Any, ...], programs: dict[Any, Any]) -> Any:
    """fn's compiled program for `args`' shapes and types, compiled (or read from JAX's persistent
    cache) the first time."""
    sig = (id(fn), jax.tree_util.tree_structure(args),
           tuple((x.shape, x.dtype, getattr(x, "weak_type", False)) for x in jax.tree_util.tree_leaves(args)))
    if sig not in programs:
        program = cast(Any, fn).lower(*args).compile()  # fn: a jax.jit function (has .lower)
        check_program_fits(program, "a round's surrogate iterations")
        programs[sig] = program
    return programs[sig]
