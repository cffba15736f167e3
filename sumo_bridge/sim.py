"""One authoritative SUMO day through libsumo, in this process.

libsumo allows one simulation per process, so a `Simulator` owns it: the network is parsed by
`libsumo.load` once per day (SUMO has no cheaper exact reset: `loadState` diverges from a fresh
run), vehicles are added up front with their departure seconds (identical to RouteRL's
second-by-second `vehicle.add`, checked against the CLI), and per-vehicle results come from
SUMO's tripinfo output on /dev/shm. After the last step `libsumo.close()` closes the tripinfo
file (about a tenth of a load), and the next day's network is loaded by `preload()`: a pool
worker calls it after sending the day back, so the load overlaps the caller's next step instead
of delaying this day's result; otherwise the next day loads it. A day costs one network load, as
SUMO's one-shot CLI run does.
"""

from __future__ import annotations

import atexit
import contextlib
import io
import logging
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

import numpy as np

from urb_jax.city.demand import ABSENT
from urb_jax.city.scenario import Scenario
from urb_jax.sumo_bridge.batch import as_batch, cav_mask, check_choices
from urb_jax.sumo_bridge.config import SumoConfig
from urb_jax.sumo_bridge.keys import routes_key, sumo_version
from urb_jax.sumo_bridge.logs import redirect_fds
from urb_jax.sumo_bridge.scheduler import out_of_memory_in_process
from urb_jax.sumo_bridge.tripinfo import insertion_order, parse_tripinfo, route_id, write_routes_file
from urb_jax.sumo_bridge.types import ARRIVED, REMOVED_CAP, REMOVED_STUCK, STAYED_HOME, DayResult

# libsumo is one simulation per process: which Simulator's state it holds, if started at all.
_LIBSUMO: dict[str, object] = {"started": False, "owner": None}
log = logging.getLogger(__name__)
# The two lines libsumo/__init__.py prints when pyarrow's version differs from the libarrow
# libsumo was built against (its buildConfig.ARROW_SO_VERSION), e.g. pyarrow 26 and libarrow2300.
_ARROW_NOTICE = ("Warning! pyarrow is installed with version ",
                 " Try to uninstall pyarrow or install a matching pyarrow version")


def import_libsumo() -> ModuleType:
    """libsumo, imported without its pyarrow-version notice (every other line it prints is kept).

    The notice is harmless here: the libsumo wheel carries its own libarrow (auditwheel-renamed,
    libsumo.libs/libarrow-<hash>.so.2300), pyarrow loads its own libarrow.so.2600, and both are
    loaded locally by their extension modules, so neither resolves the other's symbols; SUMO uses
    arrow only to write .parquet outputs, and urb-jax asks for tripinfo XML (docs/sumo_bridge.md,
    "pyarrow and libsumo"). Pinning pyarrow to libsumo's build would only move the mismatch to the
    next SUMO release."""
    if "libsumo" in sys.modules:
        return sys.modules["libsumo"]
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            import libsumo
    finally:
        lines = printed.getvalue().splitlines(keepends=True)
        notice = [line for line in lines if line.startswith(_ARROW_NOTICE)]
        sys.stdout.write("".join(line for line in lines if not line.startswith(_ARROW_NOTICE)))
        if notice:
            log.debug("libsumo's pyarrow notice, not shown (harmless: import_libsumo): %s",
                      notice[0].strip())
    return libsumo


