"""The hybrid trainer end to end on whatever backend JAX has (made for a lent GPU, which has no SUMO):
the SUMO days come from tests/support/fakeday.py's deterministic stand-in, everything else is the real
trainer (surrogate calibration, rounds, updates, checkpoints, records, metrics).

Checks, each printed as a row:
  same run twice         the tiny IQL run (task `test`) twice: records and metric files byte-identical
  killed and resumed     the same run stopped after round 1, resumed: byte-identical to the first
  big learner's seeds    URB's QMIX config1 on urb_grid at 40% CAVs (above fns.MAP_SEEDS_PARAMS), seeds
                         0,1 together: which seed axis `auto` chose here (the memory line is logged)

    python benchmarks/gpu_hybrid_check.py OUT_DIR
    python benchmarks/gpu_hybrid_check.py OUT_DIR --qmix-twice   # the big learner's run twice, alone
    XLA_FLAGS=--xla_gpu_deterministic_ops=true python benchmarks/gpu_hybrid_check.py OUT_DIR
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support import compile_cache_run
from support.compile_cache_run import IQL
from support.fakeday import FakeExecutor

from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.train import resume_train, run_train

HYBRID = {**compile_cache_run.HYBRID, "train_days": 18}  # 3 rounds


def digest(folder: Path) -> str:
    """sha256 over records.parquet and metrics/*.csv, the files a refactor must leave unchanged."""
    h = hashlib.sha256()
    for f in [folder / "records.parquet", *sorted((folder / "metrics").glob("*.csv"))]:
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def train(out: Path, exp_id: str, alg: str, alg_conf: str, seeds: list[int], overrides: tuple[str, ...] = (),
          stop_after_round: int | None = None):
    t0 = time.perf_counter()
    req = TrainRequest(alg=alg, exp_id=exp_id, results_dir=str(out), progress=False, task_conf="test",
                       hybrid_conf=str(out / "hyb.json"), alg_conf=alg_conf, seeds=tuple(seeds),
                       overrides=overrides)
    results = run_train(req, executor=FakeExecutor(), stop_after_round=stop_after_round)
    return results, time.perf_counter() - t0


def qmix_twice(out: Path) -> None:
    """The big learner's run twice: its seeds' records and metric files, byte-identical or not."""
    digests = []
    for exp_id in ("q1", "q2"):
        results, wall = train(out, exp_id, "qmix", "config1", [0, 1], overrides=("task.ratio_machines=0.4",))
        digests.append([digest(r.folder) for r in results])
        print(exp_id, digests[-1], f"{wall:.0f} s", flush=True)
    print("QMIX run twice byte-identical: " + ("yes" if digests[0] == digests[1] else "NO"))


def main(out: Path, only_qmix: bool = False) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "hyb.json").write_text(json.dumps(HYBRID))
    (out / "iql.json").write_text(json.dumps(IQL))
    iql = str(out / "iql.json")
    print(f"jax {jax.__version__} on {jax.default_backend()} ({jax.devices()[0].device_kind})", flush=True)
    if only_qmix:
        return qmix_twice(out)
    rows = []
    (a,), wall_a = train(out, "a", "iql", iql, [0])
    (b,), wall_b = train(out, "b", "iql", iql, [0])
    rows.append(("same run twice", digest(a.folder), digest(b.folder), f"{wall_a:.0f} s, {wall_b:.0f} s"))
    print(rows[-1], flush=True)
    train(out, "k", "iql", iql, [0], stop_after_round=1)
    t0 = time.perf_counter()
    (k,) = resume_train(ResumeRequest("k", results_dir=str(out), progress=False), executor=FakeExecutor())
    resume_s = time.perf_counter() - t0
    rows.append(("killed and resumed", digest(a.folder), digest(k.folder), f"resume {resume_s:.0f} s"))
    print(rows[-1], flush=True)
    qmix, wall_q = train(out, "q", "qmix", "config1", [0, 1], overrides=("task.ratio_machines=0.4",))
    used = json.loads((qmix[0].folder / "exp_config.json").read_text())["seed_axis_used"]
    rows.append(("big learner's seeds", f"seed_axis_used {used}", digest(qmix[1].folder), f"{wall_q:.0f} s"))
    print("| check | first | second | wall |\n|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    same = rows[0][1] == rows[0][2] and rows[1][1] == rows[1][2]
    print("byte-identical: " + ("yes" if same else "NO"))


if __name__ == "__main__":
    main(Path(sys.argv[1]), only_qmix="--qmix-twice" in sys.argv[2:])
