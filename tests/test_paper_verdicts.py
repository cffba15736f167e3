"""urb_jax.reporting.verdicts: the distributions against printed tables and closed forms, the tests
and the verdicts against cases computed by hand."""

from __future__ import annotations

import math

import pytest

from urb_jax.reporting.verdicts import (
    FAILS,
    HOLDS,
    TIE,
    Difference,
    Sample,
    betainc,
    clopper_pearson,
    direction,
    equivalence,
    fisher_exact,
    margin_of,
    order,
    paired,
    t_cdf,
    t_ppf,
    value_agrees,
    welch,
    win_rate,
    win_rates_agree,
)


def test_the_incomplete_beta_on_closed_forms():
    for x in (0.0, 0.1, 0.5, 0.93, 1.0):
        assert betainc(1, 1, x) == pytest.approx(x, abs=1e-14)  # uniform
        assert betainc(3, 1, x) == pytest.approx(x ** 3, abs=1e-14)
        assert betainc(1, 2.5, x) == pytest.approx(1 - (1 - x) ** 2.5, abs=1e-14)
    assert betainc(2.5, 4.0, 0.3) + betainc(4.0, 2.5, 0.7) == pytest.approx(1.0, abs=1e-14)  # symmetry


@pytest.mark.parametrize("df, q, t", [  # Student t critical values, as printed in statistics tables
    (1, 0.975, 12.706), (2, 0.975, 4.303), (4, 0.95, 2.132), (4, 0.975, 2.776), (5, 0.995, 4.032),
    (10, 0.975, 2.228), (30, 0.95, 1.697), (math.inf, 0.975, 1.960)])
def test_t_quantiles_match_the_printed_table(df, q, t):
    assert t_ppf(q, df) == pytest.approx(t, abs=5e-4)
    assert t_cdf(t, df) == pytest.approx(q, abs=5e-4)


def test_t_cdf_on_closed_forms():
    for t in (-4.0, -1.0, 0.0, 0.7, 3.0):
        assert t_cdf(t, 1) == pytest.approx(0.5 + math.atan(t) / math.pi, abs=1e-13)  # Cauchy
        assert t_cdf(t, 2) == pytest.approx(0.5 + t / (2 * math.sqrt(2 + t * t)), abs=1e-13)


def test_against_scipy_where_it_is_installed():
    stats = pytest.importorskip("scipy.stats")
    for df in (1.3, 4, 7.9, 60):
        for t in (-2.5, 0.4, 5.0):
            assert t_cdf(t, df) == pytest.approx(stats.t.cdf(t, df), abs=1e-12)
    ours = welch(Sample.of([3.1, 3.4, 3.2, 3.6, 3.3]), Sample(3.21, 0.206, 5))
    ref = stats.ttest_ind_from_stats(3.32, Sample.of([3.1, 3.4, 3.2, 3.6, 3.3]).sd, 5, 3.21, 0.206, 5,
                                     equal_var=False)
    assert ours.p_two() == pytest.approx(ref.pvalue, abs=1e-10)


def test_sample_std_divides_by_n_minus_1():
    s = Sample.of([1.0, 2.0, 3.0])
    assert (s.mean, s.sd, s.n) == (2.0, 1.0, 3)  # ddof=1 (ddof=0 would give 0.8165)
    assert Sample.of([4.2]).sd == 0.0


def test_welch_by_hand():
    """[1, 2, 3] (mean 2, sd 1) against mean 0, sd 1, n 3: se = sqrt(1/3 + 1/3), t = 2.449,
    df = (2/3)^2 / ((1/3)^2/2 * 2) = 4; two-sided p = 0.0705 (t table, df 4)."""
    d = welch(Sample.of([1, 2, 3]), Sample(0.0, 1.0, 3))
    assert (d.diff, d.se, d.df) == pytest.approx((2.0, math.sqrt(2 / 3), 4.0))
    assert d.p_two() == pytest.approx(0.0705, abs=5e-4)
    # a one-run side is a constant: the one-sample t-test (df n-1)
    one = welch(Sample.of([1, 2, 3]), Sample(0.0, 0.0, 1))
    assert (one.se, one.df) == pytest.approx((1 / math.sqrt(3), 2.0))
    # a printed number's rounding (±0.005) is variance without df: two exact values become a z-test
    z = welch(Sample(3.0152, 0.0, 1), Sample(3.01, 0.0, 1, rounding=0.005))
    assert z.se == pytest.approx(0.005 / math.sqrt(3)) and math.isinf(z.df)


def test_paired_differences():
    d = paired([3.0, 3.1, 3.2], [3.16, 3.16, 3.16])  # per-seed t_CAV - t_pre
    assert d.diff == pytest.approx(-0.06) and d.df == 2 and d.se == pytest.approx(0.1 / math.sqrt(3))


def test_direction_holds_fails_or_ties():
    below = paired([3.0, 3.01, 3.02, 3.03, 3.04], [3.16] * 5)  # clearly below t_pre
    assert direction(below, "<").kind == HOLDS and direction(below, ">").kind == FAILS
    spread = paired([3.0, 3.4, 3.1, 3.3, 3.2], [3.19] * 5)  # mean 3.2, sd 0.158: inside the spread
    assert direction(spread, "<").kind == TIE and direction(spread, ">").kind == TIE
    assert "90% CI" in direction(below, "<").detail
    # no spread (one run each): by value, and the verdict says so
    exact = Difference(-0.14, 0.0, math.inf)
    assert direction(exact, "<").kind == HOLDS and "by value" in direction(exact, "<").detail
    assert direction(Difference(0.0, 0.0, math.inf), ">").kind == TIE


