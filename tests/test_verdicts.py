"""The one verdict rule (adaptfilt.verdicts): every branch at its boundaries, infinite ends, the declared
margins, and the intervals the course-read reviews found judged two ways."""
import itertools
import math
from types import SimpleNamespace

import numpy as np
import pytest

from adaptfilt import metrics
from adaptfilt.seed_stats import difference
from adaptfilt.verdicts import CLAIMS, DECLARED_MARGINS, WORDS, declared, judge, margin, verdict

INF = math.inf


def holds(claim: str, delta: float, m: float) -> bool:
    """The claim as a statement about the true difference delta = a - b (the definition, not the rule)."""
    return {"lower": delta < -m, "not worse": delta < m, "equal": -m < delta < m}[claim]


def by_points(claim: str, lo: float, hi: float, m: float) -> str:
    """The verdict from its definition, checked point by point: confirmed when every difference the
    interval holds satisfies the claim, contradicted when none does. The region is an interval of the
    extended line, so its edges, points just beside them, the interval's ends and its middle decide."""
    edges = (-m, m)
    pts = {lo, hi}
    for e in edges:
        for p in (e, math.nextafter(e, -INF), math.nextafter(e, INF)):
            if lo <= p <= hi:
                pts.add(p)
    if math.isfinite(lo) and math.isfinite(hi):
        pts.add((lo + hi) / 2)
    sat = [holds(claim, p, m) for p in pts]
    return "confirmed" if all(sat) else "contradicted" if not any(sat) else "not confirmed"


SPECIAL = (-INF, -0.3, -0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2, 0.3, INF)


@pytest.mark.parametrize("claim", CLAIMS)
@pytest.mark.parametrize("m", [0.0, 0.1])
def test_the_rule_is_its_definition_on_every_interval_of_special_ends(claim, m):
    """Every interval whose ends are drawn from the margins, the points beside them, zero and +-inf: the
    rule's word is the one the definition gives (an interval touching an edge from outside is outside)."""
    if claim == "equal" and m == 0:
        pytest.skip("an equal claim needs a margin > 0 (tested below)")
    n = 0
    for lo, hi in itertools.combinations_with_replacement(SPECIAL, 2):
        got = verdict(claim, (lo, hi), m)
        assert got in WORDS and got == by_points(claim, lo, hi, m), (claim, m, lo, hi, got)
        n += 1
    assert n == 66


@pytest.mark.parametrize("claim, interval, m, want", [
    # equal (-m, +m): inside, touching an edge from inside, crossing an edge, touching from outside, outside
    ("equal", (-0.09, 0.09), 0.1, "confirmed"),
    ("equal", (-0.1, 0.05), 0.1, "not confirmed"),        # lo on the edge: -m is not in (-m, m)
    ("equal", (0.05, 0.15), 0.1, "not confirmed"),
    ("equal", (-0.3, 0.3), 0.1, "not confirmed"),         # wider than the margin on both sides
    ("equal", (0.1, 0.2), 0.1, "contradicted"),           # touches +m from above
    ("equal", (-0.3, -0.1), 0.1, "contradicted"),         # touches -m from below
    ("equal", (0.11, 0.2), 0.1, "contradicted"),
    ("equal", (0.02, 0.09), 0.1, "confirmed"),            # a detectable difference inside the margin
    # not worse (-inf, +m)
    ("not worse", (-0.5, 0.09), 0.1, "confirmed"),
    ("not worse", (-0.5, 0.1), 0.1, "not confirmed"),     # hi on the edge
    ("not worse", (0.1, 0.4), 0.1, "contradicted"),
    ("not worse", (0.05, 0.4), 0.1, "not confirmed"),
    ("not worse", (-0.048, 0.056), 0.0, "not confirmed"),  # margin 0 is 0: "lower at all", not shown
    ("not worse", (-0.3, -0.01), 0.0, "confirmed"),
    # lower (-inf, -m)
    ("lower", (-0.0512, -0.0403), 0.0, "confirmed"),
    ("lower", (-0.05, 0.0), 0.0, "not confirmed"),        # hi touches 0: 0 is not below 0
    ("lower", (0.0, 0.3), 0.0, "contradicted"),            # lo touches 0: a is shown not lower
    ("lower", (-0.3, -0.05), 0.1, "not confirmed"),       # lower, but not by the margin everywhere
    ("lower", (-0.09, 0.2), 0.1, "contradicted"),          # shown not lower by the margin
    ("lower", (-0.3, -0.11), 0.1, "confirmed"),
])
def test_branches_at_their_boundaries(claim, interval, m, want):
    assert verdict(claim, interval, m) == want
    assert verdict(claim, (0.0, *interval), m) == want  # (diff, lo, hi) as seed_stats gives it


