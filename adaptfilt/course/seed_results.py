r"""Results over training seeds, as text and figures, for chapters 12 (Your own model) and 13 (RL in
practice), and a CPU-time measurement for chapter 13; chapters 5, 8, 14 and 15 use them too.

========================================  =========================================================
chapter                                   helpers
========================================  =========================================================
11 Your own model                         :func:`seed_lines`, :func:`plot_differences`
12 RL in practice                         :func:`plot_seed_spread`, :func:`seed_verdicts`,
                                          :func:`claims_table`, :func:`timed`
========================================  =========================================================

A *seed group* is a set of policies named ``<group>-s<seed>``
(:func:`adaptfilt.seed_stats.seed_groups`); its aggregate is the IQM
over seeds with the two-level (seeds x runs) bootstrap interval of
:func:`adaptfilt.seed_stats.aggregate`. Tested in ``tests/test_course_seed_results.py``; figures use
:mod:`adaptfilt.style`.
"""
from __future__ import annotations

import time
from typing import Callable, Mapping, Sequence

import numpy as np

from adaptfilt.course.common import figure_axes
from adaptfilt.seed_stats import aggregate, seed_groups
from adaptfilt.verdicts import verdict

__all__ = ["seed_lines", "plot_differences", "plot_seed_spread", "seed_verdicts", "claims_table", "timed"]


# ============================================================== chapter 12
def seed_lines(results, groups: Sequence[str], baselines: Sequence[str] = (),
               metrics: Sequence[str] = ("rmse", "anees", "objective")) -> str:
    r"""Baselines one line each (value [run-level CI]), then each seed group: IQM over its
    seeds [two-level 95 % CI] (range of the per-seed values)."""
    rows = []
    for n in baselines:
        p = results[n]
        cells = []
        for m in metrics:
            ci = getattr(p, m + "_ci", None)
            cells.append(f"{m} {getattr(p, m):.3g}" + (f" [{ci[0]:.3g}, {ci[1]:.3g}]" if ci is not None else ""))
        rows.append((n, cells))
    groups_all = seed_groups(results.names)
    for g in groups:
        names = groups_all[g]
        cells = []
        for m in metrics:
            a = aggregate(results, names, m)
            cells.append(f"{m} {a.iqm:.3g} [{a.iqm_ci[0]:.3g}, {a.iqm_ci[1]:.3g}] ({a.values.min():.3g}..{a.values.max():.3g})")
        rows.append((f"{g} ({len(names)} seeds)", cells))
    width = max((len(label) for label, _ in rows), default=0)
    return "\n".join(f"{label:{width}s}  " + "   ".join(cells) for label, cells in rows)


def plot_differences(diffs: Mapping[str, Mapping[str, tuple[float, float, float]]], ax=None, ylabel: str = "",
                     title: str | None = None):
    r"""Paired differences with intervals: ``diffs[condition][label] = (diff, lo, hi)``,
    one x position per condition, one marker per label, a line at 0."""
    from adaptfilt import style

    fig, ax = figure_axes(ax)
    conds = list(diffs)
    labels = list(dict.fromkeys(lab for c in conds for lab in diffs[c]))
    x = np.arange(len(conds))
    off = np.linspace(-0.2, 0.2, len(labels)) if len(labels) > 1 else np.zeros(1)
    for j, (lab, col) in enumerate(zip(labels, style.colors(len(labels)))):
        d = np.array([diffs[c].get(lab, (np.nan,) * 3) for c in conds])
        ax.errorbar(x + off[j], d[:, 0], yerr=[d[:, 0] - d[:, 1], d[:, 2] - d[:, 0]], fmt="o", color=col, capsize=3,
                    label=style.policy_label(lab))
    ax.axhline(0, color="black", lw=0.8)
    ax.set_xticks(x, conds)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.legend()
    return fig


