"""A run's results folder, results/<exp_id>/: created once, exp_config.json written at the start and
marked done at the end, and the finishing step that turns records into metric files and plots."""

from __future__ import annotations

import atexit
import datetime
import fcntl
import functools
import logging
import os
import platform
import re
import shutil
import subprocess
import tempfile
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import pandas as pd

from urb_jax.core.atomic import umask, write_bytes
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.interrupt import at_hard_exit
from urb_jax.core.paths import os_reason
from urb_jax.reporting.drift import ERROR_COLUMN, ROUNDS_FILE
from urb_jax.reporting.records import (
    CONFIG_FILE,
    remove_parts,
    run_config,
    write_plots,
    write_run_config,
    write_run_metrics,
)
from urb_jax.reporting.urb_names import phase_keys

log = logging.getLogger(__name__)


class ResultsExistError(UrbJaxError):
    """The experiment id is taken."""


ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")
_LOCKS: dict[Path, int] = {}  # run folder -> open, flock-ed lock file, held until the process ends


def check_exp_id(exp_id: str) -> str:
    """An experiment id is one plain path component: letters, digits, '.', '_', '+', '-', not
    starting with '.' (so never '.', '..', a path or an absolute path)."""
    if not ID_PATTERN.fullmatch(exp_id or ""):
        raise UrbJaxError(f"--id {exp_id!r}: an experiment id is one plain name (letters, digits, "
                          "'.', '_', '+', '-'; no '/', not starting with '.'). Fix: pass e.g. --id iql_run1.")
    return exp_id


def lock_run(folder: Path) -> None:
    """Make this process the one writer of `folder` (an flock on results/.<id>.lock, released by
    the OS when the process ends, so a crashed owner leaves no stale lock behind)."""
    folder = folder.resolve()
    if folder in _LOCKS:
        return
    folder.parent.mkdir(parents=True, exist_ok=True)
    path = folder.parent / f".{folder.name}.lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        owner = os.read(fd, 64).decode(errors="replace").strip() or "?"
        os.close(fd)
        raise UrbJaxError(f"{folder}: run '{folder.name}' is being written by process {owner}. Fix: wait "
                          "for it to finish, or pass another --id.") from None
    previous = os.read(fd, 64).decode(errors="replace").strip()
    if previous and previous != str(os.getpid()):
        log.warning("%s: taking over the lock of process %s, which has ended", folder, previous)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    _LOCKS[folder] = fd
    release = functools.partial(os.ftruncate, fd, 0)  # an exit leaves no owner to "take over" from
    atexit.register(release)
    at_hard_exit(release)  # a Ctrl-C stop leaves with os._exit, where atexit does not run


def run_writer(folder: Path) -> int | None:
    """The live process writing `folder` (holding its `lock_run` lock), or None: a shared flock on
    the lock file is refused while the writer holds its exclusive one."""
    folder = folder.resolve()
    path = folder.parent / f".{folder.name}.lock"
    if folder in _LOCKS or not path.is_file():
        return None
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        owner = os.read(fd, 64).decode(errors="replace").strip()
        return int(owner) if owner.isdigit() else -1
    finally:
        os.close(fd)  # closing releases the shared lock, if it was granted
    return None


def train_run_names(exp_id: str | None, alg: str, mode: str, net: str, task_stem: str, seeds: list[int]
                    ) -> list[str]:
    """The results folder of each seed of a train run: `exp_id` itself for one seed, else
    `<exp_id or alg_mode_net_task>_s<seed>` (the one naming rule of run, dry run and suite)."""
    base = exp_id or f"{alg}_{mode}_{Path(net).name}_{task_stem}"
    return [exp_id if (exp_id and len(seeds) == 1) else f"{base}_s{s}" for s in seeds]


def create_results_dir(root: str | os.PathLike, exp_id: str, overwrite: bool = False) -> Path:
    """A fresh results/<exp_id>/, locked by this process; refuses an existing one unless `overwrite`,
    and `overwrite` removes only a urb-jax run (a folder with exp_config.json) that no live
    process is writing."""
    path = Path(root) / check_exp_id(exp_id)
    check_results_root(root)
    try:
        lock_run(path)
    except OSError as exc:
        raise _unwritable(root, exc) from None
    if path.exists():
        if not overwrite:
            raise ResultsExistError(
                f"{path}: results for experiment id '{exp_id}' already exist. "
                "Fix: pass another --id, or --overwrite to replace them."
            )
        if not (path / CONFIG_FILE).is_file():
            raise ResultsExistError(f"{path}: exists but is not a urb-jax run (no {CONFIG_FILE}), so "
                                    "--overwrite will not remove it. Fix: pass another --id.")
        shutil.rmtree(path)
    for stale in Path(root).glob(f".{exp_id}.new-*"):  # ours, left by a kill inside this function
        shutil.rmtree(stale, ignore_errors=True)
    try:
        new = Path(tempfile.mkdtemp(prefix=f".{exp_id}.new-", dir=root))
    except OSError as exc:
        raise _unwritable(root, exc) from None
    os.chmod(new, 0o777 & ~umask())
    write_config(new, {"status": "created"})  # replaced by the run's own before any SUMO day
    new.rename(path)  # the folder appears with its exp_config.json: always a urb-jax run
    return path