def test_order_says_lower_higher_or_tie():
    """No claim: the two-sided 5% test. [1, 2, 3] against the constant 0: t = 3.46, df 2, p = 0.074
    (tie); against -1: t = 5.20, p = 0.035 (higher); the 95% interval is mean ± 4.303 se."""
    assert order(welch(Sample.of([1, 2, 3]), Sample(0.0, 0.0, 1))).kind == TIE
    higher = order(welch(Sample.of([1, 2, 3]), Sample(-1.0, 0.0, 1)))
    assert higher.kind == "higher" and "p = 0.035" in higher.detail
    assert order(welch(Sample.of([-3, -2, -1]), Sample(1.0, 0.0, 1))).kind == "lower"
    lo, hi = paired([1, 2, 3], [0, 0, 0]).interval(0.95)
    assert (lo, hi) == pytest.approx((2 - 4.303 / math.sqrt(3), 2 + 4.303 / math.sqrt(3)), abs=1e-3)
    assert order(Difference(-0.1, 0.0, math.inf)).kind == "lower"  # no spread: by value
    assert order(Difference(0.0, 0.0, math.inf)).kind == TIE


def test_equivalence_by_tost():
    """diff 0.005, se 0.004, df 4: 90% CI 0.005 ± 2.132 * 0.004 = [-0.0035, 0.0135]."""
    d = Difference(0.005, 0.004, 4)
    assert equivalence(d, 0.02).kind == HOLDS  # inside ±0.02
    assert equivalence(d, 0.01).kind == TIE  # not inside ±0.01, and not significant (p = 0.28)
    far = Difference(0.1, 0.01, 4)  # significant and outside any small margin
    assert equivalence(far, 0.03).kind == FAILS
    assert equivalence(Difference(0.2, 0.15, 4), 0.03).kind == TIE  # wide: neither
    assert margin_of(3.53) == pytest.approx(0.0353) and margin_of(-0.06) == 0.01


def test_ours_against_the_papers_cell():
    """The paper's St. Arnoult IQL t_CAV 3.53 (sd 0.104, n 5) against five seeds near 3.02:
    a difference of -0.51 with se ~0.047 (df ~4): fails; a copy of the paper's own spread holds
    only if its mean is within 1% (0.0353)."""
    ours = Sample.of([3.0176, 3.0152, 3.0205, 3.0110, 3.0237])
    assert value_agrees(ours, Sample(3.53, 0.104, 5, rounding=0.005)).kind == FAILS
    same = Sample.of([3.53, 3.531, 3.529, 3.530, 3.532])
    assert value_agrees(same, Sample(3.53, 0.004, 5, rounding=0.005)).kind == HOLDS


def test_clopper_pearson_by_hand():
    # 0 of 5: upper = 1 - 0.025^(1/5); 5 of 5: lower = 0.025^(1/5)
    assert clopper_pearson(0, 5) == pytest.approx((0.0, 1 - 0.025 ** 0.2))
    assert clopper_pearson(0, 5)[1] == pytest.approx(0.522, abs=5e-4)  # [0, 52%]
    assert clopper_pearson(5, 5) == pytest.approx((0.025 ** 0.2, 1.0))
    assert clopper_pearson(4, 5) == pytest.approx((0.2836, 0.9949), abs=5e-5)
    assert clopper_pearson(1, 10) == pytest.approx((0.0025, 0.4450), abs=5e-5)


def test_fisher_exact_by_hand():
    # 0 of 5 against 5 of 5: only the two extreme tables, each 1/C(10,5)
    assert fisher_exact(0, 5, 5, 5) == pytest.approx(2 / 252)
    # 0 of 5 against 4 of 5: P(0) = P(4) = 6/252, the others larger
    assert fisher_exact(0, 5, 4, 5) == pytest.approx(12 / 252)
    assert fisher_exact(2, 5, 3, 5) == pytest.approx(1.0)


def test_win_rate_claims():
    # 'WR > 0': one win proves it; no win cannot disprove it (0 of 5: up to 45% one-sided)
    assert win_rate(1, 5, ">", 0).kind == HOLDS and win_rate(0, 5, ">", 0).kind == TIE
    # 'WR < 100': one loss proves it
    assert win_rate(4, 5, "<", 100).kind == HOLDS and win_rate(5, 5, "<", 100).kind == TIE
    # 'WR < 50': 0 of 5 holds (one-sided bound 1 - 0.05^(1/5) = 45%), 5 of 5 fails (lower bound 55%)
    assert win_rate(0, 5, "<", 50).kind == HOLDS and win_rate(5, 5, "<", 50).kind == FAILS
    assert win_rate(2, 5, "<", 50).kind == TIE
    assert "0 of 5 runs, 95% CI [0%, 52%]" in win_rate(0, 5, ">", 0).detail
    # against the paper's win rate: 0 of 5 against its 4 of 5 differs (p = 0.048); 1 against 0 ties
    assert win_rates_agree(0, 5, 4, 5).kind == FAILS and win_rates_agree(1, 5, 0, 5).kind == TIE
