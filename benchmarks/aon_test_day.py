"""Usage: python benchmarks/aon_test_day.py RESULTS_FOLDER NET [NETWORKS_DIR]

AON's t_CAV on a finished run's test humans: humans are deterministic and do not adapt, so every
test day has the same human choices; put the CAVs on their minimum free-flow route, one SUMO day."""
import sys

import numpy as np

from sumo_bridge import run_day
from urb_jax.config import load_env_config
from urb_jax.results import read_records
from urb_jax.scenario import load_scenario

folder, net = sys.argv[1], sys.argv[2]
env, _ = load_env_config("config1")
nets = sys.argv[3] if len(sys.argv) > 3 else None
scn = load_scenario(net, networks_dir=nets, env_seed=42, route_params=env.route_params())
rec = read_records(folder)
last = rec[rec["day"] == rec["day"].max()].set_index("agent").loc[scn.agent_id]
choices = last["action"].to_numpy().astype(np.int64)
is_cav = (last["kind"] == "CAV").to_numpy()
test = rec[rec["phase"] == "test"]
wide = test.pivot(index="day", columns="agent", values="action")
print("distinct test-day joint actions:", wide.drop_duplicates().shape[0])
aon = np.argmin(np.where(scn.route_valid, scn.fft, np.inf), axis=1)
ch = np.where(is_cav, aon, choices)
res = run_day(scn, ch, seed=42, is_cav=is_cav)
print(f"AON t_CAV {res.travel_time[is_cav].mean():.4f}  t_HDV {res.travel_time[~is_cav].mean():.4f}")
res2 = run_day(scn, choices, seed=42, is_cav=is_cav)
print(f"policy t_CAV {res2.travel_time[is_cav].mean():.4f} (one day replayed)")
