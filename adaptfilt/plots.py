"""Figures of an evaluation (:class:`adaptfilt.evaluation.Results`), as in the paper.

=====================  ===================================================  ==============
function               what                                                 paper
=====================  ===================================================  ==============
plot_rmse_time         ``RMSE_k`` over time (selected policies, 95 % band)
plot_anees_time        ``ANEES_k`` over time with the chi2 acceptance band
plot_rmse_bars         time-averaged RMSE per policy with 95 % CIs          Figs 1 and 4
plot_anees_bars        time-averaged ANEES per policy with 95 % CIs         Figs 2 and 5
plot_tradeoff          RMSE vs ANEES, one labelled point per policy          Figs 3 and 6
plot_choices           fraction of runs choosing each grid value over time
plot_usage             how often each grid value is used, per policy
save_figures           all of the above as PNG files
=====================  ===================================================  ==============

Every function returns the :class:`~matplotlib.figure.Figure` (never calls
``plt.show``) and accepts an ``ax`` to draw into. Colours are consistent per
policy family: ``default`` black, fixed values along the viridis colormap in
grid order, ``ml`` red, ``greedy`` orange, learned policies blue/green/purple.
``floor`` draws a horizontal (or vertical) reference RMSE, e.g. the
point-mass Bayes floor on UNGM.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Sequence

import matplotlib

if not os.environ.get("DISPLAY") and not os.environ.get("MPLBACKEND") and "ipykernel" not in sys.modules:
    matplotlib.use("Agg")  # headless: files only

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from adaptfilt.files import atomic_savefig  # noqa: E402
from adaptfilt.metrics import chi2_bounds  # noqa: E402
from adaptfilt.style import colors as _colors, param_label, policy_label  # noqa: E402

__all__ = ["policy_style", "selected_policies", "plot_rmse_time", "plot_anees_time", "plot_rmse_bars",
           "plot_anees_bars", "plot_tradeoff", "plot_choices", "plot_usage", "save_figures"]

_LEARNED_COLORS = ("tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:cyan", "tab:olive")
_FAMILY = {"default": ("black", "D"), "ml": ("tab:red", "s"), "greedy": ("tab:orange", "^")}
# Where labels go in the trade-off plot, per family (ML and greedy often coincide).
_LABEL_POS = {"default": ((-8, 6), "right", "bottom"), "ml": ((-7, 7), "right", "bottom"),
              "greedy": ((7, -7), "left", "top"), "learned": ((7, 7), "left", "bottom")}
# Beyond this max/min ratio an axis goes logarithmic.
_LOG_RATIO = 20.0


def _family(name: str) -> str:
    if name in _FAMILY:
        return name
    return "fixed" if name.startswith("fixed-") else "learned"


def _fixed_value(name: str) -> float:
    return float(name.split("=", 1)[1])


def _both(name: str) -> bool:
    return name.startswith("fixed-both-")


def policy_style(results, name: str) -> dict:
    """``{"color", "marker", "family"}`` of policy ``name`` in ``results``."""
    fam = _family(name)
    if fam in _FAMILY:
        c, m = _FAMILY[fam]
    elif fam == "fixed":
        grid = results.grid
        i = int(np.argmin(np.abs(grid - _fixed_value(name))))
        c, m = plt.get_cmap("viridis")(0.05 + 0.85 * i / max(1, grid.size - 1)), "o"
    else:
        learned = [n for n in results.names if _family(n) == "learned"]
        c, m = _LEARNED_COLORS[learned.index(name) % len(_LEARNED_COLORS)], "*"
    return {"color": c, "marker": m, "family": fam}


def _label(results, name: str) -> str:
    """Short label as the prose writes it: fixed values as ``κ = 2``."""
    return policy_label(name[len("fixed-"):] if name.startswith("fixed-") else name)


def selected_policies(results) -> list[str]:
    """Default, the fixed value with the lowest RMSE, and every adaptive policy (ML, greedy, learned)."""
    names = ["default"] if "default" in results else []
    fixed = [n for n in results.names if _family(n) == "fixed"]
    if fixed:
        best = min(fixed, key=lambda n: results[n].rmse)
        if "default" not in results or not np.isclose(_fixed_value(best), results.config["default"]):
            names.append(best)
    return names + [n for n in results.names if _family(n) in ("ml", "greedy", "learned")]


def _axes(ax, figsize) -> tuple[Figure, plt.Axes]:
    if ax is not None:
        return ax.figure, ax
    fig, ax = plt.subplots(figsize=figsize, layout="constrained")
    return fig, ax


def _title(results, what: str) -> str:
    c = results.config
    return f"{what} — {c.get('experiment') or c.get('model')} (M = {c['n_runs']})"


def _unit(unit: str | None) -> str:
    return f" ({unit})" if unit else ""


def _wide(values) -> bool:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    return v.size > 0 and v.max() / v.min() > _LOG_RATIO


def _time_plot(results, key: str, policies, ax, band: bool, logy, ylabel: str, what: str) -> tuple[Figure, plt.Axes]:
    fig, ax = _axes(ax, (8, 4.2))
    names = selected_policies(results) if policies is None else list(policies)
    k = np.arange(1, results.config["n_steps"] + 1)
    for n in names:
        p, st = results[n], policy_style(results, n)
        y = getattr(p, key)
        ax.plot(k, y, color=st["color"], lw=1.1, label=policy_label(n))
        if band:
            lo, hi = getattr(p, key + "_band")
            ax.fill_between(k, lo, hi, color=st["color"], alpha=0.15, lw=0)
    if logy is None:
        logy = _wide(np.concatenate([getattr(results[n], key) for n in names]))
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel("time step k")
    ax.set_ylabel(ylabel)
    ax.set_xlim(k[0], k[-1])
    ax.set_title(_title(results, what))
    ax.grid(alpha=0.3)
    return fig, ax


def plot_rmse_time(results, policies: Sequence[str] | None = None, ax=None, floor: float | np.ndarray | None = None,
                   band: bool = True, logy: bool | None = None, unit: str | None = None) -> Figure:
    """``RMSE_k`` over time with pointwise 95 % bootstrap bands.

    ``policies`` defaults to :func:`selected_policies`; ``floor`` is a
    reference (a number, or a ``(T,)`` series such as a point-mass filter's RMSE_k);
    ``unit`` (e.g. ``"m"``) labels the RMSE axis.
    """
    fig, ax = _time_plot(results, "rmse_t", policies, ax, band, logy, "RMSE$_k$" + _unit(unit), "RMSE over time")
    if floor is not None:
        f = np.asarray(floor, dtype=float)
        if f.ndim == 0:
            ax.axhline(float(f), color="0.3", ls=":", lw=1.2, label=f"floor {float(f):.3g}")
        else:
            ax.plot(np.arange(1, f.size + 1), f, color="0.3", ls=":", lw=1.2, label="floor")
    ax.legend(fontsize=8, ncol=2)
    return fig


def plot_anees_time(results, policies: Sequence[str] | None = None, ax=None, band: bool = True,
                    logy: bool | None = None, level: float = 0.95) -> Figure:
    """``ANEES_k`` over time; the grey band is where the average of ``M``
    chi2(nx) values falls with probability ``level`` (a consistent filter's ANEES_k)."""
    fig, ax = _time_plot(results, "anees_t", policies, ax, band, logy, "ANEES$_k$", "ANEES over time")
    nx, M = results.config["nx"], results.config["n_runs"]
    lo, hi = chi2_bounds(nx, M, level)
    ax.axhspan(lo, hi, facecolor="none", edgecolor="0.35", hatch="////", lw=0.6,
               label=f"consistent ({level:.0%} $\\chi^2$ band, $n_x$ = {nx})")
    ax.axhline(nx, color="0.4", lw=0.8, ls="--")
    ax.legend(fontsize=8, ncol=2)
    return fig


def _bars(results, metric: str, policies, ax, xlabel: str, what: str, logx) -> tuple[Figure, plt.Axes]:
    names = results.names if policies is None else list(policies)
    fig, ax = _axes(ax, (7, 0.32 * len(names) + 1.4))
    vals = np.array([getattr(results[n], metric) for n in names])
    cis = np.array([getattr(results[n], metric + "_ci") for n in names])
    y = np.arange(len(names))[::-1]  # first policy on top
    for yi, n, v, (lo, hi) in zip(y, names, vals, cis):
        st = policy_style(results, n)
        pts = getattr(results[n], "seed_points", {}).get(metric)
        if pts is not None:  # a seed group: each training seed beside the aggregate (IQM, two-level CI)
            jitter = np.linspace(-0.22, 0.22, len(pts))
            ax.scatter(pts, yi + jitter, s=10, color=st["color"], alpha=0.55, lw=0, zorder=1)
            vals = np.append(vals, pts)
        ax.errorbar(v, yi, xerr=[[v - lo], [hi - v]], fmt=st["marker"], color=st["color"], ms=6, capsize=3,
                    mec="black" if st["family"] != "fixed" else st["color"], mew=0.6, zorder=2)
    ax.set_yticks(y, [_label(results, n) for n in names])
    if logx is None:
        logx = _wide(np.concatenate([vals, cis.ravel()]))
    if logx:
        ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_title(_title(results, what), fontsize=10)
    ax.grid(axis="x", alpha=0.3, which="both")
    ax.set_ylim(-0.7, len(names) - 0.3)
    return fig, ax


def plot_rmse_bars(results, policies: Sequence[str] | None = None, ax=None, floor: float | None = None,
                   logx: bool | None = None, unit: str | None = None) -> Figure:
    """Time-averaged RMSE per policy with 95 % bootstrap CIs (paper Figs 1 and 4);
    ``unit`` (e.g. ``"m"``) labels the axis."""
    fig, ax = _bars(results, "rmse", policies, ax, "time-averaged RMSE" + _unit(unit), "Time-averaged RMSE", logx)
    if floor is not None:
        ax.axvline(floor, color="0.3", ls=":", lw=1.2, label=f"floor {floor:.3g}")
        ax.legend(fontsize=8)
    return fig


def plot_anees_bars(results, policies: Sequence[str] | None = None, ax=None, logx: bool | None = None) -> Figure:
    """Time-averaged ANEES per policy with 95 % bootstrap CIs and the ideal ``nx``, a dashed line that the
    x label names (paper Figs 2 and 5)."""
    nx = results.config["nx"]
    # The dashed line is named in the axis label, not in a legend: inside the axes a legend covered the first
    # policy's marker whenever its ANEES was large (chapter 12's default), and beside them it narrowed the panels
    # until side-by-side titles ran into each other. The label costs no room and suits every caller.
    fig, ax = _bars(results, "anees", policies, ax, f"time-averaged ANEES (dashed: ideal, $n_x$ = {nx})",
                    "Time-averaged ANEES", logx)
    ax.axvline(nx, color="0.4", ls="--", lw=1)
    return fig


_OFFSETS = [((5, 4), "left", "bottom"), ((5, -4), "left", "top"), ((-5, 4), "right", "bottom"),
            ((-5, -4), "right", "top"), ((0, 8), "center", "bottom"), ((0, -8), "center", "top"),
            ((9, -1), "left", "center"), ((-9, -1), "right", "center")]


def _place_labels(results, names, ax) -> None:
    """Label every point, choosing for each the candidate offset whose text box
    overlaps least with the markers and the labels placed so far (adaptive
    policies first, at their family's preferred spot when it is free)."""
    to_pt = 72.0 / ax.figure.dpi
    pos = {n: ax.transData.transform((results[n].rmse, results[n].anees)) * to_pt for n in names}
    boxes = [(x - 4, y - 4, x + 4, y + 4) for x, y in pos.values()]  # the markers

    def box(n, off, ha, va, fs):
        x, y = pos[n][0] + off[0], pos[n][1] + off[1]
        w, h = 0.55 * fs * len(_label(results, n)), 1.1 * fs
        x0 = {"left": x, "right": x - w, "center": x - w / 2}[ha]
        y0 = {"bottom": y, "top": y - h, "center": y - h / 2}[va]
        return x0, y0, x0 + w, y0 + h

    def overlap(b):
        return sum(max(0.0, min(b[2], o[2]) - max(b[0], o[0])) * max(0.0, min(b[3], o[3]) - max(b[1], o[1]))
                   for o in boxes)

    order = sorted(names, key=lambda n: _family(n) == "fixed")
    for n in order:
        st = policy_style(results, n)
        big = st["family"] != "fixed"
        fs = 8 if big else 7
        cands = ([_LABEL_POS[st["family"]]] if st["family"] in _LABEL_POS else []) + _OFFSETS
        best = min(cands, key=lambda c: overlap(box(n, *c, fs)) - 1e-9 * (c is cands[0]))
        boxes.append(box(n, *best, fs))
        off, ha, va = best
        ax.annotate(_label(results, n), (results[n].rmse, results[n].anees), xytext=off, textcoords="offset points",
                    ha=ha, va=va, fontsize=fs, color=st["color"] if big else "0.25", zorder=4)


def _tradeoff_ax(results, names, ax, floor, logx, logy, annotate, zoom: bool, unit: str | None = None) -> None:
    for both in (False, True):  # fixed in the update only, and in both steps: one line each, in grid order
        fixed = sorted((n for n in names if _family(n) == "fixed" and _both(n) == both), key=_fixed_value)
        if len(fixed) > 1:
            ax.plot([results[n].rmse for n in fixed], [results[n].anees for n in fixed], color="0.6", lw=1,
                    ls=":" if both else "-", zorder=1)
    for n in names:
        p, st = results[n], policy_style(results, n)
        big = st["family"] != "fixed"
        pts = getattr(p, "seed_points", None)
        if pts and not zoom:  # a seed group: one faint point per training seed
            ax.scatter(pts["rmse"], pts["anees"], s=14, color=st["color"], alpha=0.45, lw=0, zorder=1)
        ax.errorbar(p.rmse, p.anees, xerr=[[p.rmse - p.rmse_ci[0]], [p.rmse_ci[1] - p.rmse]],
                    yerr=[[p.anees - p.anees_ci[0]], [p.anees_ci[1] - p.anees]], fmt=st["marker"], color=st["color"],
                    ms=9 if big else 6, mec="black" if big else st["color"], mew=0.6, capsize=2, elinewidth=0.8,
                    zorder=3 if big else 2, label=None if (zoom or not big) else policy_label(n))
    pts = lambda n, m: [] if zoom else list(getattr(results[n], "seed_points", {}).get(m, []))
    xs = np.concatenate([[results[n].rmse, *results[n].rmse_ci, *pts(n, "rmse")] for n in names])
    ys = np.concatenate([[results[n].anees, *results[n].anees_ci, *pts(n, "anees")] for n in names])
    nx = results.config["nx"]
    if logx is None:
        logx = _wide(xs)
    if logy is None:
        logy = _wide(ys if zoom else np.append(ys, nx))
    if logx:
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    if zoom:
        pad = lambda lo, hi, log: ((lo / (hi / lo) ** 0.08, hi * (hi / lo) ** 0.08) if log
                                   else (lo - 0.08 * (hi - lo), hi + 0.08 * (hi - lo)))
        ax.set_xlim(*pad(xs.min(), xs.max(), logx))
        ax.set_ylim(*pad(ys.min(), ys.max(), logy))
    if annotate:
        _place_labels(results, names, ax)
    if not zoom or ax.get_ylim()[0] <= nx <= ax.get_ylim()[1]:
        ax.axhline(nx, color="0.4", ls="--", lw=1, label=None if zoom else f"ideal ANEES = $n_x$ = {nx}")
    if floor is not None:
        ax.axvline(floor, color="0.3", ls=":", lw=1.2, label=None if zoom else f"RMSE floor {floor:.3g}")
    ax.set_xlabel("time-averaged RMSE" + _unit(unit))
    ax.set_ylabel("time-averaged ANEES")
    ax.grid(alpha=0.3, which="both")


def plot_tradeoff(results, policies: Sequence[str] | None = None, ax=None, floor: float | None = None,
                  logx: bool | None = None, logy: bool | None = None, annotate: bool = True,
                  zoom: bool | None = None, unit: str | None = None) -> Figure:
    """Time-averaged RMSE (x) vs ANEES (y) with 95 % CI bars, one labelled point
    per policy; fixed values joined in grid order (paper Figs 3 and 6).

    ``zoom`` (default: when no ``ax`` is given and at least three points crowd
    around the best RMSE) adds a right panel on the policies within 15 % of
    both axis spans (in plotted, possibly log, scale) of the best-RMSE point;
    ``unit`` (e.g. ``"m"``) labels the RMSE axis.
    """
    names = results.names if policies is None else list(policies)
    rm = np.array([results[n].rmse for n in names])
    an = np.array([results[n].anees for n in names])
    sx = np.log(rm) if (logx if logx is not None else _wide(rm)) else rm
    sy = np.log(an) if (logy if logy is not None else _wide(np.append(an, results.config["nx"]))) else an
    b = int(np.argmin(rm))
    span = lambda v: max(np.ptp(v), 1e-300)
    close = (np.abs(sx - sx[b]) <= 0.15 * span(sx)) & (np.abs(sy - sy[b]) <= 0.15 * span(sy))
    near = [n for n, c in zip(names, close) if c]
    if zoom is None:
        zoom = ax is None and 3 <= len(near) < len(names)
    if zoom and ax is None:
        fig, (ax, axz) = plt.subplots(1, 2, figsize=(13, 5.8), layout="constrained", width_ratios=(1, 1))
    else:
        fig, ax = _axes(ax, (8, 6))
        axz = None
    _tradeoff_ax(results, names, ax, floor, logx, logy, annotate, zoom=False, unit=unit)
    ax.legend(fontsize=8, loc="best")
    if axz is not None:
        _tradeoff_ax(results, near, axz, floor, None, None, annotate, zoom=True, unit=unit)
        axz.set_title("zoom: around the best RMSE", fontsize=10)
        fig.suptitle(_title(results, "RMSE vs ANEES"))
    else:
        ax.set_title(_title(results, "RMSE vs ANEES"))
    return fig


def plot_choices(results, policy: str, ax=None) -> Figure:
    """Stacked fractions of runs choosing each grid value at every step (``policy``'s ``choices``)."""
    p = results[policy]
    grid = results.grid
    fig, ax = _axes(ax, (8, 4))
    k = np.arange(1, p.choices.shape[0] + 1)
    colors = _colors(grid.size)  # qualitative: a 13-value sequential map cannot be told apart
    used = p.choices.sum(axis=0) > 0
    pname = results.config.get("param_name", "param")
    ax.stackplot(k, p.choices.T[used], colors=[c for c, u in zip(colors, used) if u],
                 labels=[param_label(pname, g) for g, u in zip(grid, used) if u], lw=0)
    ax.set_xlim(k[0], k[-1])
    ax.set_ylim(0, 1)
    ax.set_xlabel("time step k")
    ax.set_ylabel("fraction of runs")
    ax.set_title(_title(results, f"parameter chosen by {policy}"))
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5), reverse=True)
    return fig


