r"""The one verdict rule, and the table of declared margins.

Every verdict word of the project comes from :func:`verdict`: the claims C1-C6 and Table I
(:mod:`adaptfilt.experiments.claims`), the fast trainer against the faithful one, the studies beyond the
paper, the report and the course. A **claim** is a statement about the true difference
:math:`\delta = a - b` of a metric where lower is better (RMSE, a cost, the objective; ANEES where both
sides lie above :math:`n_x`), with a **margin** :math:`m \ge 0`, a difference too small to matter:

==============  ===============================  ===============================  ================================
claim           holds when                       **confirmed** when               **contradicted** when
==============  ===============================  ===============================  ================================
``"lower"``     :math:`\delta < -m`              :math:`hi < -m`                  :math:`lo \ge -m`
``"not worse"`` :math:`\delta < +m`              :math:`hi < +m`                  :math:`lo \ge +m`
``"equal"``     :math:`\lvert\delta\rvert < m`   :math:`-m < lo`, :math:`hi < m`  :math:`hi \le -m` or :math:`lo \ge m`
==============  ===============================  ===============================  ================================

and **not confirmed** otherwise. It is one rule: a claim is an open region of :math:`\delta`; the verdict
on the seed-level 95 % interval :math:`[lo, hi]` is *confirmed* when the interval lies inside the region,
*contradicted* when it lies wholly outside it (an end that touches the region's edge from outside is
outside: the edge is not in the region), *not confirmed* when it holds points of both. So "equal" is
contradicted only when the interval lies wholly outside :math:`(-m, +m)`; "not worse" only when it lies
wholly above :math:`+m`; "lower" (a is better than b) is confirmed below :math:`-m` and contradicted when
the interval shows :math:`\delta \ge -m`, that is, a not better by the margin (with :math:`m = 0`, the
"better at all" of a "lower" claim: contradicted when a is shown not lower).

**Margins are declared, not chosen at the comparison.** :data:`DECLARED_MARGINS` is the one table:
comparison, metric, margin (a fraction of ``b``'s value), where it comes from, and when it was fixed.
A "not worse" or "equal" claim takes its margin from there (:func:`margin`, :func:`judge`); a comparison
that is not in the table gets no such verdict, an error names it. A "lower" claim without a declared
margin is "lower at all", margin 0; that is the rule with :math:`m = 0`, not a special case. No margin
of 0 reads as anything but 0: an "equal" claim needs :math:`m > 0` (its region is empty otherwise).

**Infinite ends.** A diverged run gives an infinite bootstrap replicate, and an interval end can be
infinite (:func:`adaptfilt.metrics.percentile_ci`: never NaN; an undefined replicate, both sides
diverged, counts as :math:`-\infty` at the lower end and :math:`+\infty` at the upper). An infinite end
means the interval is unbounded on that side: :math:`hi = +\infty` says that in at least 2.5 % of the
replicates ``a`` is worse than ``b`` without bound. The rule applies to it unchanged (:math:`+\infty`
lies beyond every margin): :math:`[lo, +\infty]` confirms no claim and contradicts one only through
its lower end, :math:`[-\infty, +\infty]` decides nothing. A NaN end is an error, never a verdict.

>>> verdict("equal", (-0.241, -0.152), margin=0.154)   # C2 against kappa = 200: its upper end inside
'not confirmed'
>>> verdict("equal", (0.14, 0.229), margin=0.135)      # C2 against kappa = 500 in both steps
'contradicted'
>>> verdict("not worse", (-0.048, 0.056), margin=0.0)  # margin 0 is 0: "lower at all", not shown
'not confirmed'
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

__all__ = ["CLAIMS", "WORDS", "verdict", "DeclaredMargin", "DECLARED_MARGINS", "declared", "margin", "judge"]

#: The claims a comparison can make about ``a - b`` (lower is better).
CLAIMS = ("lower", "not worse", "equal")
#: The only verdict words.
WORDS = ("confirmed", "contradicted", "not confirmed")


def verdict(claim: str, interval: Sequence[float], margin: float | None = None) -> str:
    r"""The verdict on ``claim`` about ``a - b`` from its seed-level interval (module docstring, the rule).

    ``interval``: ``(lo, hi)``, or ``(diff, lo, hi)`` as :func:`adaptfilt.seed_stats.difference` and
    :meth:`adaptfilt.results.Results.paired_difference` give it (the point estimate is not used).
    ``margin``: absolute, :math:`\ge 0`; required for ``"not worse"`` and ``"equal"`` (take it from
    :func:`margin`, the declared table), :math:`> 0` for ``"equal"``; ``None`` for ``"lower"`` is 0.

    .. math:: \text{confirmed} \iff [lo, hi] \subset H, \quad
              \text{contradicted} \iff [lo, hi] \cap H = \emptyset, \quad
              H_\text{lower} = (-\infty, -m),\ H_\text{not worse} = (-\infty, m),\ H_\text{equal} = (-m, m)

    >>> verdict("lower", (-0.0512, -0.0403))
    'confirmed'
    >>> verdict("lower", (0.0, 0.3))            # touches 0 from above: a is shown not lower
    'contradicted'
    >>> verdict("not worse", (1.46, float("inf")), margin=0.09)
    'contradicted'
    """
    if claim not in CLAIMS:
        raise ValueError(f"claim must be one of {', '.join(map(repr, CLAIMS))}, got {claim!r}")
    if len(interval) not in (2, 3):
        raise ValueError(f"interval must be (lo, hi) or (diff, lo, hi), got {tuple(interval)!r}")
    lo, hi = (float(v) for v in interval[-2:])
    if math.isnan(lo) or math.isnan(hi):
        raise ValueError(f"the interval [{lo}, {hi}] has an undefined (NaN) end: no verdict; an interval's ends are "
                         "numbers or infinities (adaptfilt.metrics.percentile_ci)")
    if lo > hi:
        raise ValueError(f"the interval [{lo}, {hi}] has its lower end above its upper end")
    if margin is None:
        if claim != "lower":
            raise ValueError(f"a {claim!r} claim needs a declared margin (verdicts.DECLARED_MARGINS, verdicts.margin); "
                             "none was given")
        margin = 0.0
    m = float(margin)
    if not m >= 0 or math.isinf(m):
        raise ValueError(f"a margin is a finite number >= 0, got {margin!r}")
    if claim == "equal" and m == 0:
        raise ValueError("an 'equal' claim needs a margin > 0: with margin 0 the region -0 < a - b < 0 is empty")
    if claim == "equal":  # the region (-m, +m)
        inside, outside = -m < lo and hi < m, hi <= -m or lo >= m
    else:  # the region (-inf, edge): below -m for "lower", below +m for "not worse"
        edge = -m if claim == "lower" else m
        inside, outside = hi < edge, lo >= edge
    return "confirmed" if inside else "contradicted" if outside else "not confirmed"


@dataclass(frozen=True)
class DeclaredMargin:
    """One entry of :data:`DECLARED_MARGINS`: the margin of a comparison's claim on each metric, as a
    fraction of ``b``'s value (IQM over seeds, or the baseline's value), with where it comes from and
    when it was fixed."""

    comparison: str
    claim: str
    fractions: Mapping[str, float]
    source: str
    fixed: str


#: The declared margins, the one place a margin is set: comparison -> :class:`DeclaredMargin`. Each was
#: fixed before the verdicts it judges were drawn. 5 % of an RMSE or an objective (a tracking accuracy
#: 5 % apart is the same accuracy for any use we know of; the objective is a log, 5 % is a large change
#: of the cost), 10 % of an ANEES or a cost (heavy-tailed: seed-to-seed spreads of 10-30 % are common).
DECLARED_MARGINS: dict[str, DeclaredMargin] = {m.comparison: m for m in (
    DeclaredMargin(
        "adaptive vs best fixed", "equal", {"rmse": 0.05},
        "the paper's Section VI-F: the adaptive kappa has 'the same estimate accuracy' as the best fixed kappa "
        "(claims C2 and C3b: the best constant in the update, and on UNGM also in both steps)",
        "2026-11-25, commit ad51a71, before C2 and C3b were derived at the seed level with a margin"),
    DeclaredMargin(
        "fast vs faithful", "not worse", {"cost": 0.10, "rmse": 0.05, "anees": 0.10, "objective": 0.05},
        "the fast trainer's target: not worse than Algorithm 2's loop with the library's recipe (the faithful "
        "trainer's policies) on "
        "what the paper measures and on the objective both minimise",
        "2026-11-25, commit ad51a71, before the fast trainer's verdicts were derived with a margin"),
    DeclaredMargin(
        "anchored vs greedy", "not worse", {"rmse": 0.05, "anees": 0.10},
        "the greedy-anchored learner's goal: a cost below greedy's on every seed with RMSE and ANEES not worse "
        "than greedy's (adaptfilt.anchor; the look-ahead study)",
        "2026-11-25, with the margins of commit ad51a71, before the anchored learner was written (commit 6cfbbe1) "
        "and evaluated"),
    DeclaredMargin(
        "learned gain vs learned kappa", "not worse", {"rmse": 0.05},
        "the learned-gain study's design: each arm against the other arms and against the default and best "
        "constant kappa (adaptfilt.experiments.studies.gain.PAIRS), on RMSE",
        "2026-11-27, commit f14df90, with the study's code, before its evaluation (commit 64b2f76)"),
    DeclaredMargin(
        "learned vs ML", "not worse", {"rmse": 0.05, "anees": 0.10},
        "the CTM's open question (the mlanchor study): a learned policy whose cost is below maximum likelihood's "
        "answers it only with RMSE and ANEES not worse than ML's; the margins of 'anchored vs greedy', ML in "
        "greedy's place",
        "2026-11-28, commit c4a6a14 (the mlanchor study on the one verdict rule), after its trainings, before "
        "its evaluations were read"),
    DeclaredMargin(
        "consistent kappa vs squared-error kappa", "not worse", {"rmse": 0.05},
        "the learned-gain study's consistency arm: a kappa trained on the squared error plus the Gaussian log "
        "score buys consistency (an ANEES judged 'lower' at margin 0) at no cost in accuracy only with an RMSE "
        "not worse than the squared-error kappa's; the RMSE margin of 'learned gain vs learned kappa'",
        "2026-11-28, commit after 924a5dc on the gain-study branch (the study's rewrite), before any of its "
        "trainings or evaluations"),
)}


def declared(comparison: str, metric: str, claim: str | None = None) -> DeclaredMargin:
    """The declared margin of ``comparison`` on ``metric`` (:data:`DECLARED_MARGINS`); ``claim``, when
    given, must be the declared one. An undeclared comparison or metric is an error that names it."""
    d = DECLARED_MARGINS.get(comparison)
    if d is None:
        raise ValueError(f"no margin is declared for the comparison {comparison!r} (declared: "
                         f"{', '.join(map(repr, DECLARED_MARGINS))}): without one it gets no 'equal' or 'not worse' "
                         "verdict")
    if metric not in d.fractions:
        raise ValueError(f"the comparison {comparison!r} declares a margin for {', '.join(d.fractions)}, not for "
                         f"{metric!r}: no 'equal' or 'not worse' verdict on it")
    if claim is not None and claim != d.claim:
        raise ValueError(f"the comparison {comparison!r} is declared as a {d.claim!r} claim, not {claim!r}")
    return d


def margin(comparison: str, metric: str, reference: float) -> float:
    """The absolute margin of ``comparison`` on ``metric``: its declared fraction of ``|reference|``
    (``b``'s value). A reference that is not finite has no margin (an error says so).

    >>> round(margin("adaptive vs best fixed", "rmse", 3.072), 4)
    0.1536
    """
    ref = float(reference)
    if not math.isfinite(ref):
        raise ValueError(f"the reference value of {comparison!r} on {metric!r} is {ref}: no margin")
    return declared(comparison, metric).fractions[metric] * abs(ref)


def judge(claim: str, interval: Sequence[float], comparison: str | None = None, metric: str | None = None,
          reference: float | None = None) -> tuple[str, float]:
    """``(verdict, margin)`` for ``claim`` on ``interval``: the margin declared for ``comparison`` on
    ``metric`` around ``reference`` (:func:`margin`), or 0 for a "lower" claim whose comparison declares
    none (``comparison=None``)."""
    if comparison is None:
        if claim != "lower":
            raise ValueError(f"a {claim!r} claim needs a declared comparison (verdicts.DECLARED_MARGINS)")
        return verdict(claim, interval, 0.0), 0.0
    declared(comparison, metric, claim)
    m = margin(comparison, metric, reference)
    return verdict(claim, interval, m), m
