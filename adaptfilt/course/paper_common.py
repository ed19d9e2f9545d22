r"""What the chapters on the paper's experiments (9: UKF on UNGM, 10: UKF on CTM, 11: SIF on CTM)
share, read from a stored evaluation: seed-level tables, how often each grid value is used (chapters
13, 14 and 15 too), a plain log axis, and Figures 3 and 6 with labels that keep clear of each other.

==============================  ================================================================
function                        what
==============================  ================================================================
seed_table_md                   per-seed values of seed groups beside their IQM and interval
differences_md                  seed-level differences ``a - b`` (paired over runs) as a table
usage_shares, usage_md          how often each grid value is used, per policy or training seed
plain_log                       a log axis labelled with plain numbers
place_labels                    point labels that overlap neither each other nor the markers
plot_tradeoff_panels            Figures 3 and 6: every policy, and a zoom on the ones a chapter
                                discusses, labelled without overlaps
==============================  ================================================================

Each chapter's own analyses: :mod:`adaptfilt.course.ungm_ukf` (8), :mod:`adaptfilt.course.ctm_ukf`
(9), :mod:`adaptfilt.course.ctm_sif` (10). Seed groups are policies named ``<group>-s<seed>``
(:func:`adaptfilt.seed_stats.seed_groups`); where a function takes a group name, a
single policy name works as well (:func:`adaptfilt.experiments.claims.members`).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from adaptfilt.experiments.claims import compare, members
from adaptfilt.experiments.report import fmt
from adaptfilt.seed_stats import aggregate

__all__ = ["seed_table_md", "differences_md", "usage_shares", "usage_md", "plain_log", "place_labels",
           "plot_tradeoff_panels"]


def markdown_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows]) + "\n"


def seed_table_md(res, groups: Sequence[str] = ("adaptive", "myopic"),
                  metrics: Sequence[str] = ("rmse", "anees", "cost", "objective")) -> str:
    """One row per (seed group, metric): the IQM over seeds with its two-level 95 % interval,
    the mean over seeds, and every seed's own value (columns ``s0``, ``s1``, ...).

    A learned result is a distribution over training seeds; this is that distribution
    next to its summary. Groups missing from ``res`` are skipped (e.g. faithful policies
    that are not evaluated yet); none present raises ``ValueError``.
    """
    present = []
    for g in groups:
        try:
            present.append((g, members(res, g)))
        except KeyError:
            continue
    if not present:
        raise ValueError(f"none of the groups {list(groups)} is in these results")
    n = max(len(m) for _, m in present)
    rows = []
    for g, names in present:
        for m in metrics:
            a = aggregate(res, names, m)
            vals = [f"{v:.3g}" for v in a.values] + [""] * (n - len(names))
            rows.append([g, m, fmt(a.iqm, a.iqm_ci, 3), f"{a.mean:.3g}", *vals])
    return markdown_table(["group", "metric", "IQM [95 % CI]", "mean", *[f"s{i}" for i in range(n)]], rows)


def differences_md(res, pairs: Sequence[tuple[str, str]], metrics: Sequence[str] = ("rmse", "anees")) -> str:
    """Seed-level differences ``a - b`` of every pair on every metric
    (:func:`adaptfilt.experiments.claims.compare`: seeds resampled per group, runs paired), with
    the interval and the verdict on "a lower than b" (:func:`adaptfilt.verdicts.verdict`: confirmed when
    the interval lies below 0, contradicted when it lies at or above it, not confirmed when it holds 0)."""
    rows = []
    for a, b in pairs:
        for m in metrics:
            c = compare(res, a, b, m)
            lo, hi = c["ci"]
            rows.append([f"{a} - {b}", m, f"{c['a_value']:.4g}", f"{c['b_value']:.4g}",
                         f"{c['diff']:+.3g} [{lo:+.3g}, {hi:+.3g}]", c["verdict"]])
    return markdown_table(["a - b", "metric", "a (IQM)", "b (IQM)", "a - b [95 % CI]", "a lower than b"], rows)


def usage_shares(res, names: Sequence[str]) -> dict[str, np.ndarray]:
    """``{name: (G,) fraction of all run-steps using each grid value}``; a seed group is
    expanded into its seeds."""
    out = {}
    for n in names:
        for m in members(res, n):
            u = np.asarray(res[m].usage, dtype=float)
            out[m] = u / max(u.sum(), 1.0)
    return out


def usage_md(res, names: Sequence[str], min_share: float = 0.01) -> str:
    """How often each grid value is used (percent of run-steps), one row per policy or seed;
    only the grid values some row uses at least ``min_share`` of the time get a column."""
    shares = usage_shares(res, names)
    grid = res.grid
    keep = np.max(np.stack(list(shares.values())), axis=0) >= min_share
    pname = res.config.get("param_name", "param")
    from adaptfilt.style import param_label

    head = ["policy"] + [param_label(pname, g) for g, k in zip(grid, keep) if k]
    rows = [[n] + [f"{100 * s:.0f} %" if s >= 0.005 else "." for s, k in zip(u, keep) if k] for n, u in shares.items()]
    return markdown_table(head, rows)


def plain_log(ax, axis: str = "y") -> None:
    """Make ``axis`` (``"x"``, ``"y"`` or ``"both"``) of ``ax`` logarithmic and label it with plain
    numbers at 1, 2, 3 and 5 times the powers of ten (not ``2 x 10^0``)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    if axis not in ("x", "y", "both"):
        raise ValueError(f"axis must be 'x', 'y' or 'both', got {axis!r}")
    for name in ("x", "y") if axis == "both" else (axis,):
        getattr(ax, f"set_{name}scale")("log")
        a = getattr(ax, f"{name}axis")
        a.set_major_locator(LogLocator(subs=(1.0, 2.0, 3.0, 5.0)))
        a.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        a.set_minor_formatter(NullFormatter())


