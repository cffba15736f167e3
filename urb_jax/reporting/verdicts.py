"""Verdicts on the paper's claims from per-seed values: holds, fails, tie or not comparable.

Pure and small (the standard library's math only; scipy is not a dependency): the Student t
distribution through the regularized incomplete beta function, Welch's t-test, paired and
one-sample tests, equivalence by TOST, Clopper-Pearson intervals and Fisher's exact test for win
rates. The rules, which docs/paper.md states:

* Spread: the sample std (ddof=1) of the seeds. A number the paper prints is known to half a unit
  of its last digit; that rounding (uniform, variance half-unit^2 / 3) is added to its variance.
* A claim of direction ("t_CAV > t_pre"): one-sided tests at 5% (a 90% interval for the
  difference). `holds` if the difference is significant in the claimed direction, `fails` if it is
  significant in the other, `tie` if neither (the difference is inside the seed spread).
* A claim of equality ("≈", a value of ours against the paper's): `holds` if the 90% interval of
  the difference lies inside ±margin (TOST at 5%), `fails` if the difference is significant
  (two-sided 5%) and not equivalent, `tie` otherwise (not significant, not shown equal).
* A claim on a win rate ("WR > 0"): the Clopper-Pearson one-sided 95% bounds (the 90% two-sided
  interval) of k wins in n runs: `holds` if the bound is on the claimed side, `fails` if the other
  bound is on the other side, `tie` otherwise. Two win rates (ours against the paper's k0 of n0):
  Fisher's exact test; `fails` if p < 5%, else `tie` (a handful of runs cannot show two rates equal).
* With no spread at all (one run on each side, or identical seeds), a difference is judged by its
  value and the verdict says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

ALPHA = 0.05
HOLDS, FAILS, TIE, NOT_COMPARABLE = "holds", "fails", "tie", "not comparable"
VERDICTS = (HOLDS, FAILS, TIE, NOT_COMPARABLE)


# ---- distributions

def betainc(a: float, b: float, x: float) -> float:
    """The regularized incomplete beta function I_x(a, b), by its continued fraction (Lentz)."""
    if not 0.0 <= x <= 1.0:
        raise ValueError(f"betainc: x = {x} is outside [0, 1]")
    if x in (0.0, 1.0):
        return x
    log_front = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    front = math.exp(log_front)
    if x > (a + 1.0) / (a + b + 2.0):  # the fraction converges fast on this side only
        return 1.0 - betainc(b, a, 1.0 - x)
    tiny, c, d = 1e-300, 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    f = d
    for m in range(1, 500):
        for num in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                    -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + num / c
            c = c if abs(c) > tiny else tiny
            f *= c * d
        if abs(c * d - 1.0) < 1e-15:
            break
    return front * f / a


def normal_cdf(z: float) -> float:
    return 0.5 * math.erfc(-z / math.sqrt(2.0))


def t_cdf(t: float, df: float) -> float:
    """P(T <= t) for Student's t with `df` degrees of freedom (any real df > 0; inf: the normal)."""
    if math.isinf(df):
        return normal_cdf(t)
    tail = 0.5 * betainc(df / 2.0, 0.5, df / (df + t * t))
    return 1.0 - tail if t > 0 else tail


def _invert(cdf, q: float, lo: float, hi: float) -> float:
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < q else (lo, mid)
    return 0.5 * (lo + hi)


def t_ppf(q: float, df: float) -> float:
    """The q-quantile of Student's t (bisection on t_cdf)."""
    return _invert(lambda t: t_cdf(t, df), q, -1e7, 1e7)


def beta_ppf(q: float, a: float, b: float) -> float:
    """The q-quantile of the Beta(a, b) distribution."""
    return _invert(lambda x: betainc(a, b, x), q, 0.0, 1.0)


# ---- samples and differences