class Simulator:
    """Owns this process's libsumo simulation and runs days on it."""

    def __init__(self, config: SumoConfig | None = None, log_file: str | os.PathLike | None = None,
                 redirect_output: bool = True, console_warnings: bool = False) -> None:
        self.config = config or SumoConfig()
        self.log_file = str(log_file) if log_file else None
        self.redirect_output = redirect_output and self.log_file is not None
        self.console_warnings = console_warnings  # pool workers: their fds already go to a log
        base = self.config.shm_dir if os.path.isdir(self.config.shm_dir) else None
        self.workdir = Path(tempfile.mkdtemp(prefix=f"urbjax-sumo-{os.getpid()}-", dir=base))
        self._fresh: tuple | None = None  # load key of a loaded, not yet simulated state
        self._next: tuple | None = None  # load key `preload` loads (the last day's next day)
        self._trip_path: Path | None = None
        self._n_loads = 0
        atexit.register(shutil.rmtree, self.workdir, True)  # files only; libsumo ends with us

    # --- SUMO control -------------------------------------------------------------------
    def _routes_file(self, scenario: Scenario) -> Path:
        path = self.workdir / f"routes-{routes_key(scenario)}.add.xml"  # one for any day's departures
        if not path.exists():
            write_routes_file(path, scenario)
        return path

    def _load(self, key: tuple) -> None:
        libsumo = import_libsumo()
        net_file, routes, seed, _ = key
        self._n_loads += 1
        trip = self.workdir / f"trip-{self._n_loads}.xml"
        adds = ",".join([str(routes), *self.config.additional_files])
        args = ["-n", net_file, "-a", adds, "--tripinfo-output", str(trip),
                *self.config.sumo_args(seed)]
        if self.log_file and not self.redirect_output:
            args += ["--error-log", self.log_file]
        elif not self.log_file and not self.console_warnings:
            args += ["--no-warnings", "true"]  # no log given: keep warnings off the console
        if _LIBSUMO["started"]:
            libsumo.load(args)
        else:
            libsumo.start(["sumo", *args])
            _LIBSUMO["started"] = True
        _LIBSUMO["owner"] = self
        self._fresh = key
        self._trip_path = trip

    def _close_libsumo(self) -> None:
        """End the simulation this Simulator holds (its outputs, the tripinfo, are closed)."""
        if _LIBSUMO["owner"] is self:
            with contextlib.suppress(Exception):
                import_libsumo().close()
            _LIBSUMO["started"], _LIBSUMO["owner"] = False, None
        self._fresh = None

    def preload(self) -> None:
        """Load the network for the next day `run_day` named (`next_seed`), if one is named and not
        loaded yet: what a pool worker does while its result travels back. A failed load is left to
        that day, which loads again and reports the error as its own."""
        key, self._next = self._next, None
        if key is None:
            return
        try:
            with redirect_fds(self.log_file if self.redirect_output else None):
                self._load(key)
        except Exception:  # the day that needs this state loads again and reports it
            self._fresh = None

    def close(self) -> None:
        self._close_libsumo()
        self._next = None
        shutil.rmtree(self.workdir, ignore_errors=True)

    # --- one day ------------------------------------------------------------------------
    def run_day(self, scenario: Scenario, choices: np.ndarray, *, seed: int,
                is_cav: np.ndarray | None = None, next_seed: int | None = None) -> DayResult:
        """One day; `next_seed` (default: `seed`) is the seed `preload` loads the next day with."""
        with redirect_fds(self.log_file if self.redirect_output else None):
            return self._run_day(scenario, choices, seed, is_cav, seed if next_seed is None else next_seed)

    def _run_day(self, scn: Scenario, choices: np.ndarray, seed: int,
                 is_cav: np.ndarray | None, next_seed: int) -> DayResult:
        libsumo = import_libsumo()
        t0 = time.perf_counter()
        cfg = self.config
        choices = check_choices(scn, choices)
        cav = cav_mask(scn, is_cav)
        # everything the loaded state depends on (the config may be swapped between days)
        key = (str(scn.net_file), str(self._routes_file(scn)), int(seed),
               (cfg.additional_files, tuple(cfg.sumo_args(0))))
        if self._fresh != key or _LIBSUMO["owner"] is not self:
            self._load(key)
        self._fresh = None
        trip_path = self._trip_path
        assert trip_path is not None

        ids = [str(int(a)) for a in scn.agent_id]
        depart = np.asarray(scn.agent_depart, dtype=np.int64)
        last_depart = int(depart.max())
        if cfg.max_sim_time_s <= last_depart:
            raise ValueError(f"SumoConfig.max_sim_time_s={cfg.max_sim_time_s} must exceed the last "
                             f"departure ({last_depart} s)")
        add = libsumo.vehicle.add
        home = choices == ABSENT  # [N] drivers who stay home today: no vehicle
        for i in insertion_order(depart, cav):
            if not home[i]:
                add(ids[i], route_id(scn.agent_od[i], choices[i]), typeID="AV" if cav[i] else "Human",
                    depart=str(int(depart[i])))
        pos = {v: i for i, v in enumerate(ids) if not home[i]}
        removed = _DaySteps(libsumo, cfg, pos, last_depart).run()

        end_time = libsumo.simulation.getTime()
        teleports = int(float(libsumo.simulation.getParameter("", "stats.teleports.total")))
        self._close_libsumo()  # closes this day's tripinfo
        self._next = (*key[:2], int(next_seed), key[3])
        trips = parse_tripinfo(trip_path)
        trip_path.unlink(missing_ok=True)
        return self._result(scn, trips, removed, pos, depart, seed, teleports, end_time,
                            time.perf_counter() - t0, home)

    def _result(self, scn: Scenario, trips: dict, removed: dict, pos: dict, depart: np.ndarray,
                seed: int, teleports: int, end_time: float, wall: float, home: np.ndarray) -> DayResult:
        """The day's DayResult; `pos`: the inserted vehicles' rows, `home` [N]: who stayed home
        (no vehicle: STAYED_HOME, every time NaN, in no statistic)."""
        cfg = self.config
        n = scn.n_agents
        nan = np.full(n, np.nan)
        leave, dur, length, loss, delay = nan.copy(), nan.copy(), nan.copy(), nan.copy(), nan.copy()
        status = np.full(n, REMOVED_CAP, dtype=np.int8)  # overwritten for every vehicle seen
        seen = np.zeros(n, dtype=bool)
        for v, rec in trips.items():
            i = pos.get(v)
            if i is None:
                continue
            seen[i] = True
            leave[i] = rec["arrival"]
            length[i] = rec["routeLength"]
            loss[i] = rec["timeLoss"]
            delay[i] = rec["departDelay"]
            if rec["vaporized"]:
                status[i] = removed.get(v, (0.0, REMOVED_STUCK))[1]  # SUMO's teleport-removal
            else:
                status[i] = ARRIVED
                dur[i] = rec["duration"]
        for v, (t, st) in removed.items():  # removed before SUMO wrote a tripinfo (never inserted)
            i = pos[v]
            if not seen[i]:
                leave[i], status[i], length[i], loss[i] = t, st, 0.0, np.nan
                delay[i] = t - depart[i]
        missing = ~seen & np.isnan(leave) & ~home
        if missing.any() and end_time >= cfg.max_sim_time_s:  # still waiting at the cap
            leave[missing], status[missing], length[missing] = end_time, REMOVED_CAP, 0.0
            delay[missing] = end_time - depart[missing]
        elif missing.any():
            raise RuntimeError(f"{int(missing.sum())} vehicle(s) have no SUMO result, e.g. "
                               f"{[k for k, i in pos.items() if missing[i]][:5]}")
        status[home] = STAYED_HOME
        tt = (leave + cfg.tt_offset_s - depart) / 60.0
        out = (status != ARRIVED) & ~home  # removed
        if cfg.stuck_penalty == "urb":
            tt[out] = scn.simulation_timesteps / 60.0
        arrived = status == ARRIVED
        with np.errstate(invalid="ignore", divide="ignore"):
            speed = np.where(arrived, length / dur, np.nan)
        # SUMO's statistic output averages over every vehicle with a tripinfo (removed included).
        w = seen
        trip_dur = np.where(arrived, dur, leave - (depart + delay))
        return DayResult(
            travel_time=tt, duration=dur, route_length=length, mean_speed=speed, time_loss=loss,
            depart_delay=delay, status=status, seed=int(seed),
            stat_mean_speed=float(np.mean(length[w] / np.maximum(trip_dur[w], 1e-9))) if w.any() else 0.0,
            stat_mean_route_length=float(np.mean(length[w])) if w.any() else 0.0,
            stat_mean_duration=float(np.mean(trip_dur[w])) if w.any() else 0.0,
            teleports=teleports, n_removed=int(out.sum()), sim_end_time=float(end_time),
            wall_time=float(wall), leave_time=leave,
            **(_emissions(trips, pos) if cfg.emissions else {}),
        )