# ------------------------------------------------------------------ labels that keep clear of each other
def place_labels(ax, points: dict, colors: dict | None = None, fontsize: float = 8, avoid=(), segments=(),
                 max_dist: float = 42.0) -> dict:
    """Label data points of ``ax`` with texts that overlap neither each other nor the markers.

    ``points``: ``{label: (x, y)}`` in data coordinates, in priority order (the first label gets the
    best place). ``avoid``: more ``(x, y)`` data points to keep clear of (unlabelled markers);
    ``segments``: ``((x0, y0), (x1, y1))`` axis-parallel data segments to keep clear of (error bars).
    Each label tries offsets in 16 directions at growing distances (up to ``max_dist`` points) and
    takes the one with the least overlap (measured on the rendered text) with the markers, the
    labels already placed and the outside of the axes; a label set away from its point gets a thin
    leader line. Call it after the axes limits are final. Returns ``{label: Annotation}``."""
    fig = ax.figure
    fig.canvas.draw()  # settle the layout, so that the data-to-display transform is the final one
    r = fig.canvas.get_renderer()
    pt = fig.dpi / 72.0
    disp = lambda xy: ax.transData.transform(np.asarray(xy, dtype=float))
    a = ax.get_window_extent(r)
    taken = [(x - 5 * pt, y - 5 * pt, x + 5 * pt, y + 5 * pt)
             for x, y in (disp(xy) for xy in [*points.values(), *avoid])]
    for p0, p1 in segments:
        (u0, v0), (u1, v1) = disp(p0), disp(p1)
        taken.append((min(u0, u1) - 2 * pt, min(v0, v1) - 2 * pt, max(u0, u1) + 2 * pt, max(v0, v1) + 2 * pt))

    def cost(b):
        inter = sum(max(0.0, min(b[2], o[2]) - max(b[0], o[0])) * max(0.0, min(b[3], o[3]) - max(b[1], o[1]))
                    for o in taken)
        inside = max(0.0, min(b[2], a.x1) - max(b[0], a.x0)) * max(0.0, min(b[3], a.y1) - max(b[1], a.y0))
        return inter + 4.0 * ((b[2] - b[0]) * (b[3] - b[1]) - inside)

    out = {}
    for label, xy in points.items():
        t = ax.text(0, 0, label, fontsize=fontsize)
        bb = t.get_window_extent(r)
        t.remove()
        w, h = bb.width + 2 * pt, bb.height + 1 * pt
        x0, y0 = disp(xy)
        best = None
        for d in np.arange(5.0, max_dist + 1e-9, 5.0):
            for ang in np.deg2rad(np.arange(0, 360, 22.5)):
                c, s = np.cos(ang), np.sin(ang)
                cx, cy = x0 + d * pt * c + c * w / 2, y0 + d * pt * s + s * h / 2  # the box's near side at d
                b = (cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)
                score = cost(b) + 0.4 * d * pt * h  # prefer near places among free ones
                if best is None or score < best[0]:
                    best = (score, b, cx, cy, d)
        _, b, cx, cy, d = best
        taken.append(b)
        color = (colors or {}).get(label, "0.2")
        ann = ax.annotate(label, xy, xytext=((cx - x0) / pt, (cy - y0) / pt), textcoords="offset points",
                          ha="center", va="center", fontsize=fontsize, color=color, zorder=5,
                          arrowprops=dict(arrowstyle="-", lw=0.5, color=color, shrinkA=0, shrinkB=3) if d > 12 else None)
        ann.set_in_layout(False)
        out[label] = ann
    return out


