"""The one progress display of long work: days done, days/s and ETA.

On a terminal a tqdm bar (phase as its description, live figures as its postfix); without one
(a log file, CI, nohup) a plain line at most every `every_s` seconds and at the end, so an
overnight run's log still says how far it got. `enabled=False` (`--no-progress`) drops the bar
and keeps only a plain line at most every QUIET_EVERY_S, and one per `milestone` (each training
round): a long phase is never silent for hours.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

from tqdm.auto import tqdm

QUIET_EVERY_S = 300.0


class Progress:
    def __init__(self, total: int, enabled: bool = True, *, desc: str = "", unit: str = "day",
                 every_s: float = 30.0, stream: TextIO | None = None) -> None:
        self.total, self.unit = int(total), unit
        self.every_s = every_s if enabled else max(every_s, QUIET_EVERY_S)
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.done = 0
        self.skipped = 0  # done before this process (a resume): in the count, not in the rate
        self.phase = desc
        self.info: dict[str, str] = {}
        self.bar: Any = None
        self._t0 = time.monotonic()
        self._last_line = self._t0
        if enabled and self.stream.isatty():
            self.bar = tqdm(total=total, unit=unit, desc=desc or None, dynamic_ncols=True, smoothing=0.1,
                            file=self.stream)

    def update(self, n: int, phase: str | None = None, **info: float) -> None:
        """`n` more units done, now in `phase`; `info` shows as key=value (NaN values are dropped)."""
        self.done += n
        if phase is not None:
            self.phase = phase
        self.info.update({k: f"{v:.3g}" for k, v in info.items() if v == v})
        if self.bar is not None:
            self.bar.set_description(self.phase or None)
            self.bar.set_postfix(self.info, refresh=False)
            self.bar.update(n)
        elif time.monotonic() - self._last_line >= self.every_s:
            self._line()

    def skip(self, n: int, phase: str | None = None) -> None:
        """`n` units done before this process (restored by a resume, or a phase timed by another
        bar): counted as done, left out of the rate, so a resumed run's ETA is its own pace's."""
        self.done += n
        self.skipped += n
        if phase is not None:
            self.phase = phase
        if self.bar is not None:
            self.bar.n += n
            self.bar.initial += n  # tqdm's rate: (n - initial) / elapsed
            self.bar.last_print_n = self.bar.n  # and its smoothed rate: dn since the last print
            self.bar.set_description(self.phase or None)
            self.bar.refresh()

    def milestone(self) -> None:
        """The end of a unit of work worth a line of its own (a training round): printed as a plain
        line whenever there is no bar, `--no-progress` included, so a long run's log says where it
        is at every round however long the round takes."""
        if self.bar is None:
            self._line()

    def note(self, text: str) -> None:
        """A line of its own (an estimate, a warning), above the bar when there is one; printed with
        or without `--no-progress`."""
        if self.bar is not None:
            self.bar.write(text, file=self.stream)
        else:
            print(text, file=self.stream, flush=True)

    def line(self) -> str:
        """'phase: done/total day (pct), rate day/s, ETA m:ss, key=value ...'."""
        dt = max(time.monotonic() - self._t0, 1e-9)
        rate = (self.done - self.skipped) / dt
        eta = (self.total - self.done) / rate if rate > 0 else float("nan")
        pct = 100.0 * self.done / max(self.total, 1)
        eta_s = f"{int(eta // 60)}:{int(eta % 60):02d}" if eta == eta else "?"
        extra = "".join(f", {k}={v}" for k, v in self.info.items())
        head = f"{self.phase}: " if self.phase else ""
        return (f"{head}{self.done}/{self.total} {self.unit} ({pct:.0f}%), {rate:.3g} {self.unit}/s, "
                f"ETA {eta_s}{extra}")

    def _line(self) -> None:
        self._last_line = time.monotonic()
        print(self.line(), file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        elif self.enabled and self.done:
            self._line()
        self.enabled = False
