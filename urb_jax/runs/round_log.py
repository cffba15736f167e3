"""Optional live logging of a train run's rounds: `urb-jax train --log tensorboard`.

Each seed's results/<id>/tensorboard/ gets, per round (step = rounds.csv's `round`), one scalar
`rounds/<column>` for every other rounds.csv column: the surrogate and SUMO means, the learner's
losses, the surrogate's error, the legs' wall times. The writer is tensorboardX (the extra
`urb-jax[tensorboard]`): a TensorBoard event writer without TensorFlow or PyTorch that needs only
numpy and protobuf; the run does not import it unless asked. A resumed run writes every restored
round again after a purge marker (`purge_step=1`), so TensorBoard shows each round once, with
the values rounds.csv ends with, however often the run was killed.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from urb_jax.core.choices import LOGGERS
from urb_jax.core.errors import UrbJaxError

TENSORBOARD_DIR = "tensorboard"
RoundRows = Callable[[list[dict[str, float]]], None]  # one rounds.csv row per seed


def check_logger(log: str | None) -> None:
    """Refuse, before any folder or SUMO day, a logger that cannot run (its extra is missing)."""
    if log is None:
        return
    if log not in LOGGERS:
        raise UrbJaxError(f"--log {log!r}: unknown logger. Fix: use one of {', '.join(LOGGERS)}.")
    _summary_writer()


def _summary_writer() -> type:
    try:
        from tensorboardX import SummaryWriter
    except ImportError:
        raise UrbJaxError("--log tensorboard needs the optional extra 'tensorboard' (the tensorboardX "
                          "writer), which is not installed. Fix: pip install 'urb-jax[tensorboard]', or "
                          "drop --log tensorboard.") from None
    return SummaryWriter


@contextlib.contextmanager
def round_log(folders: list[Path], log: str | None, resumed: bool) -> Iterator[RoundRows | None]:
    """The `on_round` of a seed group (None without a logger); writers closed on exit."""
    if log is None:
        yield None
        return
    check_logger(log)
    writer_class = _summary_writer()
    writers: list[Any] = [writer_class(str(f / TENSORBOARD_DIR), purge_step=1 if resumed else None)
                          for f in folders]

    def on_round(rows: list[dict[str, float]]) -> None:
        for writer, row in zip(writers, rows, strict=True):
            step = int(row["round"])
            for key, value in row.items():
                if key != "round":
                    writer.add_scalar(f"rounds/{key}", float(value), step)
            writer.flush()  # live: TensorBoard shows a round as soon as it is checkpointed

    try:
        yield on_round
    finally:
        for writer in writers:
            writer.close()