def _emissions(trips: dict, pos: dict[str, int]) -> dict[str, np.ndarray]:
    """co2_g and fuel_mg [N] from the tripinfo's emission children (SUMO gives mg of each); NaN for
    a vehicle with no tripinfo (removed before SUMO inserted it). A tripinfo without the child
    means the device did not run: an error, not a silent zero."""
    co2, fuel = np.full(len(pos), np.nan), np.full(len(pos), np.nan)
    for v, rec in trips.items():
        i = pos.get(v)
        if i is None:
            continue
        if "CO2_abs" not in rec:
            raise RuntimeError(f"SumoConfig.emissions is on, but vehicle {v}'s tripinfo has no emissions")
        co2[i], fuel[i] = rec["CO2_abs"] / 1000.0, rec["fuel_abs"]
    return {"co2_g": co2, "fuel_mg": fuel}


class _DaySteps:
    """SUMO's steps of one loaded day, and the stuck rule that removes our vehicles on the way.

    `"urb"` polls every vehicle's waiting time every `poll_every_s` and, between polls, only the
    few that could pass `stuck_time_s` before the next; `"routerl"` is RouteRL's check, every step,
    of every vehicle of ours driving (speed exactly 0 for more than `stuck_time_s` steps); `"sumo"`
    leaves removal to SUMO's teleport option. `max_sim_time_s` removes whatever is left."""

    def __init__(self, libsumo: ModuleType, cfg: SumoConfig, pos: dict[str, int], last_depart: int) -> None:
        self.libsumo, self.vehicle, self.simulation = libsumo, libsumo.vehicle, libsumo.simulation
        self.pos, self.last_depart = pos, last_depart  # our vehicles' ids -> agent index
        self.stuck, self.poll, self.cap = cfg.stuck_time_s, cfg.poll_every_s, cfg.max_sim_time_s
        self.urb_rule, self.exact_rule = cfg.stuck_rule == "urb", cfg.stuck_rule == "routerl"
        self.speed_var = libsumo.constants.VAR_SPEED
        self.removed: dict[str, tuple[float, int]] = {}  # id -> (SUMO time, status)
        self.zero_steps: dict[str, int] = {}  # "routerl": consecutive observations at speed 0
        self.watch: set[str] = set()  # "urb": vehicles checked every step until the next poll
        self.t = self.simulation.getTime()

    def run(self) -> dict[str, tuple[float, int]]:
        """Steps until none of our vehicles is left (or only foreign ones drive); the removed."""
        next_poll = 0.0
        while True:
            if self.exact_rule:
                self._count_zero_speeds()
            if self.t >= next_poll:
                if self._poll():
                    break  # only foreign vehicles left (e.g. a test's blocker)
                next_poll = self.t + self.poll
            elif self.watch:
                self._check_watched()
            if self.t >= self.cap:
                self._remove_at_cap()
                break
            self.libsumo.simulationStep()
            self.t = self.simulation.getTime()
            if self.exact_rule:
                self._watch_speeds_of_departed()
            if self.simulation.getMinExpectedNumber() == 0:
                break
        return self.removed

    def _remove(self, v: str, status: int) -> None:
        self.removed[v] = (self.t, status)
        if self.exact_rule and v in self.zero_steps:
            self.vehicle.unsubscribe(v)  # libsumo fails the next step on a removed subscribed vehicle
        self.vehicle.remove(v, self.libsumo.constants.REMOVE_VAPORIZED)

    def _count_zero_speeds(self) -> None:
        for v, r in self.vehicle.getAllSubscriptionResults().items():
            if r[self.speed_var] == 0:
                self.zero_steps[v] = self.zero_steps.get(v, 0) + 1
                if self.zero_steps[v] > self.stuck:
                    self._remove(v, REMOVED_STUCK)
            else:
                self.zero_steps[v] = 0

    def _watch_speeds_of_departed(self) -> None:
        for v in self.simulation.getDepartedIDList():
            if v in self.pos:
                self.vehicle.subscribe(v, [self.speed_var])

    def _poll(self) -> bool:
        """The periodic check: URB's waiting times, then whether only foreign vehicles are left."""
        running = self.vehicle.getIDList()
        if self.urb_rule:
            self.watch = set()
            for v in running:
                if v in self.pos:
                    w = self.vehicle.getWaitingTime(v)
                    if w > self.stuck:
                        self._remove(v, REMOVED_STUCK)
                    elif w + self.poll > self.stuck:
                        self.watch.add(v)
        return (self.t > self.last_depart
                and not any(v in self.pos and v not in self.removed for v in running)
                and not any(v in self.pos for v in self.simulation.getPendingVehicles()))

    def _check_watched(self) -> None:
        for v in list(self.watch):
            try:
                w = self.vehicle.getWaitingTime(v)
            except self.libsumo.TraCIException:  # arrived meanwhile
                self.watch.discard(v)
                continue
            if w > self.stuck:
                self._remove(v, REMOVED_STUCK)
                self.watch.discard(v)

    def _remove_at_cap(self) -> None:
        for v in (*self.vehicle.getIDList(), *self.simulation.getPendingVehicles()):
            if v in self.pos and v not in self.removed:
                self._remove(v, REMOVED_CAP)