# ============================================================== chapter 13
def plot_seed_spread(results, groups: Sequence[str], metric: str = "rmse", ax=None):
    r"""Each seed of each group with its own run-level 95 % interval (the noise of one
    evaluation), and beside them the group's IQM and mean with the two-level
    (seeds x runs) intervals: what a single seed hides."""
    from adaptfilt import style

    fig, ax = figure_axes(ax)
    all_groups = seed_groups(results.names)
    y0 = 0
    ticks, labels = [], []
    for g, col in zip(groups, style.colors(len(groups))):
        names = all_groups[g]
        for i, n in enumerate(names):
            p = results[n]
            v, (lo, hi) = getattr(p, metric), getattr(p, metric + "_ci")
            ax.errorbar(v, y0 + i, xerr=[[v - lo], [hi - v]], fmt="o", ms=4, color=col, capsize=2)
            ticks.append(y0 + i)
            labels.append(n)
        a = aggregate(results, names, metric)
        for j, (lab, v, (lo, hi), mk) in enumerate([("IQM", a.iqm, a.iqm_ci, "D"), ("mean", a.mean, a.mean_ci, "s")]):
            yy = y0 + len(names) + j
            ax.errorbar(v, yy, xerr=[[v - lo], [hi - v]], fmt=mk, ms=6, color=col, mec="black", capsize=4, lw=2)
            ticks.append(yy)
            labels.append(f"{g}: {lab} of {len(names)}")
        y0 += len(names) + 3
    ax.set_yticks(ticks, labels)
    ax.invert_yaxis()
    ax.set_xlabel(f"time-averaged {metric.upper() if metric in ('rmse', 'anees') else metric} (95 % intervals)")
    return fig


def seed_verdicts(results, group: str, other: str, metric: str = "rmse", better: str = "lower",
                  margin: float | None = None) -> dict:
    r"""What each seed of ``group`` alone says about "``group`` is ``better`` than ``other``"
    (its own paired run-level interval, judged by :func:`adaptfilt.verdicts.verdict` with ``margin``,
    required for "not worse" and "equal"): ``{"per_seed": {name: (diff, lo, hi, verdict)},
    "counts": {verdict: n}}``."""
    names = seed_groups(results.names)[group]
    per = {}
    for n in names:
        d = results.paired_difference(n, other, metric)
        per[n] = (*d, verdict(better, d, margin))
    counts: dict[str, int] = {}
    for v in per.values():
        counts[v[3]] = counts.get(v[3], 0) + 1
    return {"per_seed": per, "counts": counts}


def claims_table(claims: Mapping, experiment: str, keys: Sequence[str] = ("C1", "C2", "C4", "C6"),
                 only_held: bool = True) -> str:
    r"""A Markdown table of the stored claims (:func:`adaptfilt.experiments.artefacts.load_claims`) of one
    experiment: the seed-level verdict beside the number of seeds that hold it *alone*
    (each seed's own paired interval; defined where ``b`` is a single policy). A verdict judged
    with a margin ("equal", "not worse") shows it (:func:`adaptfilt.experiments.report.verdict_text`).
    ``only_held``: only the rows where that count exists."""
    from adaptfilt.experiments.report import verdict_text
    rows = ["| claim | comparison | metric | a - b, IQM [seed-level 95 % CI] | seed-level verdict | seeds holding alone |",
            "|---|---|---|---|---|---|"]
    seen = set()
    for k in keys:
        for r in claims.get(k, []):
            if r["experiment"] != experiment or (only_held and r.get("seeds_holding") is None):
                continue
            key = (r["claim"], r["metric"])
            if key in seen:
                continue
            seen.add(key)
            held = "" if r.get("seeds_holding") is None else f"{r['seeds_holding']}/{r['n_seeds']}"
            claim = r["claim"].replace(" equal than ", " equal to ")
            rows.append(f"| {k} | {claim} | {r['metric']} | {r['diff']:+.3g} [{r['ci'][0]:+.3g}, {r['ci'][1]:+.3g}] "
                        f"| {verdict_text(r)} | {held} |")
    return "\n".join(rows) + "\n"


def timed(fn: Callable, *args, **kwargs) -> tuple[object, float]:
    """``(fn(*args, **kwargs), CPU seconds it took)`` (process time: less sensitive to a
    loaded machine than wall time; compare two such numbers from one run only)."""
    c0 = time.process_time()
    out = fn(*args, **kwargs)
    return out, time.process_time() - c0
