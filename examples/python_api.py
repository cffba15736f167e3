"""urb-jax from Python: a scenario, two SUMO days, the surrogate, a tiny training run, its metrics.

    python examples/python_api.py [RESULTS_DIR]        # about a minute on urb_grid

On purpose there is no `if __name__ == "__main__":` guard: nothing below starts a process pool
(route sampling and SUMO days run in this process; configs/hybrid/test.json has one SUMO
worker), so the script runs as plainly as it reads. tests/test_api.py runs it. docs/api.md
describes each call.
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

import urb_jax

results_dir = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="urb-jax-api-"))

# 1. The scenario: the embedded 400-agent grid, its K = 4 routes per OD pair (cached after the first build).
scn = urb_jax.load_scenario("urb_grid")
print(f"scenario {scn.name}: {scn.n_agents} agents, {scn.n_od} OD pairs, {scn.k} routes each")

# 2. Two SUMO days in this process: everyone on route 0, then everyone on its free-flow fastest route.
choices = np.stack([np.zeros(scn.n_agents, np.int32), scn.fft.argmin(axis=1).astype(np.int32)])  # [2, N]
days = urb_jax.run_days(scn, choices)
for name, day in zip(("route 0", "free-flow fastest"), days, strict=True):
    print(f"SUMO day, {name}: mean travel time {day.travel_time.mean():.3f} min")

# 3. The surrogate: calibrated on those two days, then asked about them (minutes, [2, N]).
params = urb_jax.calibrate(scn, urb_jax.SumoSample.from_days(choices, days))
predicted = np.asarray(urb_jax.predict(params, urb_jax.build_static(scn), choices))
sumo = np.stack([d.travel_time for d in days])
print(f"surrogate: mean travel time {predicted.mean():.3f} min (SUMO {sumo.mean():.3f}), "
      f"mean |error| per agent-day {np.abs(predicted - sumo).mean():.3f} min")

# 4. URB's full protocol with IQL, as small as it goes: 10 human days, 18 training days, 10 test days.
request = urb_jax.TrainRequest(alg="iql", net="urb_grid", task_conf="test", env_conf="test",
                               hybrid_conf="test", results_dir=str(results_dir), exp_id="api_example",
                               overwrite=True, progress=False)
(run,) = urb_jax.run_train(request)
print(f"run folder {run.folder} ({run.wall_time_s:.0f} s)")

# 5. Its BenchmarkMetrics row, recomputed from the run's records (what metrics/BenchmarkMetrics.csv holds).
row = urb_jax.run_metrics(run.folder)
print(f"metrics: t_pre {row['t_pre']:.3f} min, t_CAV {row['t_CAV']:.3f} min, winrate {row['winrate']:.0f}")
