"""Peak resident memory of a hybrid training against the learner state it holds: fresh, and resumed.

The memory check (urb_jax.training.hybrid.memory) refuses a run whose learner state x seeds x
PEAK_OVER_STATE does not fit in the memory available. This measures what that factor is on a real
run: `urb-jax train` as a child in a scratch folder, killed (SIGKILL) once its first round is
checkpointed, then `--resume`d to the end. The child's resident set is sampled every 0.1 s (its
SUMO runs in-process here, sumo_workers 1: small on these networks; unlike synthetic_scale.rss_mib,
no child processes are summed), and each part's peak is set against the learner state the run
prints ("memory: the learner's state is ...", big learners only: QMIX config1 on a network with
a hundred CAVs or more).

    python benchmarks/learner_memory.py --networks-dir ../shared/networks
    python benchmarks/learner_memory.py --net provins --task-conf config1 --seeds 0 --networks-dir DIR
    python benchmarks/learner_memory.py --networks-dir DIR --set hybrid.seed_axis=vmap

Columns:
  state GB       learner state of all seeds (params, target, optimizer moments, buffer, envs)
  RSS before GB  resident set when the run printed its memory line (after setup, before the state)
  peak GB        the part's peak resident set
  (peak-before)/state   what the state costs at its peak: the check's PEAK_OVER_STATE must cover it
  check GB       what the memory check counted (state a seed x PEAK_OVER_STATE x seeds)
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

GB = 1024**3
NOTE = re.compile(r"memory: the learner's state is ([\d.]+) GB a seed, ([\d.]+) GB for (\d+) seed\(s\); "
                  r"about ([\d.]+) GB at the peak")


def rss_bytes(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def watch(cmd: list[str], kill_when: Path | None) -> dict[str, float]:
    """Run `cmd`, sampling its resident set; SIGKILL it once `kill_when` exists. Returns the peak,
    the resident set when the memory line was printed, the line's numbers and the exit code."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    events: list[tuple[float, int, str]] = []  # (time, resident set, the line printed then)
    marks: dict[str, float] = {}

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            events.append((time.monotonic(), rss_bytes(proc.pid), line.strip()[:60]))
            m = NOTE.search(line)
            if m:
                marks.update({"rss_before": rss_bytes(proc.pid) / GB, "state_seed": float(m[1]),
                              "state": float(m[2]), "seeds": int(m[3]), "check": float(m[4])})
            print("   |", line.rstrip()[:160], flush=True)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    peak, t_peak = 0, 0.0
    while proc.poll() is None:
        now = rss_bytes(proc.pid)
        if now > peak:
            peak, t_peak = now, time.monotonic()
        if kill_when is not None and kill_when.exists():
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.1)
    proc.wait()
    reader.join(timeout=10)
    if "state" not in marks:
        sys.exit("the run printed no memory line (a small learner has none): " + "".join(lines[-20:]))
    before = [e for e in events if e[0] <= t_peak]
    after = [e for e in events if e[0] > t_peak]
    where = f"after '{before[-1][2]}' (+{t_peak - before[-1][0]:.1f} s)" if before else "before any line"
    where += f", before '{after[0][2]}'" if after else ""
    return {**marks, "peak": peak / GB, "rc": proc.returncode, "where": where}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--net", default="saint_arnoult")
    parser.add_argument("--task-conf", default="scenario2_cooperative")
    parser.add_argument("--alg", default="qmix")
    parser.add_argument("--alg-conf", default="config1")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--networks-dir", default=None)
    parser.add_argument("--human-days", type=int, default=20, help="human learning days (SUMO)")
    parser.add_argument("--out", default=None, help="results folder (default: a temporary one)")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="passed to urb-jax train (e.g. hybrid.seed_axis=vmap)")
    args = parser.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix="learner_memory_"))
    out.mkdir(parents=True, exist_ok=True)
    hybrid = {"train_days": 3 * (2 * 20 + 2), "num_envs": 2, "surrogate_days_per_round": 80,
              "sumo_days_per_round": 2, "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2,
              "calib_steps": 20, "refit_days": 4, "refit_steps": 5}
    (out / "hybrid.json").write_text(json.dumps(hybrid))
    base = [sys.executable, "-m", "urb_jax.commands.cli", "train", "--results-dir", str(out), "--no-progress"]
    run = ["--alg", args.alg, "--alg-conf", args.alg_conf, "--net", args.net, "--task-conf", args.task_conf,
           "--hybrid-conf", str(out / "hybrid.json"), "--seeds", args.seeds, "--id", "mem",
           "--set", f"task.human_learning_episodes={args.human_days}", "--set", "task.test_eps=2",
           *[x for item in args.set for x in ("--set", item)]]
    first_id = f"mem_s{args.seeds.split(',')[0]}" if "," in args.seeds else "mem"  # train_run_names
    first = out / first_id
    print(f"load average {os.getloadavg()[0]:.1f}; results in {out}")
    dirs = ["--networks-dir", args.networks_dir] if args.networks_dir else []
    fresh = watch(base + run + dirs, kill_when=first / "checkpoints" / "round_00001" / "meta.json")
    resumed = watch([*base, "--resume", first_id, *dirs], kill_when=None)
    print(f"\n{args.alg} {args.alg_conf} on {args.net} ({args.task_conf}), seeds {args.seeds} "
          f"{' '.join(args.set)}; "
          f"load average {os.getloadavg()[0]:.1f}")
    print("| part | state GB | RSS before GB | peak GB | (peak-before)/state | check GB |")
    print("|---|---|---|---|---|---|")
    for name, r in (("fresh, to round 1's checkpoint", fresh), ("resumed, to the end", resumed)):
        ratio = (r["peak"] - r["rss_before"]) / r["state"]
        print(f"| {name} | {r['state']:.2f} | {r['rss_before']:.2f} | {r['peak']:.2f} | {ratio:.2f} | "
              f"{r['check']:.1f} |")
    for name, r in (("fresh", fresh), ("resumed", resumed)):
        print(f"{name}: the peak came {r['where']}")
    if resumed["rc"] != 0:
        sys.exit(f"the resumed run failed (exit {resumed['rc']})")


if __name__ == "__main__":
    main()
