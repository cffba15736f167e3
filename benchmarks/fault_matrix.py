"""Fault injection on a real run: one short train run on the embedded network, killed
with SIGKILL at N instants spread over its whole wall time (human days, calibration, rounds,
checkpoint writes, test, the final merge and metrics), each resumed with `urb-jax train --resume`;
then SIGKILL at four observed instants (a checkpoint being written, the test days, the merged
records before the metrics, the metrics before `done`: a loaded machine moves phases in time),
Ctrl-C (SIGINT to the process group, as a terminal sends it) at a few instants, and a SUMO
worker killed mid-day. Each trial counts as identical when records.parquet and
metrics/BenchmarkMetrics.csv equal the uninterrupted run's byte for byte.

    python benchmarks/fault_matrix.py [--kills 20] [--sigints 5] [--out DIR]

Resumable: finished trials are kept in DIR/trials.json and skipped when run again. Prints a table
(also written to DIR/fault_matrix.md).

`--integrity` runs the integrity trials instead, on the tests' tiny IQL run (3 rounds, SUMO days
in SUMO; tests/support/tiny_runs.py): bytes flipped
at several offsets of a round checkpoint's files, of a record part (the newest, and the human phase's
first), of a human-day journal entry and of exp_config.json, each in a copy of a run stopped at an
observed instant and then resumed (and exp_config.json's env_seed edited, the JSON still valid);
and SIGTERM and SIGHUP mid-run, then `--resume`. Each trial's outcome is "identical" (records
and metrics equal the uninterrupted run's), "refused" (exit 2 with
a message, no records.parquet or metrics written) or WRONG (anything else); a journal entry is also
replaced by a copy of another day's entry (readable, but not its day). Table in
DIR/integrity.md.

    python benchmarks/fault_matrix.py --integrity [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.digests import result_digests
from support.tiny_runs import tiny_iql_run

from urb_jax.core.paths import DAY_STORE_ENV

HYBRID = {"train_days": 120, "num_envs": 4, "surrogate_days_per_round": 32, "sumo_days_per_round": 4,
          "sumo_updates": 1, "sumo_workers": 2, "calib_human_days": 5, "calib_varied_days": 2,
          "calib_steps": 50, "refit_days": 8, "refit_steps": 20}


def _digest(folder: Path) -> list[str] | None:
    """The run's result digests as a list: the form trials.json gives back when it resumes."""
    digests = result_digests(folder)
    return None if digests is None else list(digests)


def _cmd(out: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "urb_jax.commands.cli", "train", "--results-dir", str(out / "runs"),
            "--no-progress", *args]


def _start(out: Path, exp_id: str, *extra: str) -> subprocess.Popen:
    args = ("--id", exp_id, "--task-conf", "test", "--hybrid-conf", str(out / "hybrid.json"), *extra)
    return subprocess.Popen(_cmd(out, *args), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))




def _phase(folder: Path, rounds: int) -> str:
    """Where a run was when it stopped, from what it left behind."""
    cfg_path = folder / "exp_config.json"
    if not cfg_path.is_file():
        return "start (no exp_config yet)"
    cfg = json.loads(cfg_path.read_text())
    if cfg.get("status") == "done":
        return "after done"
    ckpts = sorted((folder / "checkpoints").glob("round_*/meta.json"))
    if not ckpts:
        journal = len(list((folder / "human_days.journal").glob("*.npz")))
        return f"human days / calibration ({journal} journaled)"
    done = int(ckpts[-1].parent.name.split("_")[1])
    if (folder / "records.parquet").is_file():
        return "finish (merged, metrics)"
    partial = [p for p in (folder / "checkpoints").glob("round_*") if not (p / "meta.json").is_file()]
    where = f"round {done + 1}" if done < rounds else "test days"
    return where + (" (checkpoint being written)" if partial else "")


def _resume(out: Path, exp_id: str) -> tuple[int, str]:
    proc = subprocess.run(_cmd(out, "--resume", exp_id), capture_output=True, text=True)
    return proc.returncode, proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else ""


