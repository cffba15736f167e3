"""The hybrid budget's arithmetic (training/hybrid/plan.py): full rounds while they fit, then a
shorter last round, so a run trains `train_days` (the paper's 6,000 / 2,000 / 1,200) or, where a
learner iteration is too big to fit what is left, the largest total below it; never more.

The expected plans are computed by hand from the default hybrid config (16 envs, 640 surrogate +
4 SUMO days a round): URB's IQL config1 collects 20 days an env per iteration (320 days), IQL*
one (16 days)."""

from __future__ import annotations

import dataclasses
import json
import logging

import pytest

from urb_jax.core.errors import ConfigError, UrbJaxError
from urb_jax.training.checkpoints import CKPT_DIR
from urb_jax.training.hybrid.plan import HybridConfig, RoundPlan, kept_rounds, plan_rounds, whole_rounds
from urb_jax.training.hybrid.trainer import budget_text, resumed_plan

IQL_DAYS, IQL_STAR_DAYS = 20, 1  # days an env collects per learner iteration


def _plan(train_days: int, days_per_iter: int, mode: str = "hybrid", **cfg: int) -> RoundPlan:
    return plan_rounds(HybridConfig(train_days=train_days, **cfg), mode, days_per_iter)


# (train_days, days_per_iter) -> (n_rounds, iters, last_iters, last_sumo_days, total)
HAND = {
    # 9 x 644 = 5,796; 204 left: 4 SUMO days, 200 < one 320-day iteration
    (6000, IQL_DAYS): (10, 2, 0, 4, 5800),
    # 3 x 644 = 1,932; 68 left: 4 SUMO days, 64 < 320
    (2000, IQL_DAYS): (4, 2, 0, 4, 1936),
    # 1 x 644; 556 left: 4 SUMO days, one 320-day iteration (232 left over)
    (1200, IQL_DAYS): (2, 2, 1, 4, 968),
    (1000, IQL_DAYS): (2, 2, 1, 4, 968),  # 356 left: 4 SUMO days + one iteration
    (6000, IQL_STAR_DAYS): (10, 40, 12, 4, 5992),  # 204 left: 4 + 12 x 16 = 196
    (2000, IQL_STAR_DAYS): (4, 40, 4, 4, 2000),  # 68 left: 4 + 4 x 16, exact
    (1200, IQL_STAR_DAYS): (2, 40, 34, 4, 1192),  # 556 left: 4 + 34 x 16 = 548
    (1000, IQL_STAR_DAYS): (2, 40, 22, 4, 1000),  # 356 left: 4 + 22 x 16, exact
    (6440, IQL_DAYS): (10, 2, 2, 4, 6440),  # exactly 10 rounds: every round full
    (644, IQL_DAYS): (1, 2, 2, 4, 644),
}


@pytest.mark.parametrize(("train_days", "days_per_iter"), list(HAND))
def test_the_plan_against_hand_computed_budgets(train_days, days_per_iter):
    n_rounds, iters, last_iters, last_sumo, total = HAND[train_days, days_per_iter]
    plan = _plan(train_days, days_per_iter)
    assert plan == RoundPlan(n_rounds, iters, iters * 16 * days_per_iter, 4, last_iters, last_sumo,
                             16 * days_per_iter)
    assert plan.total_days == total <= train_days
    assert train_days - total < plan.iter_days  # short by less than one iteration
    assert plan.total_iters == (n_rounds - 1) * iters + last_iters
    assert plan.total_surrogate_days + plan.total_sumo_days == total
    assert plan.total_sumo_days == 4 * n_rounds
    assert [plan.iters_of(r) for r in range(n_rounds)] == [iters] * (n_rounds - 1) + [last_iters]
    assert [plan.days_through(r) for r in range(n_rounds + 1)] == [
        sum(plan.surrogate_days_of(q) + plan.sumo_days_of(q) for q in range(r)) for r in range(n_rounds + 1)]
    assert plan.is_whole == (train_days % 644 == 0 and days_per_iter == IQL_DAYS)


def test_a_last_round_of_no_iteration_and_fewer_sumo_days():
    """What is left after the full rounds pays SUMO days first: fewer than a round's P, and no
    surrogate iteration."""
    plan = _plan(3 * 656 + 10, IQL_DAYS, sumo_days_per_round=16)  # rounds of 640 + 16, 10 left
    assert plan == RoundPlan(4, 2, 640, 16, 0, 10, 320)
    assert plan.sumo_days_of(3) == 10 and plan.surrogate_days_of(3) == 0 and plan.sumo_days_of(2) == 16
    assert plan.total_sumo_days == 58 and plan.total_days == 1978
    # the paper's P = 16: 9 x 656 = 5,904, then 16 SUMO days and 80 < 320
    assert _plan(6000, IQL_DAYS, sumo_days_per_round=16) == RoundPlan(10, 2, 640, 16, 0, 16, 320)


