"""A hybrid run's surrogate drift: the late day error it records and the warning it carries."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeExecutor

from urb_jax.reporting.drift import ERROR_COLUMN, ROUNDS_FILE, TRUSTED, drift_warning, late_day_error
from urb_jax.runs.request import TrainRequest
from urb_jax.runs.run_log import RUN_LOG
from urb_jax.runs.train import run_train


def test_late_day_error_is_the_mean_of_the_last_half_of_the_rounds():
    assert late_day_error([-0.30, -0.10, -0.20, -0.16]) == pytest.approx(-0.18)  # the last two
    assert late_day_error([0.02, math.nan, 0.04, 0.01, 0.03]) == pytest.approx(0.02)  # NaN: no SUMO days
    assert late_day_error([0.07]) == pytest.approx(0.07)
    assert late_day_error([]) is None and late_day_error([math.nan]) is None


def test_a_warning_only_beyond_the_trusted_error():
    assert drift_warning(None) is None and drift_warning(-TRUSTED) is None and drift_warning(0.01) is None
    text = drift_warning(-0.164)
    assert text is not None and "16.4% faster than SUMO measured" in text and "sumo_days_per_round" in text
    assert "slower" in (drift_warning(0.08) or "")


def test_a_hybrid_run_records_its_late_error_and_warns_in_its_run_log(tiny_iql_reference):
    folder = tiny_iql_reference[0].folder
    config = json.loads((folder / "exp_config.json").read_text())
    errors = pd.read_csv(folder / ROUNDS_FILE)[ERROR_COLUMN].tolist()
    assert config["surrogate_late_error"] == pytest.approx(late_day_error(errors))
    warning = drift_warning(config["surrogate_late_error"])
    log = (folder / RUN_LOG).read_text() if (folder / RUN_LOG).is_file() else ""
    if warning is not None:
        assert f"{folder.name}: {warning}" in log
    else:
        assert "the surrogate predicted the day" not in log


class JamsWithCavs(FakeExecutor):
    """FakeDay's days, 40% slower for everyone once CAVs drive: a network the surrogate, calibrated
    on the human days, does not follow."""

    def run_days(self, scenario, choices, seeds, is_cav=None):
        days = super().run_days(scenario, choices, seeds, is_cav)
        if is_cav is None or not np.asarray(is_cav).any():
            return days
        return [dataclasses.replace(d, travel_time=d.travel_time * 1.4, duration=d.duration * 1.4)
                for d in days]


@pytest.mark.slow
def test_a_run_whose_surrogate_misses_sumo_says_so(tiny_iql_confs, tmp_path):
    (out,) = run_train(TrainRequest(alg="iql", exp_id="jam", results_dir=str(tmp_path), progress=False,
                                    **tiny_iql_confs), executor=JamsWithCavs())
    config = json.loads((out.folder / "exp_config.json").read_text())
    assert config["surrogate_late_error"] < -TRUSTED  # the surrogate stayed faster than these days
    warning = drift_warning(config["surrogate_late_error"])
    assert warning is not None and f"jam: {warning}" in (out.folder / RUN_LOG).read_text()
