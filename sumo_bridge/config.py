"""How a SUMO day is run: one frozen config shared by `run_day`, the pool and the CLI reference.

Semantics (see docs/sumo_bridge.md for the why):
* travel time (URB's): `(leave + tt_offset_s - scheduled_depart) / 60` minutes, where `leave` is
  SUMO's tripinfo `arrival` (or the removal second). RouteRL records an arrival one loop
  iteration after SUMO reports it, which is `arrival + 2 s`; `tt_offset_s=2` reproduces that.
* stuck vehicles: `stuck_rule="urb"` (default, cheap) removes any of our vehicles whose SUMO
  waiting time (consecutive seconds at or below 0.1 m/s) exceeds `stuck_time_s`, polling every
  vehicle only every `poll_every_s` and the few near the limit every second; `"routerl"` is
  RouteRL's literal rule (speed exactly 0 for more than `stuck_time_s` consecutive steps,
  checked every step on every vehicle: exact, slower); a vehicle creeping below 0.1 m/s restarts
  RouteRL's counter but not SUMO's waiting time, so "urb" removes a few seconds earlier.
  `"sumo"` uses SUMO's own `--time-to-teleport N --time-to-teleport.remove` (lane-front vehicles
  only). Removed vehicles are charged `stuck_penalty`: `"elapsed"` (time until removal, same
  convention as an arrival) or `"urb"` (URB's fixed `simulation_timesteps / 60`).
* `max_sim_time_s` is a hard cap: whatever is still driving (or waiting to be inserted) then is
  removed and charged like a stuck vehicle, so no day can run forever.
* `emissions`: SUMO's emission device on every vehicle (`--device.emissions.probability 1`), with
  SUMO's default emission class (HBEFA4/PC_petrol_Euro-4 in SUMO 1.28); each DayResult then carries
  per-vehicle CO2 (g) and fuel (mg, SUMO's unit). Off by default: the device costs ~14% of a
  saint_arnoult day's CPU time (benchmarks/emissions_cost.py; docs/sumo_bridge.md, "Emissions").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from urb_jax.city.network import DAY_LIMIT_S
from urb_jax.core.choices import STUCK_PENALTIES, STUCK_RULES
from urb_jax.core.errors import ConfigError
from urb_jax.core.ranges import Range, between, check_ranges

EMISSION_DEVICE = ("--device.emissions.probability", "1")  # SUMO's emission device on every vehicle


@dataclass(frozen=True)
class SumoConfig:
    stuck_rule: str = "urb"
    stuck_time_s: int = 600
    stuck_penalty: str = "elapsed"
    tt_offset_s: int = 2  # RouteRL's recording delay; 0 gives SUMO's arrival - scheduled depart
    max_sim_time_s: int = DAY_LIMIT_S  # hard cap on SUMO time per day (agents.csv is checked against it)
    poll_every_s: int = 100  # how often every vehicle's waiting time is polled (exactness kept)
    additional_files: tuple[str, ...] = ()  # extra SUMO additional files (e.g. detectors, tests)
    extra_args: tuple[str, ...] = field(default=())  # appended to SUMO's command line
    shm_dir: str = "/dev/shm"  # where route and tripinfo files live (RAM); falls back to /tmp
    emissions: bool = False  # per-vehicle CO2 and fuel from SUMO's emission device (DayResult.co2_g)

    RANGES: ClassVar[dict[str, Range]] = {
        "stuck_time_s": between(1, DAY_LIMIT_S), "tt_offset_s": between(0, 3600, "RouteRL: 2"),
        "max_sim_time_s": between(1, 7 * 86_400), "poll_every_s": between(1, DAY_LIMIT_S),
    }

    def __post_init__(self) -> None:
        check_ranges(self)
        if self.stuck_rule not in STUCK_RULES:
            raise ValueError(f"SumoConfig.stuck_rule={self.stuck_rule!r}: use one of {STUCK_RULES}")
        if self.stuck_penalty not in STUCK_PENALTIES:
            raise ValueError(
                f"SumoConfig.stuck_penalty={self.stuck_penalty!r}: use one of {STUCK_PENALTIES}"
            )
        if not isinstance(self.emissions, bool):  # a truthy string would switch the device on
            raise ConfigError(f"key 'emissions' is {self.emissions!r}. Fix: use true or false.")
        if any(a.startswith("--device.emissions") for a in self.extra_args):
            raise ConfigError("key 'extra_args' asks for SUMO's emission device itself. Fix: set "
                              "'emissions' true instead (the days then carry CO2 and fuel).")

    def sumo_args(self, seed: int) -> list[str]:
        """Options shared by libsumo days and the one-shot CLI reference (besides files)."""
        teleport = (
            ["--time-to-teleport", str(self.stuck_time_s), "--time-to-teleport.remove", "true"]
            if self.stuck_rule == "sumo"
            else ["--time-to-teleport", "-1"]
        )
        return [
            "--seed", str(int(seed)),
            "--step-length", "1",
            "--no-step-log", "true",
            *teleport,
            *(EMISSION_DEVICE if self.emissions else ()),
            *self.extra_args,
        ]
