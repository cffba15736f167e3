"""urb-jax: a JAX-native surrogate-plus-SUMO hybrid trainer for the Urban Routing Benchmark.

The entry points a script needs (docs/api.md):

    import urb_jax
    scn = urb_jax.load_scenario("urb_grid")                       # city: routes, agents (cached)
    days = urb_jax.run_days(scn, choices)                          # SUMO days [B, N], this process
    params = urb_jax.calibrate(scn, urb_jax.SumoSample.from_days(choices, days))
    times = urb_jax.predict(params, urb_jax.build_static(scn), choices)  # surrogate, minutes
    (run,) = urb_jax.run_train(urb_jax.TrainRequest(task_conf="test"))  # URB's full protocol
    row = urb_jax.run_metrics(run.folder)                          # the BenchmarkMetrics row

They load on first use (module `__getattr__`), so `import urb_jax` imports neither JAX nor SUMO;
it does set XLA's deterministic-GPU flag in XLA_FLAGS (urb_jax.core.determinism).
No room imports this module (`__version__` lives in urb_jax.core.version): the façade sits above
every layer of the import contract.
"""

from __future__ import annotations

import importlib

from urb_jax.core import determinism as _determinism
from urb_jax.core.version import __version__

_determinism.deterministic_gpu()  # before JAX computes: the same seeds give the same bytes on a GPU

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (mypy and pyright know the name)

# name -> the module that defines it (one implementation each; this file only points at them)
_EXPORTS = {
    "load_scenario": "urb_jax.city.scenario",
    "Scenario": "urb_jax.city.scenario",
    "RouteParams": "urb_jax.city.routes",
    "run_day": "urb_jax.sumo_bridge.sim",
    "run_days": "urb_jax.sumo_bridge.sim",
    "DayResult": "urb_jax.sumo_bridge.types",
    "SumoSample": "urb_jax.surrogate.calibrate",
    "calibrate": "urb_jax.surrogate.calibrate",
    "build_static": "urb_jax.surrogate.model",
    "predict": "urb_jax.surrogate.model",
    "TrainRequest": "urb_jax.runs.request",
    "ResumeRequest": "urb_jax.runs.request",
    "BaselineRequest": "urb_jax.runs.request",
    "run_train": "urb_jax.runs.train",
    "resume_train": "urb_jax.runs.train",
    "run_baseline": "urb_jax.runs.baseline",
    "RunResult": "urb_jax.runs.setup",
    "read_records": "urb_jax.reporting.records",
    "run_metrics": "urb_jax.reporting.records",
    "compute_metrics": "urb_jax.reporting.metrics",
}

__all__ = [  # the same names as _EXPORTS (tests/test_api.py), spelled out for linters and editors
    "BaselineRequest", "DayResult", "ResumeRequest", "RouteParams", "RunResult", "Scenario", "SumoSample",
    "TrainRequest", "__version__", "build_static",
    "calibrate", "compute_metrics", "load_scenario", "predict", "read_records", "resume_train",
    "run_baseline", "run_day", "run_days", "run_metrics", "run_train",
]

if TYPE_CHECKING:  # what type checkers and editors see; at run time __getattr__ loads these
    from typing import Any

    from urb_jax.city.routes import RouteParams
    from urb_jax.city.scenario import Scenario, load_scenario
    from urb_jax.reporting.metrics import compute_metrics
    from urb_jax.reporting.records import read_records, run_metrics
    from urb_jax.runs.baseline import run_baseline
    from urb_jax.runs.request import BaselineRequest, ResumeRequest, TrainRequest
    from urb_jax.runs.setup import RunResult
    from urb_jax.runs.train import resume_train, run_train
    from urb_jax.sumo_bridge.sim import run_day, run_days
    from urb_jax.sumo_bridge.types import DayResult
    from urb_jax.surrogate.calibrate import SumoSample, calibrate
    from urb_jax.surrogate.model import build_static, predict


def __getattr__(name: str) -> Any:
    """An exported name, imported from its module on first use and kept."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'urb_jax' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
