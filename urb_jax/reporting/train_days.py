"""How many training days a run actually trained, where, and whether that is more than it asked.

A hybrid run's rows on the paper page compare a number of days with the paper's (6,000 training
days, all in SUMO), so each row says what it trained: its SUMO and surrogate training days
(exp_config.json's `sumo_training_days` and `surrogate_training_days`, kept in the ledger) and the
days it asked for (`train_args.train_days`; the ledger's provenance request). Runs made with whole
rounds trained more than asked (the budget rounded up to whole rounds: 6,000 asked, 10 rounds of
640 surrogate + 4 SUMO days, 6,440 trained); their rows carry ROUND_UP_MARK, which LEGEND explains.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import pandas as pd

from urb_jax.reporting.comparable import DAYS_COLUMNS

ASKED = "train_days_asked"  # a run's row: the training days it asked for (exp_config.json's train_args)
ROUND_UP_MARK = "†"
LEGEND = (f"Training days: SUMO + surrogate = trained (asked). {ROUND_UP_MARK} trained more days than asked: "
          "the run's budget was rounded up to whole rounds (e.g. 6,000 asked, 10 rounds of 640 surrogate "
          "+ 4 SUMO days = 6,440 trained); its numbers are for the longer training. \"not recorded\": "
          "a ledger row kept before the days were.")


@dataclass(frozen=True)
class TrainDays:
    """One run's training days: in SUMO, on the surrogate, and asked for (None: not recorded)."""

    sumo: int
    surrogate: int
    asked: int | None

    @property
    def total(self) -> int:
        return self.sumo + self.surrogate

    @property
    def rounded_up(self) -> bool:
        """Trained more than asked: the budget was rounded up to whole rounds."""
        return self.asked is not None and self.total > self.asked

    def text(self) -> str:
        """'40 SUMO + 6,400 surrogate = 6,440 (6,000 asked) †'."""
        asked = "asked not recorded" if self.asked is None else f"{self.asked:,} asked"
        mark = f" {ROUND_UP_MARK}" if self.rounded_up else ""
        return f"{self.sumo:,} SUMO + {self.surrogate:,} surrogate = {self.total:,} ({asked}){mark}"


def _int(value: Any) -> int | None:
    if value is None or isinstance(value, str):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(number) else int(number)


def asked_days(row: dict[str, Any]) -> int | None:
    """The training days a run asked for: its row's ASKED, else its provenance's request (ledger
    rows kept before ASKED was)."""
    asked = _int(row.get(ASKED))
    if asked is not None:
        return asked
    prov = row.get("provenance")
    request = prov.get("request") if isinstance(prov, dict) else None
    return _int(request.get("train_days")) if isinstance(request, dict) else None


def train_days_of(row: dict[str, Any]) -> TrainDays | None:
    """A run row's TrainDays; None where its SUMO or surrogate days are not recorded (a baseline, or
    a ledger row kept before they were)."""
    sumo, surrogate = (_int(row.get(c)) for c in DAYS_COLUMNS)
    if sumo is None or surrogate is None:
        return None
    return TrainDays(sumo, surrogate, asked_days(row))


def days_cell(rows: pd.DataFrame) -> str:
    """A table row's training days over its seeds: one text where the seeds agree, each distinct
    one (with its seed count) where they do not; 'not recorded' where no seed has them; a
    baseline's row says it trains nothing."""
    records = rows.to_dict("records")
    if records and all(str(r.get("alg") or "").startswith("baseline_") for r in records):
        return "none (a baseline: no training)"
    found = [train_days_of(r) for r in records]
    known = [d for d in found if d is not None]
    if not known:
        return "not recorded"
    distinct = list(dict.fromkeys(known))
    missing = len(found) - len(known)
    if len(distinct) == 1 and not missing:
        return distinct[0].text()
    parts = [f"{d.text()} ({known.count(d)} seeds)" for d in distinct]
    return "; ".join(parts + ([f"not recorded ({missing} seeds)"] if missing else []))