_SIMULATOR: Simulator | None = None


def get_simulator(config: SumoConfig | None = None, log_file: str | os.PathLike | None = None) -> Simulator:
    """This process's Simulator (libsumo allows one), created or re-configured on demand."""
    global _SIMULATOR
    config = config or SumoConfig()
    log = str(log_file) if log_file else None
    if _SIMULATOR is None or _SIMULATOR.config != config or _SIMULATOR.log_file != log:
        if _SIMULATOR is not None:
            _SIMULATOR.close()
        _SIMULATOR = Simulator(config, log)
    return _SIMULATOR


def run_day(scenario: Scenario, choices: np.ndarray, *, seed: int, is_cav: np.ndarray | None = None,
            config: SumoConfig | None = None, log_file: str | os.PathLike | None = None) -> DayResult:
    """One SUMO day in this process: `choices[N]` route indices in the Scenario's agent order."""
    return get_simulator(config, log_file).run_day(scenario, choices, seed=seed, is_cav=is_cav)


def run_days(scenario: Scenario, choices: np.ndarray, seeds: int | Sequence[int] | np.ndarray | None = None,
             *, is_cav: np.ndarray | None = None, config: SumoConfig | None = None,
             log_file: str | os.PathLike | None = None) -> list[DayResult]:
    """SUMO days one after another in this process: `choices[B, N]`, seeds one or one per day
    (default the Scenario's env seed, as URB runs every day), `is_cav` [N] or [B, N]. No worker
    process is started, so a script needs no `if __name__ == "__main__"` guard (`SumoPool` does:
    its workers are spawned, and spawn re-runs the calling script)."""
    seeds = scenario.env_seed if seeds is None else seeds
    return _days_on(get_simulator(config, log_file), scenario, choices, seeds, is_cav)


