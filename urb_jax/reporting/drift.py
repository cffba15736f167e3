"""How far the surrogate was from SUMO on a hybrid run's own late SUMO days.

Every SUMO day of a hybrid round is first predicted by the surrogate the policies have just trained
on (rounds.csv `surrogate_mean_error`: the predicted day mean minus SUMO's, as a share of SUMO's).
On the networks that flow it ends within 1%; where SUMO's days jam it can stay 10-19% low round
after round (gargenville, docs/nine_networks), and then the policies learned on a model that does
not follow the network: the run's result rests on its few SUMO days more than on its thousands of
surrogate days. Such a run says so (exp_config.json, the run's summary, suite reports) instead of
passing for a well-trained one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

ROUNDS_FILE = "rounds.csv"  # a hybrid run's per-round log (urb_jax.runs.folder.write_rounds)
ERROR_COLUMN = "surrogate_mean_error"  # its column of the day error, per round with SUMO days
TRUSTED = 0.05  # beyond this late day error (either sign) a run is flagged


def late_day_error(errors: Sequence[float]) -> float | None:
    """The mean of the last half of a run's per-round day errors (rounds without SUMO days, NaN,
    left out; at least the last one); None where no round had SUMO days."""
    known = [float(e) for e in errors if e is not None and not math.isnan(float(e))]
    if not known:
        return None
    late = known[len(known) // 2:]
    return sum(late) / len(late)


def drift_warning(error: float | None) -> str | None:
    """The warning a run whose late day error is beyond TRUSTED carries; None otherwise."""
    if error is None or abs(error) <= TRUSTED:
        return None
    side = "faster" if error < 0 else "slower"
    return (f"on this run's late SUMO training days the surrogate predicted the day {abs(error):.1%} {side} "
            f"than SUMO measured (rounds.csv {ERROR_COLUMN}; within {TRUSTED:.0%} on networks that flow): "
            "the policies trained on a model that does not follow this network, so the result rests on "
            "the SUMO days. More SUMO days a round (--set hybrid.sumo_days_per_round=16) or --mode sumo "
            "train on what SUMO does.")