def reference(out: Path) -> dict:
    ref = out / "runs" / "ref"
    if _digest(ref) is None:
        shutil.rmtree(ref, ignore_errors=True)
        t0 = time.perf_counter()
        proc = _start(out, "ref")
        err = proc.communicate()[1]
        if proc.returncode != 0:
            raise SystemExit(f"reference run failed:\n{err}")
        (out / "ref_wall.txt").write_text(f"{time.perf_counter() - t0:.2f}")
    rounds = int(json.loads((ref / "exp_config.json").read_text())["rounds"])
    return {"digest": _digest(ref), "wall": float((out / "ref_wall.txt").read_text()), "rounds": rounds}


# Kills at an observed instant rather than a time (a loaded machine moves the phases in time):
# what the run folder shows just before the kill.
EVENTS = {
    "checkpoint being written": lambda f: any(p.is_dir() and not (p / "meta.json").is_file()
                                              for p in (f / "checkpoints").glob("round_0000[1-9]")),
    "test days": lambda f: (f / "checkpoints" / "round_00002" / "meta.json").is_file(),
    "merged, before metrics": lambda f: (f / "records.parquet").is_file(),
    "metrics written, before done": lambda f: (f / "metrics" / "BenchmarkMetrics.csv").is_file(),
}


def _wait_for(proc: subprocess.Popen, folder: Path, event: str) -> float:
    t0 = time.perf_counter()
    while proc.poll() is None and not EVENTS[event](folder):
        time.sleep(0.005)
    return time.perf_counter() - t0


def kill_trial(out: Path, exp_id: str, at: float | str, sig: int, rounds: int) -> dict:
    folder = out / "runs" / exp_id
    shutil.rmtree(folder, ignore_errors=True)
    proc = _start(out, exp_id)
    if isinstance(at, str):  # an event
        at = _wait_for(proc, folder, at)
    else:
        time.sleep(at)
    stopped_in = _phase(folder, rounds)
    t0 = time.perf_counter()
    if proc.poll() is None:
        os.killpg(proc.pid, sig)
    err = proc.communicate()[1]
    stop_s = time.perf_counter() - t0
    trial = {"id": exp_id, "signal": signal.Signals(sig).name, "at_s": round(at, 1), "phase": stopped_in,
             "exit": proc.returncode, "stop_s": round(stop_s, 1),
             "message": err.strip().splitlines()[-1][:160] if err.strip() else ""}
    resumes = 0
    while resumes < 3:  # what a user does: --resume; the same command again if there is nothing to resume
        rc, last = _resume(out, exp_id)
        resumes += 1
        if rc == 0 or "already complete" in last:
            break
        if "no urb-jax run" in last or "nothing to resume" in last:
            proc = _start(out, exp_id, "--overwrite")
            proc.communicate()
            trial["restarted"] = True
            break
        trial["resume_error"] = last[:200]
    trial["resumes"] = resumes
    trial["digest"] = _digest(folder)
    return trial


def worker_kill_trial(out: Path, at: float) -> dict:
    """SIGKILL one SUMO worker (a child of the run) at `at` s; the run must finish by itself."""
    folder = out / "runs" / "worker"
    shutil.rmtree(folder, ignore_errors=True)
    proc = _start(out, "worker")
    time.sleep(at)
    kids = subprocess.run(["pgrep", "-f", "-P", str(proc.pid), "spawn_main"], capture_output=True,
                          text=True).stdout.split()
    killed = int(kids[0]) if kids else None
    if killed:
        os.kill(killed, signal.SIGKILL)
    err = proc.communicate()[1]
    warned = [ln for ln in err.splitlines() if "restarting it" in ln]
    return {"id": "worker", "signal": "SIGKILL worker", "at_s": round(at, 1), "phase": "SUMO day",
            "exit": proc.returncode, "killed_pid": killed, "warning": warned[0][:160] if warned else "",
            "resumes": 0, "digest": _digest(folder)}


CKPT2 = Path("checkpoints") / "round_00002" / "meta.json"  # round 2's checkpoint is complete
OFFSETS = (0.1, 0.5, 0.9)  # where in a file a byte is flipped, as a fraction of its length