def test_modes_sumo_and_surrogate():
    assert _plan(40, IQL_DAYS, "sumo") == RoundPlan(10, 0, 0, 4, 0, 4, 0)  # whole: as before
    assert _plan(42, IQL_DAYS, "sumo") == RoundPlan(11, 0, 0, 4, 0, 2, 0)  # was 11 rounds of 4 = 44
    assert _plan(6000, IQL_DAYS, "sumo").total_days == 6000
    # no SUMO day: 9 rounds of 640 = 5,760, 240 < 320 left: no tenth round
    assert _plan(6000, IQL_DAYS, "surrogate") == RoundPlan(9, 2, 640, 0, 2, 0, 320)
    assert _plan(6080, IQL_DAYS, "surrogate") == RoundPlan(10, 2, 640, 0, 1, 0, 320)
    with pytest.raises(ConfigError, match="buys no learner iteration"):
        _plan(300, IQL_DAYS, "surrogate")
    with pytest.raises(ConfigError, match="sumo_days_per_round"):
        _plan(40, IQL_DAYS, "sumo", sumo_days_per_round=0)


def test_kept_rounds_follow_the_short_last_round():
    """The first round whose end reaches each day count; the last ends at 5,800, not 6,440."""
    cfg = HybridConfig(train_days=6000, keep_checkpoints_at=(0, 644, 645, 5796, 5797, 5800, 6000))
    plan = plan_rounds(cfg, "hybrid", IQL_DAYS)
    assert kept_rounds(cfg, plan) == {0, 1, 2, 9, 10}
    whole = dataclasses.replace(cfg, train_days=6440)
    assert kept_rounds(whole, plan_rounds(whole, "hybrid", IQL_DAYS)) == {0, 1, 2, 9, 10}


def test_the_budget_line_says_the_plan_and_why_it_is_short():
    assert budget_text(_plan(6000, IQL_DAYS), 6000) == (
        "9 rounds of 640 surrogate + 4 SUMO days and a last round of 0 surrogate + 4 SUMO days = 5,800 "
        "training days (6,000 asked; a learner iteration collects 320 days, so 200 are left over)")
    assert budget_text(_plan(2000, IQL_STAR_DAYS), 2000) == (
        "3 rounds of 640 surrogate + 4 SUMO days and a last round of 64 surrogate + 4 SUMO days = 2,000 "
        "training days (as asked)")
    assert budget_text(_plan(6440, IQL_DAYS), 6440) == (
        "10 rounds of 640 surrogate + 4 SUMO days = 6,440 training days (as asked)")
    assert budget_text(_plan(3, IQL_DAYS), 3) == (
        "1 round of 0 surrogate + 3 SUMO days = 3 training days (as asked)")
    # a run checkpointed by a version that rounded the budget up keeps its whole rounds
    old = whole_rounds(_plan(6000, IQL_DAYS), 10)
    assert old.total_days == 6440 and budget_text(old, 6000) == (
        "10 rounds of 640 surrogate + 4 SUMO days = 6,440 training days (6,000 asked; rounds were "
        "whole, so the budget was rounded up)")


def _checkpoint(folder, **meta):
    d = folder / CKPT_DIR / "round_00002"
    d.mkdir(parents=True)
    (d / "meta.json").write_text(json.dumps({"rounds_done": 2, **meta}))
    return folder


def test_a_resume_keeps_the_plan_its_checkpoints_were_trained_to(tmp_path, caplog):
    """A checkpoint records the last round; one from before the key had whole rounds (the budget
    rounded up), and its run finishes them; a plan that differs from the recorded one is refused."""
    plan = _plan(6000, IQL_DAYS)
    assert resumed_plan(tmp_path / "none", plan, 6000) == plan  # no checkpoint: the plan
    same = _checkpoint(tmp_path / "same", rounds_total=10, last_round=[0, 4])
    assert resumed_plan(same, plan, 6000) == plan
    with caplog.at_level(logging.WARNING):
        old = resumed_plan(_checkpoint(tmp_path / "old", rounds_total=10), plan, 6000)
    assert old == whole_rounds(plan, 10) and old.total_days == 6440
    assert "started by a version that trained whole rounds" in caplog.text
    older = _checkpoint(tmp_path / "older")  # before rounds_total too: the rounds then planned
    assert resumed_plan(older, plan, 6000) == whole_rounds(plan, 10)
    other = _checkpoint(tmp_path / "other", rounds_total=10, last_round=[1, 4])
    with pytest.raises(UrbJaxError, match=r"checkpoints were trained to 9 rounds .* now plan 9 rounds"):
        resumed_plan(other, plan, 6000)
