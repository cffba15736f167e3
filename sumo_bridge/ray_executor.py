"""SUMO days on a Ray cluster: the `DayExecutor` interface of `SumoPool`, with Ray actors as workers.

Each actor is one process owning one libsumo simulation (libsumo allows one per process). Files
travel through Ray's object store, so nodes need not share a filesystem: the network file's bytes
(and those of `SumoConfig.additional_files`) are put once and written by each actor to its local
/dev/shm; the route table is rebuilt from the Scenario's arrays as in `SumoPool`. Days are spread
over the actors by `scheduler.schedule_days` (the pool's retry loop) and come back in the order
asked. An actor that dies, raises, or exceeds the per-day timeout is killed and replaced and its
day retried once; a second failure raises `SumoDayError` naming the day, the seed and the actor's
log, or `SumoOutOfMemoryError` where memory ran out (a MemoryError the actor sent back, or a task
Ray's memory monitor killed), as the pool does. Ray is imported only here and only
when a `RayExecutor` is built (install it with `pip install 'urb-jax[ray]'`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import glob
import ipaddress
import logging
import os
import shutil
import signal
import sys
import tempfile
import traceback
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, cast

import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.errors import UrbJaxError
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.sumo_bridge.keys import scenario_key, sumo_version
from urb_jax.sumo_bridge.logs import log_folder, log_tail
from urb_jax.sumo_bridge.scheduler import (
    DayJob,
    Failed,
    KeptScenarios,
    SumoDayError,
    memory_error_text,
    schedule_days,
)
from urb_jax.sumo_bridge.sim import Simulator
from urb_jax.sumo_bridge.types import DayResult

if TYPE_CHECKING:  # Ray is optional: its types only for annotations
    from ray import ObjectRef
    from ray.actor import ActorHandle

INSTALL_HINT = "pip install 'urb-jax[ray]'"
# Ray's switch for a single-node Ray (its default on macOS and Windows): the node's IP is 127.0.0.1
SINGLE_NODE_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
log = logging.getLogger(__name__)


def import_ray() -> ModuleType:
    """The `ray` module, or an error that says how to install it."""
    try:
        import ray  # here only: Ray is an optional extra
    except ImportError as exc:
        raise UrbJaxError(f"--executor ray needs Ray, which is not installed ({exc}). Fix: {INSTALL_HINT}"
                          ) from exc
    return ray


def loopback_only_ray() -> None:
    """Make the Ray this process is about to start listen on 127.0.0.1 only.

    Ray binds its servers (GCS, raylet, object manager, workers, agents, metrics) to the node's
    IP, and to every interface when that IP is not a loopback one; `ray.init(_node_ip_address=
    "127.0.0.1")` is replaced by the machine's outward IP. Ray's single-node switch makes the node
    IP 127.0.0.1. Ray reads it when it is imported, so it has to be set before (and it stays set
    for this process: a driver that later joins a cluster must be another process)."""
    if "ray" not in sys.modules:
        os.environ.setdefault(SINGLE_NODE_ENV, "0")


def _shm_base(config: SumoConfig) -> str:
    return config.shm_dir if os.path.isdir(config.shm_dir) else tempfile.gettempdir()


class SumoActor:
    """Body of one Ray actor: a Simulator plus the scenarios and files shipped to it."""

    def __init__(self, config: SumoConfig, log_path: str, extra_files: dict[str, bytes]) -> None:
        with contextlib.suppress(ValueError):  # the driver handles Ctrl-C and kills us
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        self.files = Path(tempfile.mkdtemp(prefix=f"urbjax-ray-{os.getpid()}-", dir=_shm_base(config)))
        try:  # same path as on the driver when the node shares it (local Ray), else a local temp file
            Path(log_path).parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
        except OSError:
            log_path = str(self.files / Path(log_path).name)
            fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
        self.log_path = log_path
        os.dup2(fd, 1)  # SUMO's messages (C-level stdout/stderr) go to this actor's log for good
        os.dup2(fd, 2)
        os.close(fd)
        adds = []
        for path in config.additional_files:  # shipped copies where the driver could read them
            data = extra_files.get(path)
            if data is None:
                adds.append(path)
                continue
            local = self.files / f"add{len(adds)}-{Path(path).name}"
            local.write_bytes(data)
            adds.append(str(local))
        self.sim = Simulator(dataclasses.replace(config, additional_files=tuple(adds)),
                             console_warnings=True)
        self.scenarios: KeptScenarios[Scenario] = KeptScenarios()

    def ready(self) -> tuple[int, str, str]:
        """(pid, node address, log path) once the Simulator is up."""
        ray = import_ray()  # Ray is optional: imported only inside an actor or a built executor
        return os.getpid(), ray.util.get_node_ip_address(), self.log_path

    def cleanup(self, pid: int, node: str) -> None:
        """Remove the /dev/shm files a killed actor `pid` left, if it lived on this node."""
        ray = import_ray()
        if node == ray.util.get_node_ip_address() and pid != os.getpid():
            base = _shm_base(self.sim.config)
            for d in (*glob.glob(f"{base}/urbjax-sumo-{pid}-*"), *glob.glob(f"{base}/urbjax-ray-{pid}-*")):
                shutil.rmtree(d, ignore_errors=True)

    def run_day(self, key: str, payload: tuple[Scenario, str, bytes] | None, choices: np.ndarray, seed: int,
                is_cav: np.ndarray | None, next_seed: int) -> tuple[str, DayResult | str]:
        try:
            if payload is not None:
                scn, name, data = payload
                net = self.files / key / name
                net.parent.mkdir(exist_ok=True)
                net.write_bytes(data)
                for gone in self.scenarios.add(key, dataclasses.replace(scn, net_file=str(net))):
                    shutil.rmtree(self.files / gone, ignore_errors=True)
            scn = self.scenarios[key]
            return "ok", self.sim.run_day(scn, choices, seed=seed, is_cav=is_cav, next_seed=next_seed)
        except MemoryError:
            return "oom", memory_error_text()
        except Exception:
            return "err", f"{traceback.format_exc()}\n--- SUMO log tail ({self.log_path}) ---\n" \
                          f"{log_tail(self.log_path)}"

    def close(self) -> None:
        self.sim.close()
        shutil.rmtree(self.files, ignore_errors=True)


@dataclasses.dataclass
class _Slot:
    """One actor as the driver sees it."""

    index: int
    actor: ActorHandle
    pid: int = 0
    node: str = ""
    log_path: str = ""
    scenarios: KeptScenarios[None] = dataclasses.field(default_factory=KeptScenarios)  # the actor's
    task: int | None = None
    ref: ObjectRef | None = None  # the day in flight
    started: float = 0.0
    finished: float = 0.0


class RayExecutor:
    """`n_actors` Ray actors running SUMO days; `address` None starts a local Ray, else connects.

    `address`: None = a new local Ray with `num_cpus or n_actors` CPUs (shut down again by
    `close()`), "auto" = the running cluster this machine belongs to, "ray://host:port" = a remote
    cluster through Ray Client. If Ray is already initialised in this process it is used as is and
    left running. Each actor reserves `actor_cpus` of Ray's logical CPUs (one: a day is one core).
    urb-jax must be importable on every node (installed there, or shipped with
    `runtime_env={"py_modules": [...]}`); data files need not be shared.
    """

    def __init__(self, n_actors: int = 2, config: SumoConfig | None = None,
                 log_dir: str | os.PathLike | None = None, day_timeout_s: float = 600.0,
                 start_timeout_s: float = 300.0, address: str | None = None, num_cpus: int | None = None,
                 runtime_env: dict | None = None, actor_cpus: float = 1.0) -> None:
        if n_actors < 1:
            raise ValueError("RayExecutor needs n_actors >= 1")
        if address is None:
            loopback_only_ray()
        ray = import_ray()
        self._ray = ray
        self.config = config or SumoConfig()
        self.day_timeout_s = float(day_timeout_s)
        self.start_timeout_s = float(start_timeout_s)
        self.log_dir, self._tmp = log_folder(log_dir, "urbjax-ray-logs-")
        self.owns_ray = not ray.is_initialized()
        if self.owns_ray:
            if address is None:
                # "local": a new instance even if RAY_ADDRESS or a `ray start` cluster exists
                ray.init(address="local", num_cpus=num_cpus or n_actors, include_dashboard=False,
                         dashboard_host="127.0.0.1", runtime_env=runtime_env, logging_level=logging.WARNING)
                _check_loopback(ray.util.get_node_ip_address())
            else:
                ray.init(address=address, runtime_env=runtime_env)
        extra = {}
        for path in self.config.additional_files:
            with contextlib.suppress(OSError):  # unreadable here: the actor tries the path itself
                extra[path] = Path(path).read_bytes()
        self._extra = ray.put(extra)
        self._cls = ray.remote(num_cpus=actor_cpus, max_restarts=0, max_task_retries=0)(SumoActor)
        self._payloads: dict[str, ObjectRef] = {}
        self.restarts = 0
        self.slots: list[_Slot] = []
        try:
            self.slots = [self._new(i) for i in range(n_actors)]
            for s in self.slots:
                self._wait_ready(s)
        except BaseException:
            self.close()
            raise

    # --- actors -------------------------------------------------------------------------
    @property
    def simulator(self) -> str:
        """What runs the days (part of every stored day's key): this process's `keys.sumo_version()`
        (the actors run the same environment, installed or shipped with `runtime_env`)."""
        return sumo_version()

    def _new(self, index: int) -> _Slot:
        log = str(self.log_dir / f"sumo_actor{index}.log")
        return _Slot(index, self._cls.remote(self.config, log, self._extra), log_path=log)

    def _wait_ready(self, s: _Slot) -> None:
        ray = self._ray
        try:
            s.pid, s.node, s.log_path = ray.get(s.actor.ready.remote(), timeout=self.start_timeout_s)
        except ray.exceptions.GetTimeoutError as exc:
            raise SumoDayError(f"Ray SUMO actor {s.index} did not start within {self.start_timeout_s:.0f} s "
                               "(not enough free CPUs in the cluster?); log "
                               f"{s.log_path}:\n{log_tail(s.log_path)}") from exc
        except ray.exceptions.RayError as exc:
            raise SumoDayError(f"Ray SUMO actor {s.index} failed to start: {exc}; log {s.log_path}:\n"
                               f"{log_tail(s.log_path)}") from exc

    def restart(self, s: _Slot) -> None:
        """Kill the actor and start a new one in its slot (a `scheduler.Workers` method)."""
        with contextlib.suppress(Exception):
            self._ray.kill(s.actor, no_restart=True)
        self.restarts += 1
        ns = self._new(s.index)
        self._wait_ready(ns)
        ns.actor.cleanup.remote(s.pid, s.node)  # the dead actor's /dev/shm files, if on the same node
        self.slots[s.index] = ns

    def _where(self, s: _Slot) -> str:
        return f"{s.log_path} on node {s.node}" if s.node else s.log_path

    def busy_pids(self) -> list[int]:
        """Process ids of actors running a day now (for fault-injection tests)."""
        return [s.pid for s in self.slots if s.task is not None]

    # --- days ---------------------------------------------------------------------------
    def put_scenario(self, scenario: Scenario) -> ObjectRef:
        """The object-store copy of a Scenario and its network file's bytes (read once per scenario)."""
        key = scenario_key(scenario)
        if key not in self._payloads:
            net = Path(scenario.net_file)
            self._payloads[key] = self._ray.put((scenario, net.name, net.read_bytes()))
        return self._payloads[key]

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        return schedule_days(self, scenario, choices, seeds, is_cav, day_timeout_s=self.day_timeout_s,
                             where=" on Ray")

    # --- the scheduler's backend (scheduler.Workers) ------------------------------------------
    def submit(self, s: _Slot, job: DayJob) -> Failed | None:
        send = None if job.key in s.scenarios else self.put_scenario(job.scenario)
        s.ref = s.actor.run_day.remote(job.key, send, job.choices, job.seed, job.is_cav, job.next_seed)
        if send is not None:
            s.scenarios.add(job.key, None)
        return None

    def wait(self, busy: list[_Slot], timeout: float) -> dict[int, DayResult | Failed]:
        ray = self._ray
        done, _ = ray.wait([s.ref for s in busy], num_returns=1, timeout=timeout)
        finished = set(done)
        out: dict[int, DayResult | Failed] = {}
        for s in busy:
            if s.ref not in finished:
                continue
            who = f"actor {s.index} (pid {s.pid})"
            try:
                kind, res = ray.get(s.ref)
            except ray.exceptions.OutOfMemoryError as exc:  # Ray's memory monitor killed the task
                out[s.index] = self._failed(s, f"{who} ran out of memory (Ray's memory monitor): "
                                               f"{_first_line(exc)}", memory=True)
            except ray.exceptions.RayActorError as exc:
                out[s.index] = self._failed(s, f"{who} died: {_first_line(exc)}",
                                            memory=_killed_for_memory(exc))
            except ray.exceptions.RayError as exc:
                out[s.index] = self._failed(s, f"{who} failed: {_first_line(exc)}")
            else:
                out[s.index] = self._answer(s, who, kind, res)
            s.ref = None
        return out

    def overdue(self, s: _Slot) -> Failed:
        return self._failed(s, f"actor {s.index} (pid {s.pid}) exceeded the {self.day_timeout_s:g} s "
                               "day limit")

    def _answer(self, s: _Slot, who: str, kind: str, res: DayResult | str) -> DayResult | Failed:
        """An actor's answer: its day, the MemoryError it ran into, or the error it raised (whose text
        already ends with the actor's log tail)."""
        if kind == "ok":
            return cast(DayResult, res)
        if kind == "oom":
            return self._failed(s, f"{who} ran out of memory (MemoryError):\n{res}", memory=True)
        return Failed(f"{who} raised:\n{res}", self._where(s))

    def _failed(self, s: _Slot, reason: str, memory: bool = False) -> Failed:
        where = self._where(s)
        return Failed(f"{reason}\n--- SUMO log tail ({where}) ---\n{log_tail(s.log_path)}", where, memory)

    def close(self) -> None:
        ray = self._ray
        for s in self.slots:
            if s.task is None:  # a busy actor (a day abandoned by Ctrl-C or an error) is killed at once
                with contextlib.suppress(Exception):
                    ray.get(s.actor.close.remote(), timeout=10)
            with contextlib.suppress(Exception):
                ray.kill(s.actor, no_restart=True)
        self.slots = []
        self._payloads = {}
        if self.owns_ray and ray.is_initialized():
            ray.shutdown()
        self.owns_ray = False
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> RayExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _check_loopback(node_ip: str) -> None:
    """Say so when a local Ray could not be kept on the loopback interface."""
    if not ipaddress.ip_address(node_ip).is_loopback:
        log.warning("the local Ray listens on %s, not only on 127.0.0.1 (ray was imported before the "
                    "RayExecutor was built, or %s is set to 1). Fix: set %s=0 before ray is imported, "
                    "or use --executor pool.", node_ip, SINGLE_NODE_ENV, SINGLE_NODE_ENV)


# What Ray says when its memory monitor, not a crash, ended an actor's task (Ray's generic "the
# process exited unexpectedly" text lists the OOM killer among possible causes for any death: not
# taken as proof).
_RAY_MEMORY_WORDS = ("low on memory", "memory pressure", "outofmemoryerror")


def _killed_for_memory(exc: BaseException) -> bool:
    """An actor's death that Ray attributes to memory running out."""
    text = str(exc).lower()
    return any(w in text for w in _RAY_MEMORY_WORDS)


def _first_line(exc: BaseException) -> str:
    lines = [ln for ln in str(exc).splitlines() if ln.strip()]
    return " ".join(lines[:3])[:500] if lines else type(exc).__name__
