"""Checkpoints: pytrees saved with orbax, and the hybrid trainer's round checkpoints built on them.

A round checkpoint is `checkpoints/round_NNNNN/` in the first folder of a seed group:
`state/` (orbax, the group's arrays as numbered leaves), `sumo_days.npz` (every SUMO day so far,
per seed) and `meta.json`, written last, so a directory with `meta.json` is complete. `meta.json`
records the sha256 of every other file of the checkpoint (`digests`); a resume verifies them before
it reads anything, and a checkpoint whose files do not match (bit rot, a copy cut short, an edit) is
named, set aside as `damaged_round_NNNNN/`, and the previous one is used: the last two rounds are
kept (older ones are removed once the new one is complete). A partial one (no `meta.json`: a kill or
a full disk while writing) is ignored by a resume and replaced.
"""

from __future__ import annotations

import errno
import json
import logging
import shutil
import threading
from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from urb_jax.core.atomic import file_sha256, write_json, write_npz
from urb_jax.core.errors import UrbJaxError
from urb_jax.surrogate.calibrate import SumoSample

CKPT_DIR = "checkpoints"
DAMAGED_PREFIX = "damaged_"  # a checkpoint whose files failed their digests, kept for inspection
log = logging.getLogger(__name__)


SAVE_TIMEOUT_S = 1800.0  # the longest wait for orbax's writer threads to finish one checkpoint


def save_checkpoint(path: str | Path, tree: Any, timeout_s: float | None = None) -> Path:
    """Save a pytree with orbax at an absolute path; waits for the async save to finish, at most
    `timeout_s` (default SAVE_TIMEOUT_S): a save that has not finished by then (a hung filesystem)
    is a UrbJaxError that says so; the previous checkpoint is still complete."""
    import orbax.checkpoint as ocp  # about a second to import: paid only by runs that checkpoint

    path = Path(path).expanduser().resolve()
    ckptr = ocp.StandardCheckpointer()
    ckptr.save(path, tree, force=True)
    wait_bounded(ckptr.wait_until_finished, SAVE_TIMEOUT_S if timeout_s is None else timeout_s, path)
    return path


def wait_bounded(wait: Callable[[], Any], timeout_s: float, path: Path) -> None:
    """`wait()` in a thread, at most `timeout_s` seconds; its exception is raised here."""
    failed: list[BaseException] = []

    def run() -> None:
        try:
            wait()
        except BaseException as exc:  # handed to the caller's thread
            failed.append(exc)

    worker = threading.Thread(target=run, name="orbax-save-wait", daemon=True)
    worker.start()
    worker.join(timeout_s)
    if worker.is_alive():
        raise UrbJaxError(f"{path}: the checkpoint's save did not finish within {timeout_s:.0f} s (a hung "
                          "or very slow filesystem?); the previous round's checkpoint is kept. Fix: check "
                          "the disk holding the results folder, then continue with "
                          "`urb-jax train --resume <id>`.")
    if failed:
        raise failed[0]


def restore_checkpoint(path: str | Path, target: Any) -> Any:
    """Restore a pytree saved by save_checkpoint; `target` gives structure, shapes and dtypes."""
    import orbax.checkpoint as ocp  # as in save_checkpoint

    path = Path(path).expanduser().resolve()
    abstract = jax.tree_util.tree_map(ocp.utils.to_shape_dtype_struct, target)
    return ocp.StandardCheckpointer().restore(path, abstract)


@dataclass(frozen=True)
class RoundMeta:
    """meta.json of a round checkpoint: what a resume needs besides the arrays."""

    rounds_done: int
    sumo_days: int  # SUMO training days per seed so far
    seeds: list[int]
    folders: list[str]  # the seeds' results folders (names)
    record_parts: list[int]  # per seed: record parts written up to this checkpoint
    rounds: list[list[dict[str, Any]]]  # per seed: the rounds.csv rows so far
    rounds_total: int | None = None  # the group's planned rounds (None: a checkpoint from before the key)
    # the group's wall seconds when it was written, earlier processes' included, so a run killed
    # outright (no exp_config write) still counts them on resume (None: from before the key)
    wall_s: float | None = None
    # the group's last round [surrogate iterations, SUMO days]: a budget that is not whole rounds ends
    # with a shorter one (None: a checkpoint from before the key, when every round was whole)
    last_round: list[int] | None = None