def _start_in(results: Path, confs: dict[str, str], exp_id: str, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "urb_jax.commands.cli", "train", "--results-dir", str(results),
           "--no-progress", "--id", exp_id, "--alg", "iql", "--task-conf", confs["task_conf"],
           "--hybrid-conf", confs["hybrid_conf"], "--alg-conf", confs["alg_conf"], *extra]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _stop_at(proc: subprocess.Popen, seen, sig: int) -> tuple[int, str]:
    """Send `sig` to the run's process group once `seen()` holds; (exit code, last stderr line)."""
    while proc.poll() is None and not seen():
        time.sleep(0.01)
    if proc.poll() is None:
        os.killpg(proc.pid, sig)
    err = proc.communicate()[1].strip()
    return proc.returncode, err.splitlines()[-1][:200] if err else ""


def _flip(path: Path, at: float) -> int:
    data = bytearray(path.read_bytes())
    i = min(len(data) - 1, int(len(data) * at))
    data[i] ^= 0xFF
    path.write_bytes(bytes(data))
    return i


def _outcome(results: Path, exp_id: str, ref: list[str] | None) -> dict:
    """--resume the run, then judge it: identical, refused (exit 2, a message, no results) or WRONG."""
    cmd = [sys.executable, "-m", "urb_jax.commands.cli", "train", "--results-dir", str(results),
           "--no-progress", "--resume", exp_id]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    err = proc.stderr.strip()
    last = err.splitlines()[-1] if err else ""
    folder = results / exp_id
    digest = _digest(folder)
    if proc.returncode == 0 and digest == ref:
        outcome = "identical"
    elif proc.returncode == 2 and last.startswith("urb-jax: error:") and not (
            (folder / "records.parquet").is_file() or (folder / "metrics").is_dir()):
        outcome = "refused"
    else:
        outcome = "WRONG"
    warned = [ln for ln in err.splitlines() if ln.startswith("WARNING") and "taking over the lock" not in ln]
    return {"exit": proc.returncode, "outcome": outcome, "message": (last if proc.returncode else
                                                                     (warned[0] if warned else ""))[:300]}