def _days_on(sim: Simulator, scenario: Scenario, choices: np.ndarray, seeds: int | Sequence[int] | np.ndarray,
             is_cav: np.ndarray | None) -> list[DayResult]:
    """A batch of days on one Simulator, each pre-loading the next day's seed."""
    batch = as_batch(choices, seeds, is_cav)
    seeds = batch.seeds
    nxt = [*seeds[1:], seeds[-1]] if seeds else []
    return [sim.run_day(scenario, c, seed=s, is_cav=m, next_seed=n)
            for c, s, m, n in zip(batch.choices, seeds, batch.cavs, nxt, strict=True)]


class InProcessExecutor:
    """The `DayExecutor` without workers: days one after another on this process's own Simulator."""

    def __init__(self, config: SumoConfig | None = None, log_file: str | os.PathLike | None = None) -> None:
        self.sim = Simulator(config, log_file)

    @property
    def config(self) -> SumoConfig:
        return self.sim.config

    @property
    def simulator(self) -> str:
        """What runs the days (part of every stored day's key): `keys.sumo_version()`."""
        return sumo_version()

    def run_days(self, scenario: Scenario, choices: np.ndarray, seeds: list[int] | np.ndarray,
                 is_cav: np.ndarray | None = None) -> list[DayResult]:
        try:
            return _days_on(self.sim, scenario, choices, seeds, is_cav)
        except MemoryError as exc:  # in the trainer's own process: SUMO's and JAX's hints both apply
            raise out_of_memory_in_process(scenario, exc) from None

    def close(self) -> None:
        self.sim.close()
