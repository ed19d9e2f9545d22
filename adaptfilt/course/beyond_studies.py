r"""What chapters 14 (Beyond the paper) and 15 (Out of distribution and the raw cost) show of the
studies that :mod:`adaptfilt.experiments.beyond` runs: a seed group against one policy per metric,
when a filter with a fixed grid value diverges, every SIF policy's cost against its share of
divergent runs, and the gains out of distribution.

========================================  =========================================================
function                                  what
========================================  =========================================================
verdict_counts, plot_seed_differences     a seed group minus one policy: the seed-level verdict and
                                          what each seed alone finds, as lines and as a figure
divergence_onsets                         which runs of one fixed grid value diverge, and when
plot_cost_divergence                      every policy of a SIF evaluation: relative cost against
                                          the share of divergent runs
plot_ood_gains                            the gains over the default out of distribution, as heat
                                          maps
========================================  =========================================================

Seed groups as in :mod:`adaptfilt.course.seed_results`. Tested in ``tests/test_course_beyond_studies.py``;
figures use :mod:`adaptfilt.style`.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from adaptfilt.course.common import figure_axes
from adaptfilt.course.seed_results import seed_verdicts
from adaptfilt.seed_stats import seed_groups
from adaptfilt.verdicts import verdict

__all__ = ["verdict_counts", "plot_seed_differences", "divergence_onsets", "plot_cost_divergence", "plot_ood_gains"]


def verdict_counts(results, group: str, other: str, metrics: Sequence[str] = ("cost", "rmse")) -> str:
    r"""One line per metric: ``group - other`` as IQM over seeds [two-level 95 % CI], the seed-level
    verdict on "``group`` lower than ``other``" (:func:`adaptfilt.verdicts.verdict`), and what the seeds
    alone (their own paired run-level interval) say about it."""
    from adaptfilt.seed_stats import difference

    names = seed_groups(results.names)[group]
    lines = []
    for m in metrics:
        d = difference(results, names, [other], m)["iqm"]
        c = seed_verdicts(results, group, other, m)["counts"]
        alone = ", ".join(f"{n} {v}" for v, n in sorted(c.items(), key=lambda kv: -kv[1]))
        lines.append(f"{group} - {other}  {m:9s} {d[0]:+.4g} [{d[1]:+.4g}, {d[2]:+.4g}]  {verdict('lower', d)}"
                     f"   (seeds alone: {alone})")
    return "\n".join(lines)


def divergence_onsets(env, value: float, n_runs: int = 1000, seed: int = 0) -> dict:
    r"""Run the environment's filter with the grid value ``value`` at every step on ``n_runs``
    simulated runs and find, per run, whether it diverged and when, by the library's one definition
    (:data:`adaptfilt.metrics.DIVERGED_NEES`): a run is divergent when its time-averaged NEES exceeds
    ``10^4 n_x`` (:func:`adaptfilt.metrics.divergent`), and its onset is the first step at which the
    running time average crosses that line (:func:`adaptfilt.metrics.divergence_step`); and whether the
    covariance was repaired at some step. Returns ``{"divergent": (M,) bool, "onset": (M,) first step
    or -1, "repaired": (M,) bool, "nees": (T, M)}``; a run with an onset that recovers below the line
    by the last step has ``onset >= 0`` and ``divergent`` False."""
    from adaptfilt.metrics import divergence_step, divergent

    grid = np.asarray(env.grid, dtype=float)
    hit = np.flatnonzero(np.isclose(grid, value))
    if hit.size == 0:
        raise ValueError(f"{value} is not on the grid {grid.tolist()}")
    d = env.reset(n_runs=n_runs, rng=np.random.default_rng(seed), stream=seed)
    a = np.full(n_runs, hit[0])
    nees, repaired = [], np.zeros(n_runs, dtype=bool)
    done = False
    while not done:
        d, _, done, info = env.step(a)
        e = info["x_filt"] - env.traj.x[:, info["t"], :]
        nees.append(np.einsum("mi,mi->m", e, np.linalg.solve(info["P_filt"], e[..., None])[..., 0]))
        repaired |= np.asarray(info["repaired"], dtype=bool)
    N = np.array(nees)
    return {"divergent": divergent(N.T, env.model.nx), "onset": divergence_step(N.T, env.model.nx),
            "repaired": repaired, "nees": N}


def _clipped_errorbar(ax, v, lo, hi, y, lim, text_fmt, **kw):
    """An error bar at height ``y`` whose parts outside ``lim`` are cut at the axis edge, with the
    value written there (a point far off the scale stays visible and readable)."""
    a, b = lim
    ax.errorbar(min(max(v, a), b), y, xerr=[[max(min(v, b) - max(lo, a), 0)], [max(min(hi, b) - max(v, a), 0)]],
                **kw)
    outside = [(x, side) for x, side in ((v, "point"), (hi, "upper"), (lo, "lower")) if not a <= x <= b]
    if not outside:
        return
    x, _ = outside[0]
    edge, ha, mk = (b, "right", ">") if x > b else (a, "left", "<")
    ax.plot(edge, y, mk, ms=7, color=kw.get("color", "black"), clip_on=False, zorder=5)
    f = text_fmt.format
    what = f"{f(v)} [{f(lo)}, {f(hi)}]" if not a <= v <= b else f"to {f(x)}"
    ax.annotate(what, (edge, y), textcoords="offset points", xytext=(-8 if ha == "right" else 8, 5), ha=ha,
                va="bottom", fontsize=8, color=kw.get("color", "black"))


def plot_seed_differences(results, groups: Sequence[str], other: str, metrics: Sequence[str] = ("cost", "rmse"),
                          xlim: Mapping[str, tuple[float, float]] | None = None, axes=None):
    r"""Each seed of each group minus ``other`` (its paired run-level 95 % interval) and the group's
    IQM and mean of the differences with their two-level (seeds x runs) intervals, on a linear axis
    with a line at 0, one panel per metric: an effect far smaller than the values themselves stays
    visible. ``xlim[metric]`` fixes a panel's range; a point or interval end outside it is cut at the
    edge, marked with a triangle and its value written beside it."""
    from adaptfilt import style
    from adaptfilt.seed_stats import difference

    if axes is None:
        fig, axes = style.figure(1, len(metrics), size=(5.2 * len(metrics) + 1.6, 3.2 * len(groups) + 1.2),
                                 sharey=True)
    axes = np.atleast_1d(axes)
    fig = axes[0].figure
    all_groups = seed_groups(results.names)
    for ax, m in zip(axes, metrics):
        y0, ticks, labels, ends = 0, [], [], []
        rows = []
        for g, col in zip(groups, style.colors(len(groups))):
            names = all_groups[g]
            for i, n in enumerate(names):
                rows.append((y0 + i, *results.paired_difference(n, other, m), "o", 4, col, 1.2))
                labels.append(n)
            d = difference(results, names, [other], m)
            for j, (lab, mk) in enumerate((("IQM", "D"), ("mean", "s"))):
                rows.append((y0 + len(names) + j, *d[lab.lower()], mk, 7, col, 2.2))
                labels.append(f"{g}: {lab} of {len(names)}")
            y0 += len(names) + 3
        ticks = [r[0] for r in rows]
        lim = (xlim or {}).get(m)
        if lim is None:
            ends = np.array([r[1:4] for r in rows], dtype=float)
            lim = (min(ends.min(), 0.0), max(ends.max(), 0.0))
            pad = 0.05 * (lim[1] - lim[0])
            lim = (lim[0] - pad, lim[1] + pad)
        for y, v, lo, hi, mk, ms, col, lw in rows:
            _clipped_errorbar(ax, v, lo, hi, y, lim, "{:+.3g}", fmt=mk, ms=ms, color=col, capsize=3, lw=lw,
                              mec="black" if mk != "o" else col)
        ax.axvline(0.0, color="black", lw=1, ls="--")
        ax.set_xlim(*lim)
        ax.set_yticks(ticks, labels)
        name = m.upper() if m in ("rmse", "anees") else m
        ax.set_xlabel(f"{name} minus {other}'s (95 % intervals; dashed: no difference)")
    axes[0].invert_yaxis()
    return fig


def _label_points(ax, xs, ys, texts, min_px: float = 14.0):
    """Label points on one line without overlap and without dropping any: each label goes to the
    nearest free row (above, below, two rows above, two below, ...), a row being free when its last
    label is at least ``min_px`` display pixels to the left; a label off its point's own row gets a
    thin leader line to the point."""
    ax.figure.canvas.draw()
    to_px = ax.transData.transform
    last: dict[int, float] = {}
    rows = [1, -1, 2, -2, 3, -3, 4, -4]
    for x, y, t in sorted(zip(xs, ys, texts), key=lambda r: r[0]):
        if not (np.isfinite(x) and ax.get_xlim()[0] <= x <= ax.get_xlim()[1]):
            continue
        px = to_px((x, y))[0]
        row = next((r for r in rows if px - last.get(r, -np.inf) >= min_px), rows[-1])
        last[row] = px
        dy = 6 + 10 * (row - 1) if row > 0 else -11 - 10 * (-row - 1)
        ax.annotate(t, (x, y), textcoords="offset points", xytext=(0, dy), ha="center", fontsize=8, color="0.3",
                    zorder=6, arrowprops=dict(arrowstyle="-", color="0.6", lw=0.6, shrinkA=0, shrinkB=3)
                    if abs(row) > 1 else None)


def plot_cost_divergence(results, groups: Sequence[str] = (), ax=None, title: str | None = None,
                         metric: str = "cost_charged", xlim: tuple[float, float] = (-40.0, 105.0),
                         legend: str | None = "right"):
    r"""Every policy of a SIF evaluation as a point (mean cost relative to the default's, fraction of
    divergent runs), the cost ``metric`` by default charged for the iterations each policy computes
    (greedy's candidates included): the fixed iteration counts (a grey line, labelled with n_it),
    greedy, and each seed of ``groups``; the default is the dotted vertical line at 0.

    The x axis is ``100 (cost / default's cost - 1)`` in %, on the linear range ``xlim``; give each
    panel of a figure a range that fits its own policies (the costs differ by orders of magnitude in
    how far the policies spread) and say so in the caption. A point beyond it is drawn at the edge as
    a triangle with its value written beside it. The n_it labels never overlap: a crowded one moves
    to a further row with a leader line. The divergent fraction is on a symlog axis so that
    0 (never diverged) stays on the plot. The learned seeds are drawn last, above the fixed line.
    ``legend``: ``"right"`` of the axes, ``"figure"`` (below all panels of a constrained-layout
    figure), or ``None``."""
    from adaptfilt import style

    fig, ax = figure_axes(ax, size=(7.5, 4.6))
    ref = getattr(results["default"], metric)

    def rel(n):
        return 100.0 * (getattr(results[n], metric) / ref - 1.0)

    lo, hi = xlim
    ax.set_xlim(lo, hi)
    ax.axvline(0.0, color="0.35", lw=1.2, ls=":", label="default ($n_{it}$ = 10): 0 %", zorder=1)
    fixed = results.fixed_names()
    x = np.array([rel(n) for n in fixed])
    y = np.array([100 * results[n].divergent_frac for n in fixed])
    ax.plot(np.clip(x, lo, hi), y, "o-", color="0.6", ms=4, label="fixed $n_{it}$", zorder=2)
    cols = style.colors(len(groups) + 1)
    markers = ["^", "v", "o", "P", "X"]

    def point(n, mk, col, ms, label=None, z=3):
        xv, yv = rel(n), 100 * results[n].divergent_frac
        inside = lo <= xv <= hi
        ax.plot(min(max(xv, lo), hi), yv, mk if inside else (">" if xv > hi else "<"), ms=ms, color=col,
                mec="black", mew=0.6, alpha=0.85, label=label, zorder=z, clip_on=False)
        return None if inside else (xv, yv)

    far = []
    if "greedy" in results:
        if (f := point("greedy", "D", cols[0], 8, "greedy")) is not None:
            far.append(("greedy", *f))
    all_groups = seed_groups(results.names)
    for k, (g, col) in enumerate(zip(groups, cols[1:])):
        names = all_groups.get(g, [])
        for i, n in enumerate(names):
            f = point(n, markers[k % len(markers)], col, 7, f"{g} ({len(names)} seeds)" if i == 0 else None, z=4 + k)
            if f is not None:
                far.append((n, *f))
    ax.set_yscale("symlog", linthresh=0.01)
    ax.set_ylim(-0.003, None)
    _label_points(ax, x, y, [n.split("=")[1] for n in fixed])
    for n, xv, yv in [(n, xv, yv) for n, xv, yv in zip(fixed, x, y) if not lo <= xv <= hi] + far:
        label = f"fixed $n_{{it}}$ = {n.split('=')[1]}" if n.startswith("fixed-") else n
        ax.annotate(f"{label}: {xv:+.2g} %", (hi if xv > hi else lo, yv),
                    textcoords="offset points", xytext=(-8 if xv > hi else 8, 6), ha="right" if xv > hi else "left",
                    fontsize=8, color="0.3")
    what = "mean cost, compute charged" if metric == "cost_charged" else f"mean {metric}"
    ax.set_xlabel(f"{what}, relative to the default (%)")
    ax.set_ylabel("divergent runs (%)")
    if title:
        ax.set_title(title)
    if legend == "right":
        ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
    elif legend == "figure":  # one legend for all panels, below them
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=6, fontsize=9)
    return fig


def plot_ood_gains(table: Mapping, metric: str = "objective",
                   columns: Sequence[str] = ("greedy", "best fixed", "learned", "retuned")):
    r"""One heat map per column of :func:`adaptfilt.experiments.ood.gain_table` (gain over the
    default on the 3 x 3 grid of truth noise scalings; positive is better), on one colour scale."""
    import matplotlib.pyplot as plt

    from adaptfilt.experiments.ood import plot_gain

    fig, axes = plt.subplots(1, len(columns), figsize=(4.1 * len(columns), 3.7), layout="constrained")
    v = max(abs(c["gain"]) for row in table.values() for k, c in row.items() if k in columns)
    for ax, col in zip(np.atleast_1d(axes), columns):
        plot_gain(table, col, metric, ax=ax, title=f"{col}", vmax=v)
    fig.suptitle(f"gain in {metric} over the default (positive: better)")
    return fig
