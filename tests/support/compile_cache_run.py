"""A tiny hybrid run on urb_grid with FakeDay for SUMO, in its own process (tests/test_compile.py
runs it twice on one compile cache): `PYTHONPATH=tests python -m support.compile_cache_run OUT_DIR`.
Writes OUT_DIR/compiles.json: the programs that asked the persistent cache and those it answered."""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import jax

from support.fakeday import FakeExecutor
from urb_jax.runs.request import TrainRequest
from urb_jax.runs.train import run_train

HYBRID = {"train_days": 12, "num_envs": 2, "surrogate_days_per_round": 4, "sumo_days_per_round": 2,
          "sumo_updates": 1, "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2,
          "calib_steps": 20, "refit_days": 4, "refit_steps": 5}
IQL = {"agent_frames_per_batch": 2, "n_iters": 10, "num_epochs": 1, "minibatch_size": 64,
       "mlp_depth": 1, "mlp_cells": 16, "memory_size": 400}


REQUESTS = "/jax/compilation_cache/compile_requests_use_cache"
HITS = "/jax/compilation_cache/cache_hits"


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    events: Counter = Counter()
    jax.monitoring.register_event_listener(lambda event, **_: events.update([event]))
    (out / "hyb.json").write_text(json.dumps(HYBRID))
    (out / "iql.json").write_text(json.dumps(IQL))
    run_train(TrainRequest(alg="iql", exp_id="run", results_dir=str(out), progress=False, task_conf="test",
                           hybrid_conf=str(out / "hyb.json"),
                           alg_conf=str(out / "iql.json")), executor=FakeExecutor())
    (out / "compiles.json").write_text(json.dumps({"requests": events[REQUESTS], "hits": events[HITS]}))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
