"""How a SUMO day is run: one frozen config shared by `run_day`, the pool and the CLI reference.

Semantics (see docs/sumo_bridge.md for the why):
* travel time (URB's): `(leave + tt_offset_s - scheduled_depart) / 60` minutes, where `leave` is
  SUMO's tripinfo `arrival` (or the removal second). RouteRL records an arrival one loop
  iteration after SUMO reports it, which is `arrival + 2 s`; `tt_offset_s=2` reproduces that.
* stuck vehicles: `stuck_rule="urb"` removes any vehicle whose SUMO waiting time (consecutive
  seconds below 0.1 m/s) exceeds `stuck_time_s` (RouteRL: speed == 0 for more than 600 steps);
  `"sumo"` uses SUMO's own `--time-to-teleport N --time-to-teleport.remove` (lane-front vehicles
  only). Removed vehicles are charged `stuck_penalty`: `"elapsed"` (time until removal, same
  convention as an arrival) or `"urb"` (URB's fixed `simulation_timesteps / 60`).
* `max_sim_time_s` is a hard cap: whatever is still driving (or waiting to be inserted) then is
  removed and charged like a stuck vehicle, so no day can run forever.
"""

from __future__ import annotations

from dataclasses import dataclass, field

STUCK_RULES = ("urb", "sumo")
STUCK_PENALTIES = ("elapsed", "urb")


@dataclass(frozen=True)
class SumoConfig:
    stuck_rule: str = "urb"
    stuck_time_s: int = 600
    stuck_penalty: str = "elapsed"
    tt_offset_s: int = 2  # RouteRL's recording delay; 0 gives SUMO's arrival - scheduled depart
    max_sim_time_s: int = 6 * 3600  # hard cap on SUMO time per day
    poll_every_s: int = 50  # how often every vehicle's waiting time is polled (exactness kept)
    additional_files: tuple[str, ...] = ()  # extra SUMO additional files (e.g. detectors, tests)
    extra_args: tuple[str, ...] = field(default=())  # appended to SUMO's command line
    shm_dir: str = "/dev/shm"  # where route and tripinfo files live (RAM); falls back to /tmp

    def __post_init__(self) -> None:
        if self.stuck_rule not in STUCK_RULES:
            raise ValueError(f"SumoConfig.stuck_rule={self.stuck_rule!r}: use one of {STUCK_RULES}")
        if self.stuck_penalty not in STUCK_PENALTIES:
            raise ValueError(
                f"SumoConfig.stuck_penalty={self.stuck_penalty!r}: use one of {STUCK_PENALTIES}"
            )
        if self.stuck_time_s <= 0 or self.poll_every_s <= 0 or self.max_sim_time_s <= 0:
            raise ValueError("SumoConfig: stuck_time_s, poll_every_s and max_sim_time_s must be > 0")

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
            *self.extra_args,
        ]
