"""Progress: a bar on a terminal, plain lines elsewhere, and never silent for hours."""

from __future__ import annotations

import io

from urb_jax.core import progress as progress_module
from urb_jax.core.progress import Progress


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_plain_lines_without_a_terminal_and_rarer_ones_with_no_progress(monkeypatch):
    clock = Clock()
    monkeypatch.setattr(progress_module.time, "monotonic", clock)
    shown, quiet = io.StringIO(), io.StringIO()
    bars = [Progress(1000, True, desc="human/SUMO", stream=shown, every_s=30),
            Progress(1000, False, desc="human/SUMO", stream=quiet, every_s=30)]
    for _ in range(20):  # 20 days, one a minute
        clock.t += 60
        for bar in bars:
            bar.update(1)
    for bar in bars:
        bar.close()
    lines = shown.getvalue().splitlines()
    assert len(lines) == 21 and lines[-1] == "human/SUMO: 20/1000 day (2%), 0.0167 day/s, ETA 980:00"
    # --no-progress: a line every 5 minutes at most, none at the end (a short run prints nothing)
    assert quiet.getvalue().splitlines() == [f"human/SUMO: {d}/1000 day ({p}%), 0.0167 day/s, ETA {m}:00"
                                             for d, p, m in ((5, 0, 995), (10, 1, 990), (15, 2, 985),
                                                             (20, 2, 980))]


def test_a_line_per_round_even_with_no_progress(monkeypatch):
    clock = Clock()
    monkeypatch.setattr(progress_module.time, "monotonic", clock)
    quiet = io.StringIO()
    bar = Progress(300, False, desc="train/SUMO", stream=quiet)
    for _ in range(3):  # three 10-second rounds of 100 days: far under the 5-minute quiet interval
        clock.t += 10
        bar.update(100)
        bar.milestone()
    assert quiet.getvalue().splitlines() == [f"train/SUMO: {d}/300 day ({p}%), 10 day/s, ETA {e}"
                                             for d, p, e in ((100, 33, "0:20"), (200, 67, "0:10"),
                                                             (300, 100, "0:00"))]


def test_a_resumed_runs_rate_and_eta_are_its_own_pace(monkeypatch):
    """Days restored by a resume count as done, not as this process's speed: 600 restored days and
    100 new ones in 10 minutes is 0.167 day/s and 30 minutes left, not 1.17 day/s and 4 minutes."""
    clock = Clock()
    monkeypatch.setattr(progress_module.time, "monotonic", clock)
    quiet = io.StringIO()
    bar = Progress(1000, False, desc="train/SUMO", stream=quiet)
    bar.skip(600, "resume")
    for _ in range(10):
        clock.t += 60
        bar.update(10, "train/SUMO")
    assert bar.line() == "train/SUMO: 700/1000 day (70%), 0.167 day/s, ETA 30:00"


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_resumed_runs_bar_starts_at_the_restored_days_at_its_own_pace():
    """On a terminal: the tqdm bar shows the restored days, and its rate (tqdm's own clock, smoothed)
    counts only the days done since: 10 days in at least 0.2 s is at most 50 day/s."""
    import time

    bar = Progress(1000, True, desc="train/SUMO", stream=Terminal())
    bar.skip(600, "resume")
    time.sleep(0.2)
    bar.update(10, "train/SUMO")
    fmt = bar.bar.format_dict
    assert fmt["n"] == 610 and fmt["initial"] == 600
    assert fmt["rate"] is not None and 0 < fmt["rate"] <= 50
    bar.close()