def latest_checkpoint(folder: Path) -> tuple[int, Path] | None:
    """(rounds done, dir) of the newest complete checkpoint (meta.json is written last)."""
    done = kept_checkpoints(folder)
    return (done[-1], folder / CKPT_DIR / f"round_{done[-1]:05d}") if done else None


def save_round(folder: Path, state: Any, samples: Sequence[SumoSample], meta: RoundMeta,
               keep: Collection[int] = ()) -> None:
    """checkpoints/round_NNNNN/ in `folder` (the group's first), then the older ones removed, except
    the rounds in `keep` (the learning curve's snapshots)."""
    d = folder / CKPT_DIR / f"round_{meta.rounds_done:05d}"
    if d.exists():
        shutil.rmtree(d)  # a partial one (no meta.json) from a kill or a full disk
    d.mkdir(parents=True)
    leaves = {f"{i:05d}": np.asarray(x) for i, x in enumerate(jax.tree_util.tree_leaves(state))}
    arrays: dict[str, np.ndarray] = {}
    for i, sample in enumerate(samples):
        arrays |= {f"choices_{i}": sample.choices, f"travel_time_{i}": sample.travel_time,
                   f"arrived_{i}": sample.arrived}
        if sample.shift is not None:  # days whose departures moved
            arrays[f"shift_{i}"] = sample.shift
    _check_space(d, sum(a.nbytes for a in (*leaves.values(), *arrays.values())))
    save_checkpoint(d / "state", leaves)
    write_npz(d / "sumo_days.npz", **arrays)
    write_json(d / "meta.json", {**asdict(meta), "digests": file_digests(d)})
    older = sorted(int(p.name.split("_")[1]) for p in (folder / CKPT_DIR).glob("round_*")
                   if p != d and (p / "meta.json").is_file() and int(p.name.split("_")[1]) < meta.rounds_done)
    keep = {*keep, *older[-1:]}  # the previous complete one: the fallback of a damaged newest one
    for old in (folder / CKPT_DIR).glob("round_*"):
        if old != d and int(old.name.split("_")[1]) not in keep:
            shutil.rmtree(old, ignore_errors=True)


def file_digests(d: Path) -> dict[str, str]:
    """sha256 of every file under checkpoint `d` but meta.json, by path relative to `d`."""
    return {p.relative_to(d).as_posix(): file_sha256(p) for p in sorted(d.rglob("*"))
            if p.is_file() and p.name != "meta.json"}


def damaged_files(ckpt: Path, meta: dict[str, Any]) -> list[str]:
    """The files of `ckpt` that are missing, extra or differ from meta.json's digests (none: a
    checkpoint from before digests, which is trusted as it was)."""
    recorded = meta.get("digests")
    if recorded is None:
        return []
    now = file_digests(ckpt)
    return sorted(name for name in {*recorded, *now} if recorded.get(name) != now.get(name))


def _check_space(d: Path, nbytes: int) -> None:
    """Raise ENOSPC before writing a checkpoint that cannot fit (orbax would fail in its writer
    threads, with a traceback per array); the previous checkpoint is still complete."""
    free = shutil.disk_usage(d).free
    need = nbytes + (4 << 20)  # metadata and a margin
    if free < need:
        raise OSError(errno.ENOSPC, f"No space left on device: the round checkpoint needs about "
                      f"{need / 2**20:.1f} MiB, {free / 2**20:.1f} MiB are free", str(d))


def kept_checkpoints(folder: Path) -> list[int]:
    """The rounds done of every complete checkpoint in `folder` (a group's first), ascending: the
    newest two and those `hybrid.keep_checkpoints_at` kept."""
    root = folder / CKPT_DIR
    return sorted(int(p.name.split("_")[1]) for p in root.glob("round_*") if (p / "meta.json").is_file())


