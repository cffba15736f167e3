"""Multi-seed training under vmap and human-phase reuse, on urb_grid with the FakeDay stand-in for
SUMO (tests/support/fakeday.py) and a short budget (3 rounds of 4 surrogate env-days + 2 SUMO days)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from support.fakeday import FakeExecutor
from support.tiny_runs import H

from urb_jax.core.errors import UrbJaxError
from urb_jax.core.interrupt import InterruptedRunError
from urb_jax.reporting.records import read_records
from urb_jax.runs.request import ResumeRequest, TrainRequest
from urb_jax.runs.train import resume_train, run_train
from urb_jax.training.checkpoints import latest_checkpoint

P, ROUNDS = 2, 3


def _train(confs, root, exp_id, executor, stop_after_round=None, **kw):
    req = TrainRequest(alg="iql", exp_id=exp_id, results_dir=str(root), progress=False, **confs, **kw)
    return run_train(req, executor=executor, stop_after_round=stop_after_round)


def _metrics(folder):
    return pd.read_csv(folder / "metrics" / "BenchmarkMetrics.csv")


def _with_conf(confs, tmp_path, **hyb):
    cfg = json.loads(Path(confs["hybrid_conf"]).read_text()) | hyb
    path = tmp_path / "hyb_override.json"
    path.write_text(json.dumps(cfg))
    return confs | {"hybrid_conf": str(path)}


@pytest.fixture(scope="module")
def pair(confs, tmp_path_factory):
    """The reference: seeds 0 and 1 trained together (vmapped), uninterrupted."""
    root = tmp_path_factory.mktemp("pair")
    ex = FakeExecutor()
    outs = _train(confs, root, "pair", ex, seeds=[0, 1])
    return {"root": root, "outs": outs, "executor": ex}


@pytest.mark.slow
def test_vmapped_seeds_equal_seeds_trained_alone(pair, confs, tmp_path):
    """Each seed of a vmapped 2-seed run gets exactly the SUMO choices, records and metrics of the
    same seed trained alone (`max_vmapped_seeds: 1` trains the two seeds one after another, each a
    group of one). Exact equality holds because every seed's randomness flows from its own key, no
    computation mixes seeds, and at these shapes XLA's batched CPU kernels round like the unbatched
    ones. At ingolstadt's shapes (414 per-CAV networks) they do not, and training amplifies the
    last-bit differences (docs/hybrid.md, "Equivalence"); a mixing bug would fail here, rounding
    at large shapes cannot."""
    ex = FakeExecutor()
    alone = _train(_with_conf(confs, tmp_path, max_vmapped_seeds=1), tmp_path, "alone", ex, seeds=[0, 1])
    together = pair["outs"]
    # One human phase for both seeds, the same in both runs: at most H single-day human batches
    # (a day repeating an earlier one is read back) and the calibration days.
    human = [[b for b, cav in e.batches if cav is None] for e in (pair["executor"], ex)]
    assert len(human[0]) == len(human[1]) and all(np.array_equal(a, b) for a, b in zip(*human, strict=True))
    assert sum(len(b) for b in human[0]) <= H + 2
    # Vmapped: each round's (and each test chunk's) days of both seeds go out as one batch of 2 x P;
    # then one AON reference day per group.
    cav_batches = [len(b) for b, cav in pair["executor"].batches if cav is not None]
    assert cav_batches == [2 * P] * (ROUNDS + 10 // P) + [1]
    assert [len(b) for b, cav in ex.batches if cav is not None] == ([P] * (ROUNDS + 10 // P) + [1]) * 2
    for a, b in zip(together, alone, strict=True):
        cfg_a = json.loads((a.folder / "exp_config.json").read_text())
        cfg_b = json.loads((b.folder / "exp_config.json").read_text())
        assert cfg_a["seeds_together"] == 2 and cfg_b["seeds_together"] == 1
        assert cfg_a["group"] == ["pair_s0", "pair_s1"]
        pd.testing.assert_frame_equal(read_records(a.folder), read_records(b.folder))
        pd.testing.assert_frame_equal(_metrics(a.folder), _metrics(b.folder))
        cols = ["sur_time_cav", "sumo_time_cav", "surrogate_mape"]
        pd.testing.assert_frame_equal(pd.read_csv(a.folder / "rounds.csv")[cols],
                                      pd.read_csv(b.folder / "rounds.csv")[cols])
    # the CLI's one-line seed summary, against each seed's written metrics and AON reference day
    from urb_jax.commands.train import seed_summary

    t = [float(_metrics(o.folder)["t_CAV"].iloc[0]) for o in together]
    aon = [json.loads((o.folder / "exp_config.json").read_text())["aon_same_humans"]["t_CAV"]
           for o in together]
    assert aon[0] == aon[1]  # one AON day per group: both seeds share the test humans
    wins = sum(float(_metrics(o.folder)["winrate"].iloc[0]) for o in together)
    dur = [float(_metrics(o.folder)["t_CAV_duration"].iloc[0]) for o in together]
    assert seed_summary(together) == (
        f"2 seeds: t_CAV {np.mean(t):.4f} (sd {np.std(t, ddof=1):.4f}), at or below AON "
        f"{sum(x <= aon[0] for x in t)}/2, below t_pre {wins:.0f}/2; "
        f"in SUMO duration t_CAV {np.mean(dur):.4f}")
    assert seed_summary(together[:1]) is None
    r0, r1 = (read_records(o.folder) for o in together)
    assert not np.array_equal(r0[r0["day"] > H]["action"], r1[r1["day"] > H]["action"])  # seeds differ


@pytest.mark.slow
def test_mapped_seeds_equal_vmapped_seeds(pair, confs, tmp_path):
    """`seed_axis: map` (a big learner's default: lax.map runs the seeds one after another in the
    program) trains each seed as the vmapped group does, at these shapes to the last bit, and the
    run records which axis it used; `auto` keeps this small learner vmapped."""
    mapped = _train(_with_conf(confs, tmp_path, seed_axis="map"), tmp_path, "mapped", FakeExecutor(),
                    seeds=[0, 1])
    for a, b in zip(pair["outs"], mapped, strict=True):
        pd.testing.assert_frame_equal(read_records(a.folder), read_records(b.folder))
        pd.testing.assert_frame_equal(_metrics(a.folder), _metrics(b.folder))
        assert json.loads((a.folder / "exp_config.json").read_text())["seed_axis_used"] == "vmap"
        assert json.loads((b.folder / "exp_config.json").read_text())["seed_axis_used"] == "map"


def test_auto_maps_the_seeds_of_a_big_learner_on_a_cpu_only():
    import jax
    import jax.numpy as jnp

    from urb_jax.training.hybrid.fns import MAP_SEEDS_PARAMS, maps_seeds

    big = {"w": jax.ShapeDtypeStruct((MAP_SEEDS_PARAMS + 1,), jnp.float32)}
    small = {"w": jax.ShapeDtypeStruct((MAP_SEEDS_PARAMS,), jnp.float32)}
    assert maps_seeds("auto", big, "cpu") and not maps_seeds("auto", small, "cpu")
    assert maps_seeds("auto", big) == (jax.default_backend() == "cpu")
    # on a GPU vmapped seeds ran faster than mapped ones at every size measured (fns.MAP_SEEDS_PARAMS)
    assert not maps_seeds("auto", big, "gpu") and not maps_seeds("auto", big, "tpu")
    for backend in ("cpu", "gpu"):  # an explicit choice holds on any backend
        assert maps_seeds("map", small, backend) and not maps_seeds("vmap", big, backend)


@pytest.mark.slow
def test_a_run_resumes_with_the_seed_axis_it_started_with(confs, tmp_path, monkeypatch):
    """A run started before `seed_axis` existed vmapped its seeds: resumed, it still does, even
    where `auto` would now map them (here every learner counts as big)."""
    from urb_jax.training.hybrid import fns

    killed = _train(confs, tmp_path, "old", FakeExecutor(), seeds=[0, 1], stop_after_round=1)
    monkeypatch.setattr(fns, "MAP_SEEDS_PARAMS", 0)
    for out in killed:  # as such a run's exp_config.json reads
        config = json.loads((out.folder / "exp_config.json").read_text())
        del config["hybrid_seed_axis"], config["content_sha256"]  # nor had it a digest
        (out.folder / "exp_config.json").write_text(json.dumps(config))
    resumed = resume_train(ResumeRequest("old_s0", results_dir=str(tmp_path), progress=False),
                           executor=FakeExecutor())
    fresh = _train(confs, tmp_path, "new", FakeExecutor(), seeds=[0, 1])
    assert [json.loads((o.folder / "exp_config.json").read_text())["seed_axis_used"]
            for o in resumed + fresh] == ["vmap", "vmap", "map", "map"]


@pytest.mark.slow
def test_multi_seed_resume_after_kill_mid_round(pair, confs, tmp_path):
    """A 2-seed run killed in the middle of round 2's SUMO batch, resumed by the second seed's id,
    ends with both seeds' records and metrics equal to the uninterrupted run. The reference run's
    executor calls end: round 2, round 3, 10 // P test batches, the AON day (before them: the
    varied calibration batch and the distinct human days, a number that depends on the repeats)."""
    round2 = len(pair["executor"].batches) - 10 // P - 2
    with pytest.raises(InterruptedRunError, match="Continue with: urb-jax train --resume"):
        _train(confs, tmp_path, "pair", FakeExecutor(fail_on_call=round2), seeds=[0, 1])
    lead, other = tmp_path / "pair_s0", tmp_path / "pair_s1"
    assert latest_checkpoint(lead)[0] == 1  # the group checkpoint lives in the first folder
    assert not (other / "checkpoints").exists()
    meta = json.loads((lead / "checkpoints" / "round_00001" / "meta.json").read_text())
    assert meta["seeds"] == [0, 1] and len(meta["record_parts"]) == 2
    ex = FakeExecutor()
    finals = resume_train(ResumeRequest("pair_s1", results_dir=str(tmp_path), progress=False), executor=ex)
    assert [len(b) for b, _ in ex.batches] == [2 * P] * (ROUNDS - 1 + 10 // P) + [1]  # rounds 2-3, test, AON
    for final, ref in zip(finals, pair["outs"], strict=True):
        assert final.folder.name == ref.folder.name
        pd.testing.assert_frame_equal(read_records(final.folder), read_records(ref.folder))
        pd.testing.assert_frame_equal(_metrics(final.folder), _metrics(ref.folder))


@pytest.mark.slow
def test_human_phase_reuse_equals_own_human_phase(pair, confs, tmp_path):
    """Reusing pair_s0's human phase: no human or calibration day reaches the executor, and the
    records and metrics equal pair_s0's (which simulated its own)."""
    import shutil

    src = pair["outs"][0].folder
    shutil.copytree(src, tmp_path / "src")
    ex = FakeExecutor()
    (out,) = _train(confs, tmp_path, "reused", ex, seeds=[0], human_phase_from="src")
    assert all(cav is not None for _, cav in ex.batches)  # only CAV days (training and test) ran
    assert len(ex.batches) == ROUNDS + 10 // P + 1  # + the AON reference day
    pd.testing.assert_frame_equal(read_records(out.folder), read_records(src))
    pd.testing.assert_frame_equal(_metrics(out.folder), _metrics(src))
    assert json.loads((out.folder / "exp_config.json").read_text())["human_phase_from"] == "src"