def integrity(out: Path) -> None:
    """The integrity trials (module docstring); prints and writes DIR/integrity.md."""
    out.mkdir(parents=True, exist_ok=True)
    # every day in SUMO: with the SUMO day store on, a run whose days an earlier run stored finishes
    # its human phase before the instant it is to be stopped at (and no trial would damage a day)
    os.environ[DAY_STORE_ENV] = "0"
    confs = tiny_iql_run(out)  # the tests' tiny IQL run: 3 rounds of 4 surrogate and 2 SUMO days
    done_path = out / "trials.json"
    trials = json.loads(done_path.read_text()) if done_path.is_file() else {}
    ref_dir = out / "ref"
    if _digest(ref_dir / "r") is None:
        shutil.rmtree(ref_dir, ignore_errors=True)
        proc = _start_in(ref_dir, confs, "r")
        err = proc.communicate()[1]
        if proc.returncode != 0:
            raise SystemExit(f"reference run failed: {err}")
    ref = _digest(ref_dir / "r")
    bases = {  # a run stopped at an observed instant, copied for each trial
        "round2": lambda f: (f / CKPT2).is_file(),
        "human": lambda f: len(list((f / "human_days.journal").rglob("*.npz"))) >= 6,
    }
    for name, seen in bases.items():
        base = out / f"base_{name}"
        if not (base / "r" / "exp_config.json").is_file() or not (base / "stopped").is_file():
            shutil.rmtree(base, ignore_errors=True)
            proc = _start_in(base, confs, "r")
            _stop_at(proc, lambda seen=seen, base=base: seen(base / "r"), signal.SIGKILL)
            if json.loads((base / "r" / "exp_config.json").read_text()).get("status") == "done":
                raise SystemExit(f"{base}: the run finished before it was stopped; use more rounds")
            (base / "stopped").write_text("")

    def files(f: Path) -> dict[str, Path]:
        ckpt = f / "checkpoints" / "round_00002"
        state = max((p for p in (ckpt / "state").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
        parts = sorted((f / "records.parts").glob("part-*.parquet"))
        return {"checkpoint sumo_days.npz": ckpt / "sumo_days.npz", "checkpoint state (largest file)": state,
                "records part (newest)": parts[-1], "records part (human phase)": parts[0],
                "exp_config.json": f / "exp_config.json"}

    plan: list[tuple[str, str, str, float]] = []  # (trial, base, file, offset)
    for what in ("checkpoint sumo_days.npz", "checkpoint state (largest file)", "records part (newest)",
                 "records part (human phase)", "exp_config.json"):
        plan += [(f"{what} @{at}", "round2", what, at) for at in OFFSETS]
    plan += [(f"journal entry @{at}", "human", "journal entry", at) for at in OFFSETS]
    plan.append(("journal entry replaced by another day's", "human", "journal swap", 0.0))
    plan.append(("exp_config.json env_seed edited", "round2", "config edit", 0.0))
    for trial, base_name, what, at in plan:
        if trial in trials:
            continue
        results = out / "trials" / "".join(c if c.isalnum() or c in "._" else "_" for c in trial)
        shutil.rmtree(results, ignore_errors=True)
        shutil.copytree(out / f"base_{base_name}", results)
        folder = results / "r"
        entries = sorted((folder / "human_days.journal").rglob("*.npz"))
        if what == "journal swap":  # a valid entry of another day under this day's name
            shutil.copy(entries[3], entries[2])
            how = "journal entry replaced by a copy of another day's entry"
        elif what == "config edit":  # still valid JSON: only its digest tells
            cfg = folder / "exp_config.json"
            cfg.write_text(cfg.read_text().replace('"env_seed": 42', '"env_seed": 43'))
            how = "exp_config.json's env_seed edited (42 to 43, valid JSON)"
        else:
            target = entries[2] if what == "journal entry" else files(folder)[what]
            how = f"flip byte {_flip(target, at)} of {what} ({at:.0%} in)"
        t = {"trial": how, "stop_exit": "SIGKILL", **_outcome(results, "r", ref)}
        trials[trial] = t
        done_path.write_text(json.dumps(trials, indent=1))
        print(f"{t['trial']}: exit {t['exit']}, {t['outcome']}: {t['message'][:120]}", flush=True)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        trial = f"{sig.name} mid-run"
        if trial in trials:
            continue
        results = out / "trials" / sig.name
        shutil.rmtree(results, ignore_errors=True)
        proc = _start_in(results, confs, "r")
        rc, msg = _stop_at(proc, lambda r=results: (r / "r" / CKPT2).is_file(), sig)
        t = {"trial": f"{sig.name} after round 2's checkpoint, then --resume", "stop_exit": rc,
             **_outcome(results, "r", ref)}
        t["message"] = f"stop: {msg[:150]}" + (f"; resume: {t['message']}" if t["message"] else "")
        trials[trial] = t
        done_path.write_text(json.dumps(trials, indent=1))
        print(f"{t['trial']}: stop exit {rc}, resume exit {t['exit']}, {t['outcome']}", flush=True)
    rows = ["| trial | stop exit | resume exit | outcome | message |", "|---|---|---|---|---|"]
    for t in trials.values():
        msg = t["message"].replace(f"{out / 'trials'}/", "").replace("|", "/")  # paths from the trial folder
        rows.append(f"| {t['trial']} | {t['stop_exit']} | {t['exit']} | {t['outcome']} | {msg} |")
    counts = {o: sum(t["outcome"] == o for t in trials.values()) for o in ("identical", "refused", "WRONG")}
    table = "\n".join([*rows, "", ", ".join(f"{k}: {v}" for k, v in counts.items())]) + "\n"
    (out / "integrity.md").write_text(table)
    print(table)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=20)
    ap.add_argument("--sigints", type=int, default=5)
    ap.add_argument("--out", default="benchmarks/out/fault_matrix")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--integrity", action="store_true",
                    help="run the integrity trials (corrupted files, SIGTERM and SIGHUP) instead")
    args = ap.parse_args()
    out = Path(args.out)
    if args.integrity:
        integrity(out / "integrity")
        return
    out.mkdir(parents=True, exist_ok=True)
    (out / "hybrid.json").write_text(json.dumps(HYBRID))
    ref = reference(out)
    print(f"reference run: {ref['wall']:.1f} s, {ref['rounds']} rounds, load {os.getloadavg()[0]:.1f}",
          flush=True)
    rng = np.random.default_rng(args.seed)
    span = ref["wall"] * 1.05  # the last instants land in the finish or after it
    kill_at = [span * (i + rng.uniform()) / args.kills for i in range(args.kills)]  # one per stratum
    int_at = [span * (i + rng.uniform()) / args.sigints for i in range(args.sigints)]
    plan = ([(f"kill{i:02d}", t, signal.SIGKILL) for i, t in enumerate(kill_at)]
            + [(f"int{i:02d}", t, signal.SIGINT) for i, t in enumerate(int_at)])
    done_path = out / "trials.json"
    trials = json.loads(done_path.read_text()) if done_path.is_file() else {}
    for exp_id, at, sig in plan:
        if exp_id not in trials:
            trials[exp_id] = kill_trial(out, exp_id, at, sig, ref["rounds"])
        else:
            continue
        t = trials[exp_id]
        same = t["digest"] == ref["digest"]
        print(f"{exp_id}: {t['signal']} at {t['at_s']} s in {t['phase']}: exit {t['exit']} after "
              f"{t['stop_s']} s, {t['resumes']} resume(s), identical {same}", flush=True)
        done_path.write_text(json.dumps(trials, indent=1))
    for i, event in enumerate(EVENTS):
        exp_id = f"event{i}"
        if exp_id not in trials:
            trials[exp_id] = kill_trial(out, exp_id, event, signal.SIGKILL, ref["rounds"])
            trials[exp_id]["phase"] = f"{event}: {trials[exp_id]['phase']}"
            t = trials[exp_id]
            print(f"{exp_id}: SIGKILL at {t['phase']}: identical {t['digest'] == ref['digest']}", flush=True)
            done_path.write_text(json.dumps(trials, indent=1))
    if "worker" not in trials:
        trials["worker"] = worker_kill_trial(out, 0.4 * ref["wall"])
        done_path.write_text(json.dumps(trials, indent=1))
    table = _table(trials, ref)
    (out / "fault_matrix.md").write_text(table)
    print(table)