def verified_checkpoint(folder: Path) -> tuple[int, Path] | None:
    """(rounds done, dir) of the newest complete checkpoint whose files match their digests. A
    damaged one is named (a warning: run.log) and moved aside to damaged_round_NNNNN/, and the one
    before it is tried; all damaged is a UrbJaxError naming them."""
    damaged = []
    while (found := latest_checkpoint(folder)) is not None:
        ckpt = found[1]
        try:
            bad = damaged_files(ckpt, json.loads((ckpt / "meta.json").read_text()))
        except ValueError as exc:  # meta.json itself is not JSON
            bad = [f"meta.json ({exc})"]
        if not bad:
            return found
        damaged.append(f"{ckpt}: {', '.join(bad)}")
        aside = ckpt.with_name(f"{DAMAGED_PREFIX}{ckpt.name}")
        shutil.rmtree(aside, ignore_errors=True)
        ckpt.rename(aside)
        log.warning("%s: damaged checkpoint (%s do(es) not match the digests in its meta.json); moved to "
                    "%s, resuming from the checkpoint before it, if any", ckpt, ", ".join(bad), aside.name)
    if damaged:
        raise UrbJaxError(f"{folder}: every checkpoint is damaged ({'; '.join(damaged)}; moved aside as "
                          f"{DAMAGED_PREFIX}round_*). Fix: start the run again with the same command and "
                          "--overwrite.")
    return None


def restore_round(folder: Path, target: Any, seeds: Sequence[int], rounds_done: int | None = None
                  ) -> tuple[Any, list[SumoSample], RoundMeta]:
    """The checkpoint in `folder` after `rounds_done` rounds (None: the newest whose files match their
    digests, `verified_checkpoint`): (state shaped like `target`, each seed's SUMO days, meta);
    raises RuntimeError if there is none or it holds other seeds, UrbJaxError if the one asked for
    is damaged."""
    if rounds_done is None:
        found = verified_checkpoint(folder)
    else:
        ckpt = folder / CKPT_DIR / f"round_{rounds_done:05d}"
        found = (rounds_done, ckpt) if rounds_done in kept_checkpoints(folder) else None
        bad = [] if found is None else damaged_files(ckpt, json.loads((ckpt / "meta.json").read_text()))
        if bad:
            raise UrbJaxError(f"{ckpt}: damaged ({', '.join(bad)} do(es) not match the digests in its "
                              "meta.json). Fix: test another kept round.")
    if found is None:
        raise RuntimeError(f"{folder}: no checkpoint to resume from" if rounds_done is None else
                           f"{folder}: no complete checkpoint after round {rounds_done}")
    rounds_done, ckpt = found
    meta = json.loads((ckpt / "meta.json").read_text())
    if meta.get("seeds", seeds) != list(seeds):
        raise RuntimeError(f"{ckpt}: checkpoint holds seeds {meta['seeds']}, not {list(seeds)}")
    state = _restore_state(ckpt / "state", target)
    z = np.load(ckpt / "sumo_days.npz")
    samples = [SumoSample(z[f"choices_{i}"], z[f"travel_time_{i}"], z[f"arrived_{i}"],
                          z[f"shift_{i}"] if f"shift_{i}" in z.files else None)
               for i in range(len(seeds))]
    return state, samples, RoundMeta(rounds_done, meta["sumo_days"], list(seeds), meta.get("folders", []),
                                     meta["record_parts"], meta["rounds"], meta.get("rounds_total"),
                                     meta.get("wall_s"), meta.get("last_round"))


def checkpoint_meta(folder: Path) -> dict[str, Any] | None:
    """The newest complete checkpoint's meta.json in `folder` (a group's first), with `saved_at`
    (its mtime, epoch seconds); None without one. Reads no arrays: for reporting progress."""
    found = latest_checkpoint(folder)
    if found is None:
        return None
    meta_file = found[1] / "meta.json"
    return {**json.loads(meta_file.read_text()), "saved_at": meta_file.stat().st_mtime}


def _restore_state(path: Path, target: Any) -> Any:
    """Orbax stores the state as numbered leaves; `target` gives the tree, shapes and dtypes (arrays
    or, better, `jax.eval_shape`'s structs: a resume then holds the state once, not a fresh copy
    beside the restored one). Leaves come back as jax arrays, never weakly typed (as saved)."""
    leaves, treedef = jax.tree_util.tree_flatten(target)
    abstract = {f"{i:05d}": jax.ShapeDtypeStruct(np.shape(x), x.dtype) for i, x in enumerate(leaves)}
    flat = restore_checkpoint(path, abstract)
    restored = [jnp.asarray(flat.pop(f"{i:05d}")) for i in range(len(leaves))]
    return jax.tree_util.tree_unflatten(treedef, restored)