def plot_usage(results, policies: Sequence[str] | None = None, ax=None) -> Figure:
    """How often each grid value is used (fraction of all run-steps), grouped bars per policy.

    ``policies`` defaults to the adaptive ones (ML, greedy, learned).
    """
    names = [n for n in results.names if _family(n) in ("ml", "greedy", "learned")] if policies is None else list(policies)
    grid = results.grid
    fig, ax = _axes(ax, (8, 4))
    width = 0.8 / max(1, len(names))
    x = np.arange(grid.size)
    for i, n in enumerate(names):
        u = results[n].usage
        ax.bar(x + (i - (len(names) - 1) / 2) * width, u / max(1, u.sum()), width, color=policy_style(results, n)["color"],
               label=policy_label(n), edgecolor="black", lw=0.4)
    ax.set_xticks(x, [f"{g:g}" for g in grid])
    ax.set_xlabel(param_label(results.config.get("param_name", "parameter")))
    ax.set_ylabel("fraction of run-steps")
    ax.set_title(_title(results, "parameter usage"))
    ax.grid(axis="y", alpha=0.3)
    if names:
        ax.legend(fontsize=8)
    return fig


def save_figures(results, out_dir: str | Path, floor: float | None = None, dpi: int = 130) -> list[Path]:
    """Write every figure as a PNG into ``out_dir``; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figs = {
        "rmse_time": plot_rmse_time(results, floor=floor),
        "anees_time": plot_anees_time(results),
        "rmse_bars": plot_rmse_bars(results, floor=floor),
        "anees_bars": plot_anees_bars(results),
        "tradeoff": plot_tradeoff(results, floor=floor),
    }
    adaptive = [n for n in results.names if _family(n) in ("ml", "greedy", "learned")]
    if adaptive:
        figs["usage"] = plot_usage(results)
    for n in adaptive:
        figs[f"choices_{n}"] = plot_choices(results, n)
    paths = []
    for stem, fig in figs.items():
        safe = "".join(ch if ch.isalnum() or ch in "-_=." else "_" for ch in stem)
        path = out / f"{safe}.png"
        atomic_savefig(fig, path, dpi=dpi)
        plt.close(fig)
        paths.append(path)
    return paths