def check_results_root(root: str | os.PathLike) -> None:
    """--results-dir `root` is a folder, or can be made one, that this process can write to: its
    nearest existing folder is a folder (no file in the way) on a writable filesystem and
    permitted. A dry run checks this without creating anything; a run checks it first."""
    root = Path(root)
    existing = next((p for p in (root, *root.parents) if p.exists()), Path("/"))
    if not existing.is_dir():
        what = "is a file, not a folder" if existing == root else f"cannot be created: {existing} is a file"
        raise UrbJaxError(f"--results-dir {root}: {what}. Fix: pass a folder (or one that can be created).")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UrbJaxError(f"--results-dir {root}: {existing} is not writable by this user. Fix: pass a "
                          "folder you can write to.")
    try:
        probe = os.statvfs(existing)
    except OSError:
        return
    if probe.f_flag & os.ST_RDONLY:
        raise UrbJaxError(f"--results-dir {root}: {existing} is on a read-only filesystem. Fix: pass a "
                          "folder you can write to.")


def _unwritable(root: str | os.PathLike, exc: OSError) -> UrbJaxError:
    return UrbJaxError(f"--results-dir {root}: cannot create or write the run's folder there "
                       f"({os_reason(exc, Path(root))}). Fix: pass a folder you can write to.")


SOURCE_ROOT = Path(__file__).resolve().parents[2]  # the checkout this process imported urb_jax from


@functools.cache
def source_commit(root: Path = SOURCE_ROOT) -> str:
    """The git commit of the urb-jax source this process runs, '+changes' when its tracked files
    differ from it: package metadata says 0.1.0 for every commit, and a run's numbers can depend on
    the commit (docs/algorithms.md: QMIX's faster step changed its float rounding)."""
    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=10)

    try:
        found = git("rev-parse", "--show-toplevel", "HEAD")
        lines = found.stdout.splitlines()  # [top level, HEAD]; a venv inside a repository is not one
        if found.returncode != 0 or len(lines) != 2 or Path(lines[0]).resolve() != root.resolve():
            return "unknown (not a git checkout)"
        changed = git("diff", "--quiet", "HEAD", "--").returncode != 0
    except (OSError, subprocess.SubprocessError):
        return "unknown (git not available)"
    return lines[1] + ("+changes" if changed else "")


def versions() -> dict[str, str]:
    """Installed versions (from package metadata: importing libsumo just to ask is costly) and the
    source's git commit."""
    out = {"python": platform.python_version(), "urb-jax source": source_commit()}
    for dist in ("urb-jax", "jax", "numpy", "pandas", "pyarrow", "eclipse-sumo", "libsumo", "janux"):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = "absent"
    return out


# The instruction-set extensions XLA:CPU's code can differ by. Measured: without FMA a product's last
# bits change; AVX-512 against AVX2 alone changed none.
ISA_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512_vnni", "avx512_bf16", "avx512_fp16",
             "amx_tile", "neon", "asimd", "sve")


def _cpu(cpuinfo: Path = Path("/proc/cpuinfo")) -> tuple[str, list[str]]:
    """(model name, the ISA_FLAGS it has) from /proc/cpuinfo; platform's answer elsewhere."""
    try:
        text = cpuinfo.read_text()
    except OSError:
        return platform.processor() or platform.machine(), []
    first = text.split("\n\n", 1)[0]  # the first processor's block; the others repeat it
    fields = {k.strip(): v.strip() for k, v in (ln.split(":", 1) for ln in first.splitlines() if ":" in ln)}
    get = fields.get
    model = get("model name") or get("Hardware") or platform.processor() or platform.machine()
    if "cpu family" in fields:  # a VM's model name can be generic ("Intel(R) Xeon(R) Processor")
        model += f" (family {get('cpu family')}, model {get('model')}, stepping {get('stepping')})"
    if "cache size" in fields:  # product kernels size their blocks by it
        model += f", cache {get('cache size')}"
    have = set((get("flags") or get("Features") or "").split())
    return model, [f for f in ISA_FLAGS if f in have]