def short_label(name: str) -> str:
    from adaptfilt.style import policy_label

    return policy_label(name[len("fixed-"):] if name.startswith("fixed-") else name)


def plot_tradeoff_panels(res, names: Sequence[str], zoom: Sequence[str], floor: float | None = None,
                         unit: str | None = None, label: Sequence[str] | None = None,
                         size: tuple[float, float] = (13, 6.4)):
    r"""Figures 3 and 6: time-averaged RMSE (across) against ANEES (up), every policy of ``names`` on
    the left, and on the right a zoom on the policies ``zoom`` (chosen by the chapter: the ones it
    discusses), whose box is drawn dashed on the left. Seed groups (``collapse_seeds``) show their
    IQM with the two-level interval and one faint dot per seed; fixed values are joined in grid
    order. Labels never overlap (:func:`place_labels`): on the left the points outside the zoom box,
    on the right those of ``label`` (default: all of ``zoom``). The legend sits below the panels.
    Returns the figure."""
    from matplotlib.patches import Rectangle

    from adaptfilt import style
    from adaptfilt.plots import plot_tradeoff, policy_style

    fig, (ax, axz) = style.figure(1, 2, size=size)
    plot_tradeoff(res, list(names), ax=ax, floor=floor, annotate=False, unit=unit)
    plot_tradeoff(res, list(zoom), ax=axz, annotate=False, unit=unit, logx=False, logy=False)
    handles, labels = ax.get_legend_handles_labels()
    labels = [t.replace(" nx ", " $n_x$ ") for t in labels]  # "ideal ANEES = nx = 1"
    for a in (ax, axz):
        a.get_legend().remove()
    seeds = lambda n, m: list(getattr(res[n], "seed_points", {}).get(m, []))
    xs = np.concatenate([res[n].rmse_ci for n in zoom])  # the intervals: a far seed dot may fall outside
    ys = np.concatenate([res[n].anees_ci for n in zoom])
    pad = lambda v: (v.min() - 0.06 * np.ptp(v), v.max() + 0.06 * np.ptp(v))
    (x0, x1), (y0, y1) = pad(xs), pad(ys)
    axz.set(xlim=(x0, x1), ylim=(y0, y1), title="zoom: the dashed box on the left", ylabel="")
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", lw=0.9, color="0.35", zorder=0))
    ax.set_title("every policy")
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 5), fontsize=8.5)
    color = lambda n: policy_style(res, n)["color"] if policy_style(res, n)["family"] != "fixed" else "0.25"
    outside = [n for n in names if not (x0 <= res[n].rmse <= x1 and y0 <= res[n].anees <= y1)]
    for a, sel, rest in ((axz, list(zoom if label is None else label), zoom), (ax, outside, names)):
        order = sorted(sel, key=lambda n: n.startswith("fixed-"))  # adaptive policies place first
        dots = [(u, v) for n in rest for u, v in zip(seeds(n, "rmse"), seeds(n, "anees"))]
        bars = [s for n in rest for s in (((res[n].rmse_ci[0], res[n].anees), (res[n].rmse_ci[1], res[n].anees)),
                                          ((res[n].rmse, res[n].anees_ci[0]), (res[n].rmse, res[n].anees_ci[1])))]
        place_labels(a, {short_label(n): (res[n].rmse, res[n].anees) for n in order},
                     colors={short_label(n): color(n) for n in order}, segments=bars,
                     avoid=[(res[n].rmse, res[n].anees) for n in rest if n not in sel] + dots)
    return fig
