"""urb_jax.training.hybrid.memory: a learner that would not fit is refused before training, with
the fix, instead of being found out by the kernel's OOM killer."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from support.fakeday import FakeExecutor

from urb_jax.core.errors import UrbJaxError
from urb_jax.runs.request import TrainRequest
from urb_jax.training.hybrid import memory

MB = 1024**2


def test_the_state_is_counted_from_shapes_and_compared_with_room_for_the_peak():
    state = {"w": jax.ShapeDtypeStruct((1024, 1024), np.float32), "n": jax.ShapeDtypeStruct((256,), np.int32)}
    assert memory.tree_bytes(state) == 4 * MB + 1024
    peak = memory.tree_bytes(state) * memory.PEAK_OVER_STATE  # one seed at its peak (16 MB and a bit)
    note = memory.check_fits(state, seeds=3, what="x", available=int(3 * peak) + 1)  # fits, just
    assert note.startswith("memory: the learner's state is 0.00 GB a seed") and "on this machine" in note
    with pytest.raises(UrbJaxError) as err:
        memory.check_fits(state, seeds=5, what="qmix on nowhere", available=int(2.5 * peak))
    text = str(err.value)  # 5 seeds' peaks > 2.5: 2 seeds at a time fit
    assert text.startswith("qmix on nowhere: the learner's state is 0.0 GB a seed")
    assert "Fix: --set hybrid.max_vmapped_seeds=2 (trains 2 seed(s) at a time)" in text
    with pytest.raises(UrbJaxError) as err:  # not even one seed: no max_vmapped_seeds to offer
        memory.check_fits(state, seeds=1, what="x", available=int(0.9 * peak))
    assert "max_vmapped_seeds" not in str(err.value) and "--alg-conf hybrid" in str(err.value)
    assert memory.available_bytes() > 0


def test_on_an_accelerator_its_own_free_memory_counts(monkeypatch):
    """A GPU's learner lives in the GPU's memory: JAX's memory_stats, not the host's MemAvailable."""

    class Gpu:
        device_kind = "NVIDIA H100 80GB HBM3"

        def memory_stats(self):
            return {"bytes_limit": 80 * 1024 * MB, "bytes_in_use": 30 * 1024 * MB, "peak_bytes_in_use": 1}

    monkeypatch.setattr(memory.jax, "devices", lambda: [Gpu()])
    assert memory.available_bytes() == 50 * 1024 * MB
    state = {"w": jax.ShapeDtypeStruct((1024, 1024, 1024), np.float32)}  # 4 GB a seed
    with pytest.raises(UrbJaxError, match=r"and the NVIDIA H100 80GB HBM3 has 50\.0 GB available"):
        memory.check_fits(state, seeds=5, what="x")  # 5 x 4 GB x PEAK_OVER_STATE > 50 GB


def test_a_run_that_would_not_fit_stops_before_training(tmp_path, monkeypatch):
    from urb_jax.runs.train import run_train

    monkeypatch.setattr(memory, "available_bytes", lambda: 1 * MB)
    hyb = {"train_days": 20, "num_envs": 2, "surrogate_days_per_round": 8, "sumo_days_per_round": 2,
           "sumo_workers": 1, "calib_human_days": 5, "calib_varied_days": 2, "calib_steps": 20,
           "refit_days": 4, "refit_steps": 5}
    (tmp_path / "hyb.json").write_text(json.dumps(hyb))
    with pytest.raises(UrbJaxError, match=r"and this machine has 0\.0 GB available"):
        run_train(TrainRequest(alg="iql", task_conf="test", hybrid_conf=str(tmp_path / "hyb.json"),
                               seeds=[0, 1], results_dir=str(tmp_path / "r"), progress=False),
                  executor=FakeExecutor())
    folders = sorted((tmp_path / "r").glob("iql_*"))
    assert folders and all(not (f / "checkpoints").exists() for f in folders)  # no training round ran
    assert (folders[0] / "human_phase.npz").is_file()  # what the error says --human-phase-from reuses


def _hidden_layers(x, w):  # [R, 256] @ [256, 256] twice: XLA must keep both activations for the gradient
    h = jax.numpy.tanh(x @ w)
    return jax.numpy.tanh(h @ w).sum()


def test_a_program_whose_temporaries_would_not_fit_is_refused_with_the_fix():
    """The learner's state can be small and a round's transient batch huge (IPPO on URB's frames):
    XLA's own count of the compiled program's temporaries is compared with the memory available."""
    rows = 20_000
    program = jax.jit(jax.grad(_hidden_layers, argnums=1)).lower(
        jax.ShapeDtypeStruct((rows, 256), np.float32), jax.ShapeDtypeStruct((256, 256), np.float32)).compile()
    need = memory.program_bytes(program)
    assert need is not None and need >= 2 * rows * 256 * 4  # at least the two [R, 256] activations
    memory.check_program_fits(program, "x", available=need)  # exactly enough: runs
    with pytest.raises(UrbJaxError) as err:
        memory.check_program_fits(program, "a round's surrogate iterations", available=need // 2)
    text = str(err.value)
    assert text.startswith("a round's surrogate iterations: its compiled program needs about")
    assert "--set hybrid.seed_axis=map" in text and "max_vmapped_seeds" in text


def test_a_round_too_big_for_memory_stops_before_it_runs(monkeypatch):
    """run_chunks checks each chunk's program when it compiles it, before the first iteration."""
    from urb_jax.training.hybrid.clock import IterationClock, run_chunks

    calls = []

    def step(c, keys):
        calls.append(1)
        return c + 1.0, {"m": keys[..., 0]}

    monkeypatch.setattr(memory, "available_bytes", lambda: 0)
    keys = jax.numpy.zeros((1, 4, 2), jax.numpy.uint32)
    with pytest.raises(UrbJaxError, match="its compiled program needs"):
        run_chunks(jax.jit(lambda c, k: jax.vmap(step)(c, k)), (jax.numpy.zeros(1),), keys,
                   IterationClock(4, 1, note=lambda s: None), {})