def _table(trials: dict, ref: dict) -> str:
    rows = ["| trial | signal | at (s) | stopped in | exit | stop (s) | recovery | identical |",
            "|---|---|---|---|---|---|---|---|"]
    for t in trials.values():
        how = "same command, --overwrite" if t.get("restarted") else f"{t['resumes']} x --resume"
        if t["signal"] == "SIGKILL worker":
            how = "none needed (day retried)"
        rows.append(f"| {t['id']} | {t['signal']} | {t['at_s']} | {t['phase']} | {t['exit']} | "
                    f"{t.get('stop_s', '')} | {how} | {t['digest'] == ref['digest']} |")
    summary = []
    for kind, label in (("SIGKILL", "SIGKILL + resume (timed and at observed instants)"),
                        ("SIGINT", "SIGINT + resume"),
                        ("SIGKILL worker", "SUMO worker killed mid-day")):
        group = [t for t in trials.values() if t["signal"] == kind]
        if group:
            same = sum(t["digest"] == ref["digest"] for t in group)
            summary.append(f"- {label}: {same}/{len(group)} identical to the uninterrupted run")
    sig = [t for t in trials.values() if t["signal"] == "SIGINT" and t["exit"] == 130]
    if sig:
        summary.append(f"- SIGINT: exit 130 in {len(sig)} trial(s), stopped within "
                       f"{max(t['stop_s'] for t in sig):.1f} s at most")
    return "\n".join([*rows, "", *summary]) + "\n"


if __name__ == "__main__":
    main()