@dataclass(frozen=True)
class Sample:
    """A mean with its sample std (ddof=1; 0 for one value) over n runs, and the rounding of a
    printed number (half a unit of its last digit; 0 for values we computed)."""

    mean: float
    sd: float
    n: int
    rounding: float = 0.0

    @classmethod
    def of(cls, values: Sequence[float]) -> Sample:
        vals = [float(v) for v in values]
        if not vals:
            raise ValueError("a sample needs at least one value")
        mean = sum(vals) / len(vals)
        sd = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else 0.0
        return cls(mean, sd, len(vals))

    @property
    def spread(self) -> float:
        """The variance of the mean from the runs (0 for one run)."""
        return self.sd ** 2 / self.n if self.n > 1 else 0.0


@dataclass(frozen=True)
class Difference:
    """left - right, its standard error and degrees of freedom (inf: no seed variance in it)."""

    diff: float
    se: float
    df: float

    def interval(self, level: float) -> tuple[float, float]:
        if self.se == 0:
            return self.diff, self.diff
        half = t_ppf(0.5 + level / 2.0, self.df) * self.se
        return self.diff - half, self.diff + half

    def p_greater(self) -> float:
        """One-sided p for 'the true difference > 0'."""
        return 1.0 - t_cdf(self.diff / self.se, self.df)

    def p_less(self) -> float:
        return t_cdf(self.diff / self.se, self.df)

    def p_two(self) -> float:
        return min(1.0, 2.0 * min(self.p_greater(), self.p_less()))


def welch(left: Sample, right: Sample) -> Difference:
    """Welch's t-test of two independent samples (Welch-Satterthwaite degrees of freedom); a
    one-run side counts as a constant, the printed numbers' rounding as variance without df."""
    vl, vr = left.spread, right.spread
    rounding = (left.rounding ** 2 + right.rounding ** 2) / 3.0
    var = vl + vr + rounding
    denom = sum(v ** 2 / (s.n - 1) for v, s in ((vl, left), (vr, right)) if s.n > 1)
    return Difference(left.mean - right.mean, math.sqrt(var), var ** 2 / denom if denom > 0 else math.inf)


def paired(left: Sequence[float], right: Sequence[float]) -> Difference:
    """The per-seed differences' one-sample t-test (left and right from the same seeds)."""
    if len(left) != len(right):
        raise ValueError("paired: both sides need one value per seed")
    d = Sample.of([a - b for a, b in zip(left, right, strict=True)])
    return Difference(d.mean, math.sqrt(d.spread), d.n - 1 if d.n > 1 and d.sd > 0 else math.inf)


# ---- verdicts

@dataclass(frozen=True)
class Verdict:
    kind: str  # one of VERDICTS
    detail: str  # the numbers behind it, or why not comparable

    def __str__(self) -> str:
        return f"{self.kind} ({self.detail})" if self.detail else self.kind


def not_comparable(why: str) -> Verdict:
    return Verdict(NOT_COMPARABLE, why)


def _num(x: float) -> str:
    return f"{x:+.4f}"


def _p(p: float) -> str:
    return "p < 0.001" if p < 0.001 else f"p = {p:.3f}"


def direction(d: Difference, op: str) -> Verdict:
    """A claim 'left op right' (op '<' or '>') on the difference left - right."""
    if op not in ("<", ">"):
        raise ValueError(f"direction: op {op!r} is '<' or '>'")
    want = 1 if op == ">" else -1
    if d.se == 0:
        sign = (d.diff > 0) - (d.diff < 0)
        kind = TIE if sign == 0 else HOLDS if sign == want else FAILS
        return Verdict(kind, f"difference {_num(d.diff)}; no spread: by value")
    p_claim, p_other = (d.p_greater(), d.p_less()) if want == 1 else (d.p_less(), d.p_greater())
    lo, hi = d.interval(0.90)
    kind = HOLDS if p_claim < ALPHA else FAILS if p_other < ALPHA else TIE
    return Verdict(kind, f"difference {_num(d.diff)}, 90% CI [{_num(lo)}, {_num(hi)}], one-sided "
                         f"{_p(p_claim if kind != FAILS else p_other)}")