def machine() -> dict[str, Any]:
    """Where this process computes: JAX's backend and device, the CPU and its ISA flags, the cores.
    A run records it because its last bits can depend on it: Ingolstadt's QMIX seed 0, the same
    command on two 2-core CPU hosts (no change to what the code computes between), gave t_CAV
    5.0097 and 4.9711; a GPU and a CPU differ too (docs/hybrid.md,
    "Equivalence")."""
    import jax  # the callers have it loaded already; this module's other users need not

    model, isa = _cpu()
    return {"backend": jax.default_backend(), "device": jax.devices()[0].device_kind,
            "devices": jax.device_count(), "cpu": model, "cpu_isa": isa, "cpu_count": os.cpu_count()}


def write_config(folder: Path, config: dict[str, Any]) -> None:
    """exp_config.json with the sha256 of its content (`reporting.records.write_run_config`)."""
    write_run_config(folder, config)


def write_outputs(folder: Path, human_days: int, training_days: int,
                  hybrid: bool = False) -> tuple[dict[str, float], dict[str, Any]]:
    """The metric files and plots of a finished run (`hybrid`: some training days on the surrogate),
    from its records; returns the metrics and the phase keys that describe the records to URB's
    tools (`urb_names.phase_keys`)."""
    metrics, records = write_run_metrics(folder, human_days, training_days, hybrid)
    write_plots(folder, records, human_days, training_days, smooth_by=1)
    return metrics, phase_keys(records, human_days)


def read_run_config(folder: Path) -> dict[str, Any]:
    """The run's exp_config.json, checked against the sha256 it carries (`reporting.records.run_config`);
    unreadable, not JSON (truncated), not an object or not its digest: a UrbJaxError that names the
    file and what can be done (a run cannot go on without its record)."""
    return run_config(folder)


def read_train_config(folder: Path) -> dict[str, Any]:
    """`read_run_config` of a `urb-jax train` run; another folder (none, or a baseline run, which
    keeps no policies, checkpoints or calibration days): a UrbJaxError that says what to pass."""
    path = folder / CONFIG_FILE
    if not path.is_file():
        raise UrbJaxError(f"{path}: not found. Fix: pass a `urb-jax train` run (its id in --results-dir, "
                          "or its folder).")
    config = read_run_config(folder)
    if "train_args" not in config:
        raise UrbJaxError(f"{path}: not a `urb-jax train` run (no 'train_args'); baseline runs keep no "
                          "policies, checkpoints or calibration days. Fix: pass a train run.")
    return config


def run_status(folder: Path) -> str | None:
    """exp_config.json's status ("created", ..., "done": `mark_done`); None without the file."""
    return read_run_config(folder).get("status") if (folder / CONFIG_FILE).is_file() else None


def seed_groups_of(results_dir: Path, names: list[str]) -> list[list[str]]:
    """The groups of seeds trained together among run folders `names`, in their order: each
    folder's exp_config.json `group` (a folder without one: a group of its own)."""
    groups: list[list[str]] = []
    for name in names:
        if not any(name in g for g in groups):
            config = results_dir / name / CONFIG_FILE
            groups.append(read_run_config(config.parent).get("group", [name]) if config.is_file() else [name])
    return groups


def mark_done(folder: Path, config: dict[str, Any], **updates: Any) -> None:
    """exp_config.json with status done, `finished_at` (UTC, to the second: the paper page's ledger
    dates each run by it) and `updates` (without it, the run is unfinished), then the merged
    records' parts go: the finish is ordered so that a kill at any instant resumes."""
    finished = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    config.update(status="done", finished_at=finished, **updates)
    write_config(folder, config)
    remove_parts(folder)


def write_rounds(folder: Path, rounds: list[dict[str, float]]) -> None:
    """rounds.csv (per round: surrogate and SUMO days, times, surrogate error) and its plot."""
    df = pd.DataFrame(rounds)
    write_bytes(folder / ROUNDS_FILE, df.to_csv(index=False).encode())
    if ERROR_COLUMN not in df:
        return
    import matplotlib  # imported by the runs that plot; the Agg backend is chosen before pyplot loads

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(df["round"], 100 * df[ERROR_COLUMN], label="error of the day mean (%)")
    ax.plot(df["round"], 100 * df["surrogate_mape"], label="per agent-day MAPE (%)")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_xlabel("round")
    ax.set_ylabel("surrogate vs SUMO (before refit)")
    ax.legend()
    fig.tight_layout()
    (folder / "plots").mkdir(exist_ok=True)
    fig.savefig(folder / "plots" / "surrogate_error.png", dpi=110)
    plt.close(fig)
