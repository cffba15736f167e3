"""Where and how a run was made, as the paper page's ledger keeps it (docs/paper_runs.json).

The same command can give a run other last bits on another host (Ingolstadt's QMIX seed 0: t_CAV
5.0097 and 4.9711 on two 2-core CPUs), so a ledger row that keeps only metrics cannot say which host
made it, nor rerun it. Each run's exp_config.json records the commit, the machine, the package
versions, the command and its request (with its `--set` overrides), where its human phase came from,
its wall time and when it finished; `provenance` keeps those, with every absolute path cut to its last
part (the ledger is committed and read on other machines). Older runs lack some: "not recorded".
"""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path
from typing import Any

NOT_RECORDED = "not recorded"
PROVENANCE = "provenance"  # the ledger row's key holding it


def portable(value: Any) -> Any:
    """`value` with every absolute path string cut to its last part, in lists and dicts too: the
    ledger never names this machine's folders."""
    if isinstance(value, str):
        return Path(value).name if os.path.isabs(value) else value
    if isinstance(value, list | tuple):
        return [portable(v) for v in value]
    if isinstance(value, dict):
        return {k: portable(v) for k, v in value.items()}
    return value


def finished_date(cfg: dict[str, Any], cfg_path: Path) -> str:
    """When the run finished: exp_config.json's `finished_at` (UTC), or for runs written before it
    existed, the file's modification time (its last write is the finish), said so."""
    if cfg.get("finished_at"):
        return str(cfg["finished_at"])
    if not cfg_path.is_file():
        return NOT_RECORDED
    stamp = dt.datetime.fromtimestamp(cfg_path.stat().st_mtime, tz=dt.UTC)
    return f"{stamp.isoformat(timespec='seconds')} (exp_config.json's file time; no finished_at recorded)"


def provenance(cfg: dict[str, Any], cfg_path: Path) -> dict[str, Any]:
    """A finished run's provenance from its exp_config.json `cfg` (read from `cfg_path`)."""
    versions = cfg.get("versions") or {}
    args = cfg.get("train_args") or {}
    return portable({
        "commit": versions.get("urb-jax source", NOT_RECORDED),
        "machine": cfg.get("machine") or NOT_RECORDED,
        "versions": versions or NOT_RECORDED,
        "command": " ".join(map(str, portable(cfg["command"]))) if cfg.get("command") else NOT_RECORDED,
        "request": args or NOT_RECORDED,
        "overrides": list(args.get("overrides") or (cfg.get("overrides") or {}).get("given") or []),
        "human_phase_from": cfg.get("human_phase_from"),
        # seeds trained in one program, and how (vmap or lax.map): XLA rounds a vmapped group otherwise
        "seeds_trained_together": cfg.get("group", NOT_RECORDED),
        "seed_axis": cfg.get("seed_axis_used", NOT_RECORDED),
        "wall_time_s": cfg.get("wall_time_s", NOT_RECORDED),
        "date": finished_date(cfg, cfg_path),
    })


def host(prov: Any) -> str:
    """A provenance's commit and machine in a line, for a report that sets two side by side."""
    if not isinstance(prov, dict):
        return f"commit {NOT_RECORDED}, machine {NOT_RECORDED}, finished {NOT_RECORDED}"
    m = prov.get("machine")
    where = m if not isinstance(m, dict) else (
        f"{m.get('cpu', '?')}, {m.get('cpu_count', '?')} cores, {m.get('backend', '?')}")
    commit, date = prov.get("commit", NOT_RECORDED), prov.get("date", NOT_RECORDED)
    return f"commit {commit}, machine {where}, finished {date}"