@pytest.mark.parametrize("claim, interval, m, want", [
    ("lower", (1.46, INF), 0.0, "contradicted"),          # a diverged side: unbounded above, lo decides
    ("lower", (-INF, INF), 0.0, "not confirmed"),         # decides nothing
    ("lower", (-INF, -2.0), 0.0, "confirmed"),            # unbounded below, wholly below 0
    ("lower", (-INF, -INF), 0.0, "confirmed"),
    ("not worse", (-3.7, INF), 0.35, "not confirmed"),
    ("not worse", (0.6, INF), 0.15, "contradicted"),
    ("equal", (-INF, -0.2), 0.1, "contradicted"),
    ("equal", (-INF, 0.0), 0.1, "not confirmed"),
    ("equal", (INF, INF), 0.1, "contradicted"),
])
def test_infinite_ends_are_numbers_beyond_every_margin(claim, interval, m, want):
    assert verdict(claim, interval, m) == want


def test_bad_input_is_an_early_clear_error():
    with pytest.raises(ValueError, match="undefined .NaN. end"):
        verdict("lower", (math.nan, 0.3))
    with pytest.raises(ValueError, match="lower end above its upper end"):
        verdict("lower", (0.3, 0.1))
    with pytest.raises(ValueError, match="'not worse' claim needs a declared margin"):
        verdict("not worse", (0.0, 0.1))
    with pytest.raises(ValueError, match="'equal' claim needs a declared margin"):
        verdict("equal", (0.0, 0.1))
    with pytest.raises(ValueError, match="'equal' claim needs a margin > 0"):
        verdict("equal", (-0.01, 0.01), 0.0)
    with pytest.raises(ValueError, match="finite number >= 0"):
        verdict("not worse", (0.0, 0.1), -0.1)
    with pytest.raises(ValueError, match="finite number >= 0"):
        verdict("not worse", (0.0, 0.1), INF)
    with pytest.raises(ValueError, match="claim must be one of"):
        verdict("better", (0.0, 0.1))
    with pytest.raises(ValueError, match=r"\(lo, hi\) or \(diff, lo, hi\)"):
        verdict("lower", (0.1,))


def test_the_intervals_the_reviews_found_judged_two_ways():
    """C2's "equal to kappa = 200" ends inside its margin: not confirmed (it was "contradicted"); the kappa = 500
    row lies wholly above: contradicted; chapter 5's margin-0 row: "not worse" not confirmed (it was
    "confirmed", the interval holds 0); adaptive vs myopic in RMSE has no declared margin: no "equal" verdict."""
    m200 = margin("adaptive vs best fixed", "rmse", 3.072)
    assert m200 == pytest.approx(0.1536)
    assert verdict("equal", (-0.2414, -0.1519), m200) == "not confirmed"
    assert verdict("equal", (0.140, 0.229), margin("adaptive vs best fixed", "rmse", 2.691)) == "contradicted"
    assert verdict("not worse", (-0.048, 0.056), 0.0) == "not confirmed"
    assert verdict("lower", (-0.0485, 0.0559)) == "not confirmed"
    with pytest.raises(ValueError, match="no margin is declared for the comparison 'adaptive vs myopic'"):
        judge("equal", (-0.0485, 0.0559), "adaptive vs myopic", "rmse", 2.87)