def order(d: Difference) -> Verdict:
    """Left against right with no claim behind it: "lower" or "higher" where a two-sided test at 5%
    says so, else TIE (the difference is inside the seed spread). The detail is a table cell's: the
    difference, its 95% interval and the two-sided p."""
    if d.se == 0:
        kind = "lower" if d.diff < 0 else "higher" if d.diff > 0 else TIE
        return Verdict(kind, f"{_num(d.diff)} (no spread: by value)")
    p = d.p_two()
    lo, hi = d.interval(0.95)
    kind = ("lower" if d.diff < 0 else "higher") if p < ALPHA else TIE
    return Verdict(kind, f"{_num(d.diff)} [{_num(lo)}, {_num(hi)}], {_p(p)}")


def equivalence(d: Difference, margin: float) -> Verdict:
    """A claim of equality within ±margin: TOST at 5% (the 90% interval inside the margin)."""
    lo, hi = d.interval(0.90)
    if d.se == 0:
        kind = HOLDS if abs(d.diff) < margin else FAILS
        return Verdict(kind, f"difference {_num(d.diff)}, margin ±{margin:.4f}; no spread: by value")
    p = d.p_two()
    kind = HOLDS if -margin < lo and hi < margin else FAILS if p < ALPHA else TIE
    return Verdict(kind, f"difference {_num(d.diff)}, 90% CI [{_num(lo)}, {_num(hi)}], margin ±{margin:.4f}, "
                         f"two-sided {_p(p)}")


def margin_of(paper_value: float) -> float:
    """The equivalence margin behind 'ours equal the paper's': 1% of the paper's value, at least
    0.01 (one unit of the last digit it prints)."""
    return max(0.01 * abs(paper_value), 0.01)


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) interval of a proportion from k successes in n trials."""
    if not 0 <= k <= n or n < 1:
        raise ValueError(f"clopper_pearson: k = {k} of n = {n}")
    tail = (1.0 - level) / 2.0
    lo = 0.0 if k == 0 else beta_ppf(tail, k, n - k + 1)
    hi = 1.0 if k == n else beta_ppf(1.0 - tail, k + 1, n - k)
    return lo, hi


def _hypergeom(x: int, wins: int, n1: int, n: int) -> float:
    return math.comb(wins, x) * math.comb(n - wins, n1 - x) / math.comb(n, n1)


def fisher_exact(k1: int, n1: int, k2: int, n2: int) -> float:
    """Two-sided p of Fisher's exact test: k1 of n1 against k2 of n2 (the tables no more likely
    than the observed one)."""
    wins, n = k1 + k2, n1 + n2
    observed = _hypergeom(k1, wins, n1, n)
    probs = [_hypergeom(x, wins, n1, n) for x in range(max(0, wins - n2), min(wins, n1) + 1)]
    return min(1.0, sum(p for p in probs if p <= observed * (1 + 1e-9)))


def _pct(x: float) -> str:
    return f"{100 * x:.0f}%"


def win_rate(k: int, n: int, op: str, pct: float) -> Verdict:
    """A claim 'WR op pct' on k wins in n runs: Clopper-Pearson one-sided 95% bounds."""
    lo, hi = clopper_pearson(k, n, 0.90)
    x = pct / 100.0
    if op == ">":
        kind = HOLDS if lo > x else FAILS if hi <= x else TIE
    elif op == "<":
        kind = HOLDS if hi < x else FAILS if lo >= x else TIE
    else:
        raise ValueError(f"win_rate: op {op!r} is '<' or '>'")
    lo95, hi95 = clopper_pearson(k, n, 0.95)
    return Verdict(kind, f"{k} of {n} runs, 95% CI [{_pct(lo95)}, {_pct(hi95)}], one-sided bounds "
                         f"[{_pct(lo)}, {_pct(hi)}]")


def win_rates_agree(k: int, n: int, k0: int, n0: int) -> Verdict:
    """Ours (k of n) against the paper's (k0 of n0): Fisher's exact test."""
    p = fisher_exact(k, n, k0, n0)
    return Verdict(FAILS if p < ALPHA else TIE, f"{k} of {n} against {k0} of {n0}, Fisher's exact {_p(p)}")


def value_agrees(ours: Sample, paper: Sample) -> Verdict:
    """Ours against the paper's mean/std/n: Welch's t-test, equivalence within margin_of(paper)."""
    return equivalence(welch(ours, paper), margin_of(paper.mean))