def test_human_phase_reuse_refuses_a_different_phase(confs, tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    (src / "exp_config.json").write_text(json.dumps({"network": "urb_grid", "env_seed": 7}))
    with pytest.raises(UrbJaxError, match=r"env_seed \(source 7, this run 42\)"):
        _train(confs, tmp_path, "bad", FakeExecutor(), human_phase_from="src")
    with pytest.raises(UrbJaxError, match="not found"):
        _train(confs, tmp_path, "bad2", FakeExecutor(), human_phase_from="nowhere")
    assert not (tmp_path / "bad").exists() and not (tmp_path / "bad2").exists()  # refused before any folder


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["records.parquet", "human_phase.npz", "exp_config.json"])
def test_human_phase_reuse_refuses_a_damaged_source_naming_the_file(pair, confs, tmp_path, damage):
    """A byte flipped in the source's records or human phase, or a value of its exp_config.json
    edited: refused before any folder or SUMO day, naming the file."""
    import shutil

    src = tmp_path / "src"
    shutil.copytree(pair["outs"][0].folder, src)
    path = src / damage
    if damage == "exp_config.json":
        path.write_text(path.read_text().replace('"env_seed": 42', '"env_seed": 41'))
    else:
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(data))
    ex = FakeExecutor()
    with pytest.raises(UrbJaxError, match=f"{path}: (does not match its digest|its content does not match)"):
        _train(confs, tmp_path, "reuse", ex, seeds=[0], human_phase_from="src")
    assert ex.batches == [] and not (tmp_path / "reuse").exists()