def test_declared_margins_say_what_when_and_why():
    assert set(DECLARED_MARGINS) == {"adaptive vs best fixed", "fast vs faithful", "anchored vs greedy",
                                     "learned gain vs learned kappa", "learned vs ML",
                                     "consistent kappa vs squared-error kappa"}
    for name, d in DECLARED_MARGINS.items():
        assert d.comparison == name and d.claim in ("equal", "not worse")
        assert d.fractions and all(0 < f < 1 for f in d.fractions.values())
        assert len(d.source) > 40 and "2026-" in d.fixed and "commit" in d.fixed
    assert DECLARED_MARGINS["fast vs faithful"].fractions == {"cost": 0.10, "rmse": 0.05, "anees": 0.10,
                                                              "objective": 0.05}
    assert margin("fast vs faithful", "anees", -9.437) == pytest.approx(0.9437)
    with pytest.raises(ValueError, match="declares a margin for rmse, not for 'anees'"):
        declared("adaptive vs best fixed", "anees")
    with pytest.raises(ValueError, match="declared as a 'equal' claim, not 'not worse'"):
        declared("adaptive vs best fixed", "rmse", "not worse")
    with pytest.raises(ValueError, match="reference value .* is inf: no margin"):
        margin("fast vs faithful", "rmse", INF)
    assert judge("lower", (-0.2, -0.1)) == ("confirmed", 0.0)
    assert judge("not worse", (-0.2, 0.2), "fast vs faithful", "rmse", 3.0) == ("not confirmed", pytest.approx(0.15))
    with pytest.raises(ValueError, match="needs a declared comparison"):
        judge("equal", (-0.2, 0.1))


def test_percentile_interval_with_infinite_and_undefined_replicates():
    """An end next to an infinite replicate is that infinity (np.quantile gives NaN there), checked against
    the same quantile with the infinities replaced by +-1e300; an undefined replicate widens both ends."""
    rng = np.random.default_rng(0)
    for n_inf in (0, 1, 20, 25, 26, 40, 999):
        x = rng.normal(size=1000)
        x[rng.choice(1000, n_inf, replace=False)] = np.inf
        lo, hi = metrics.percentile_ci(x)
        ref = np.quantile(np.where(np.isinf(x), 1e300, x), [0.025, 0.975])
        want = [np.inf if r > 1e200 else r for r in ref]  # beside a 1e300: the infinity
        assert [lo, hi] == pytest.approx(want) and not np.isnan([lo, hi]).any(), n_inf
    x = np.r_[-np.inf, np.arange(38.0), np.inf]   # both ends fall between an infinity and its neighbour
    assert metrics.percentile_ci(x) == (-np.inf, np.inf)
    y = np.r_[np.full(50, np.nan), np.arange(950.0)]  # 5 % undefined: both ends become infinite
    assert metrics.percentile_ci(y) == (-np.inf, np.inf)
    z = np.r_[np.full(10, np.nan), np.arange(990.0)]  # 1 %: the ends move inward only by the widening
    lo, hi = metrics.percentile_ci(z)
    assert lo == pytest.approx(np.quantile(np.r_[np.full(10, -1e300), np.arange(990.0)], 0.025))
    assert hi == pytest.approx(np.quantile(np.r_[np.full(10, 1e300), np.arange(990.0)], 0.975))
    finite, a = rng.normal(size=500), (1 - 0.95) / 2  # finite replicates: np.quantile's numbers, bit for bit
    assert metrics.percentile_ci(finite) == tuple(float(v) for v in np.quantile(finite, [a, 1 - a]))


def test_a_seed_level_difference_with_diverged_seeds_has_no_nan_end():
    """Two groups with an infinite seed each: replicates where both IQMs are infinite are undefined, and the
    interval says "anything" instead of NaN; the verdict then decides nothing."""
    B = 400
    rng = np.random.default_rng(1)

    def pol(v):
        return SimpleNamespace(rmse=v, boot_rmse=v + 0.01 * rng.standard_normal(B))

    vals_a = [3.0, 3.1, np.inf, 3.2, np.inf, 2.9, 3.0, np.inf]
    vals_b = [3.5, np.inf, 3.4, np.inf, 3.6, 3.5, np.inf, 3.3]
    res = {**{f"a-s{i}": pol(v) for i, v in enumerate(vals_a)}, **{f"b-s{i}": pol(v) for i, v in enumerate(vals_b)}}
    d = difference(res, [f"a-s{i}" for i in range(8)], [f"b-s{i}" for i in range(8)], "rmse")
    _, lo, hi = d["iqm"]
    assert not math.isnan(lo) and not math.isnan(hi) and lo == -INF and hi == INF
    assert verdict("lower", d["iqm"]) == "not confirmed"
