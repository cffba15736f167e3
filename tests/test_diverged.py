"""A learner whose loss or parameters become NaN or infinite stops the run with an error naming the
round and the seed, before that round's checkpoint; no metric file is written. Before, a NaN loss
trained to the end and printed metrics (exit 0)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from support.fakeday import FakeExecutor

from urb_jax.commands import cli
from urb_jax.training.checkpoints import latest_checkpoint
from urb_jax.training.hybrid import trainer as trainer_module
from urb_jax.training.hybrid.diverged import DivergedError, check_learner, finite_per_seed

PARAMS = {"w": jnp.ones((2, 3, 4)), "b": jnp.zeros((2, 4)), "steps": jnp.zeros((2,), jnp.int32)}


def test_finite_learners_pass() -> None:
    assert finite_per_seed(PARAMS).tolist() == [True, True]
    check_learner(PARAMS, [{"sur_loss": 1.0, "sumo_loss": 0.5}, {"sur_loss": 2.0}], 0, [0, 1])


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_non_finite_loss_names_the_round_and_the_seed(bad) -> None:
    with pytest.raises(DivergedError, match=rf"diverged in round 4 \(seed 7: sumo_loss = {bad}\).*Fix:"):
        check_learner(PARAMS, [{"sur_loss": 1.0}, {"sur_loss": 1.0, "sumo_loss": bad}], 3, [3, 7])


def test_non_finite_parameters_name_the_seed() -> None:
    params = {**PARAMS, "w": PARAMS["w"].at[1, 2, 0].set(jnp.nan)}
    assert finite_per_seed(params).tolist() == [True, False]
    with pytest.raises(DivergedError, match=r"round 1 \(seed 5: its parameters hold NaN"):
        check_learner(params, [{}, {}], 0, [4, 5])


@pytest.mark.slow
def test_a_run_whose_learner_diverges_stops_before_writing_metrics(confs, tmp_path, monkeypatch, capsys):
    """The tiny IQL run (3 rounds) with its learner's parameters poisoned in round 2's surrogate leg:
    exit 2 and the message, round 1's checkpoint the newest, no metric file, no metrics printed."""
    leg = trainer_module.HybridTrainer.surrogate_leg

    def poisoned(self, k_sur, rows, *iters):
        leg(self, k_sur, rows, *iters)
        if len(self.rounds_logs[0]) == 1:  # round 2 (round 1 is logged)
            params = jax.tree_util.tree_map(lambda x: x * np.nan, self.state.runner.params)
            self.state = self.state._replace(runner=self.state.runner._replace(params=params))

    monkeypatch.setattr(trainer_module.HybridTrainer, "surrogate_leg", poisoned)
    monkeypatch.setattr("urb_jax.runs.train.make_executor", lambda *a, **k: FakeExecutor())
    argv = ["train", "--results-dir", str(tmp_path), "--id", "nan", "--no-progress", "--task-conf",
            confs["task_conf"], "--hybrid-conf", confs["hybrid_conf"], "--alg-conf", confs["alg_conf"]]
    assert cli.main(argv) == 2
    out, err = capsys.readouterr()
    assert "urb-jax: error: the learner diverged in round 2 (seed 0: " in err, err
    assert "parameters hold NaN" in err and "t_CAV" not in out
    folder = tmp_path / "nan"
    assert latest_checkpoint(folder)[0] == 1  # round 2's state was never checkpointed
    assert not list(folder.rglob("*Metrics.csv")) and not (folder / "rounds.csv").exists()
