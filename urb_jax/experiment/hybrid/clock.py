"""The surrogate leg's clock: how long a round and the whole training will take, said early.

A URB config whose update count grows with the data (the TorchRL family's config1 for QMIX on a
mid-size network) can spend many minutes on one round, all inside one jitted `lax.scan`, where
Python cannot print. The scan calls `IterationClock` (a host callback that reads only the
iteration index) as each iteration starts, so after the first iteration of the first round the
run says what the training will cost on this machine, and a long round still prints a line every
few minutes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

LINE_EVERY_S = 300.0
SLOW_S = 3600.0  # a surrogate training estimated longer than this gets the --alg-conf hybrid hint


def fmt_duration(seconds: float) -> str:
    """'42 s', '12.5 min' or '3.2 h'."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h"


class IterationClock:
    """Called with the iteration index i as each iteration of a round's scan starts (once per seed
    under vmap: repeats of an index are ignored)."""

    def __init__(self, n_iters: int, n_rounds: int, hint: str = "",
                 note: Callable[[str], None] = print, clock: Callable[[], float] = time.monotonic) -> None:
        self.n_iters, self.n_rounds, self.hint = n_iters, n_rounds, hint
        self.note, self.clock = note, clock
        self.round = 0
        self.estimated = False
        self._seen, self._t0, self._last = -1, 0.0, 0.0

    def start_round(self, r: int) -> None:
        self.round, self._seen = r, -1

    def __call__(self, i: Any) -> None:
        i = int(np.asarray(i).reshape(-1)[0])
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
        elif now - self._last >= LINE_EVERY_S:
            self._last = now
            left = fmt_duration(per_iter * (self.n_iters - i))
            self.note(f"round {self.round + 1}/{self.n_rounds}: surrogate iteration {i}/{self.n_iters}, "
                      f"{fmt_duration(per_iter)} each, round ETA {left}")

    def estimate(self, per_iter: float) -> str:
        """The surrogate training's cost on this machine, from one measured iteration."""
        rounds_left = self.n_rounds - self.round
        total = per_iter * self.n_iters * rounds_left
        text = (f"estimate: one surrogate iteration takes {fmt_duration(per_iter)} here, so a round's "
                f"{self.n_iters} iterations take about {fmt_duration(per_iter * self.n_iters)} and the "
                f"{rounds_left} round(s) left about {fmt_duration(total)} (plus their SUMO days)")
        if total > SLOW_S and self.hint:
            text += f". {self.hint}"
        return text
