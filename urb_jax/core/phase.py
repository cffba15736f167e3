"""What a run is doing now, for the message of a stop that has no better context: memory
exhaustion (a MemoryError, or XLA's RESOURCE_EXHAUSTED) ends a run with the phase it happened in
and what uses less memory, instead of a traceback; in a SUMO worker process, with SUMO's hint."""

from __future__ import annotations

_NOW = ["setup"]

MEMORY_HINT = ("To use less memory, start the run again (same command with --overwrite) with fewer "
               "parallel envs (--set hybrid.num_envs=N, or alg.num_envs for --mode sumo), seeds mapped "
               "instead of vmapped (--set hybrid.seed_axis=map) or fewer seeds trained together "
               "(--set hybrid.max_vmapped_seeds=1)")


SUMO_MEMORY_HINT = ("To use less memory in SUMO, start the run again (same command with --overwrite) with "
                    "fewer SUMO worker processes (--set hybrid.sumo_workers=N; each holds a whole "
                    "simulation of the network) or on a smaller network")


IN_PROCESS_MEMORY_HINT = ("SUMO shares this process with the learners: to use less memory, start the run "
                          "again (same command with --overwrite) on a smaller network, or with fewer "
                          "parallel envs (--set hybrid.num_envs=N) or seeds mapped instead of vmapped "
                          "(--set hybrid.seed_axis=map) so that JAX holds less beside it")


def enter_phase(name: str) -> None:
    """The run is now in phase `name` (e.g. "round 3: surrogate leg")."""
    _NOW[0] = name


def current_phase() -> str:
    return _NOW[0]


def is_out_of_memory(exc: BaseException) -> bool:
    """A MemoryError, an XLA runtime error whose status is RESOURCE_EXHAUSTED (an allocation
    that failed on the device or the host), or an error that carries its own `memory_hint` (memory
    ran out in a SUMO worker process: `sumo_bridge.scheduler`)."""
    if isinstance(exc, MemoryError) or getattr(exc, "memory_hint", None):
        return True
    names = {t.__name__ for t in type(exc).__mro__}
    return bool(names & {"XlaRuntimeError", "JaxRuntimeError"}) and "RESOURCE_EXHAUSTED" in str(exc)[:2000]


def memory_hint(exc: BaseException) -> str:
    """What uses less memory where `exc` ran out of it: the error's own hint, else MEMORY_HINT's."""
    return str(getattr(exc, "memory_hint", None) or MEMORY_HINT)