@pytest.mark.slow
def test_a_resume_refuses_an_algorithm_config_edited_since_the_start(confs, tmp_path):
    """The algorithm config file a run started with, edited before its resume: refused naming
    alg.<key> with the value recorded and the value read now, before any SUMO day."""
    (killed,) = _train(confs, tmp_path, "alg_edit", FakeExecutor(), seeds=[0], stop_after_round=1)
    alg = Path(confs["alg_conf"])
    original = alg.read_text()
    try:
        alg.write_text(json.dumps(json.loads(original) | {"num_epochs": 2}))
        ex = FakeExecutor()
        req = ResumeRequest(killed.folder.name, results_dir=str(tmp_path), progress=False)
        with pytest.raises(UrbJaxError, match=r"changed since it started \('alg.num_epochs' was 1, now 2"):
            resume_train(req, executor=ex)
        assert ex.batches == []
    finally:
        alg.write_text(original)


@pytest.mark.slow
def test_a_resume_refuses_a_config_file_edited_since_the_start(confs, tmp_path):
    """The hybrid file a run started with, edited before its resume: the resume names the value
    recorded and the value read now, and trains nothing."""
    (killed,) = _train(confs, tmp_path, "edit", FakeExecutor(), seeds=[0], stop_after_round=1)
    hyb = Path(confs["hybrid_conf"])
    original = hyb.read_text()
    try:
        cfg = json.loads(original)
        hyb.write_text(json.dumps(cfg | {"refit_steps": cfg.get("refit_steps", 150) + 1}))
        ex = FakeExecutor()
        req = ResumeRequest(killed.folder.name, results_dir=str(tmp_path), progress=False)
        with pytest.raises(UrbJaxError, match=r"configs changed since it started \('hybrid_refit_steps' was"):
            resume_train(req, executor=ex)
        assert ex.batches == []  # refused before any SUMO day
    finally:
        hyb.write_text(original)
