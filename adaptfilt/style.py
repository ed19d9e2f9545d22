"""One plotting style for every figure of the course (the role of d2l's ``plot``
or Labbe's ``book_plots``).

=====================  ==========================================================
function               what
=====================  ==========================================================
use                    set matplotlib's rcParams: readable fonts and legends, a
                       colour-blind-safe colour cycle, light grid, tight layout
figure                 ``fig, ax = figure()`` / ``fig, axes = figure(1, 3)``
small_multiples        one panel per value of a knob (the static stand-in for a widget)
param_label            ``param_label("kappa", 200)`` -> ``"κ = 200"``
policy_label           ``policy_label("fixed-kappa=200")`` -> ``"fixed κ = 200"``
colors                 ``n`` colours that can be told apart (qualitative, ordered)
=====================  ==========================================================

Example
-------
>>> from adaptfilt import style
>>> style.use()
>>> fig, ax = style.figure(title="a figure")
>>> _ = ax.plot([0, 1], [0, 1], label=style.param_label("kappa", 2))
>>> style.param_label("n_iter", 10)
'N_it = 10'
"""
from __future__ import annotations

import re
from typing import Callable, Sequence

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

__all__ = ["GREEK", "OKABE_ITO", "use", "figure", "small_multiples", "param_label", "policy_label", "colors"]

#: Parameter names of the library -> how the prose writes them.
GREEK = {"kappa": "κ", "gamma": "γ", "theta": "θ", "omega": "ω", "rho": "ρ", "sigma": "σ", "alpha": "α",
         "tau": "τ", "n_iter": "N_it"}

#: Okabe & Ito's colour-blind-safe qualitative palette (black last: it is the
#: colour of references such as the exact filter).
OKABE_ITO = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#CC79A7", "#56B4E9", "#F0E442", "#000000")

#: The rcParams :func:`use` sets (a reader can inspect or override them).
RC = {
    "figure.figsize": (7.0, 3.6),
    "figure.dpi": 100,
    "savefig.dpi": 130,
    "figure.constrained_layout.use": True,
    "font.size": 10.5,
    "axes.titlesize": 11,
    "axes.labelsize": 10.5,
    "xtick.labelsize": 9.5,
    "ytick.labelsize": 9.5,
    "legend.fontsize": 9,
    "legend.title_fontsize": 9,
    "legend.framealpha": 0.85,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "lines.linewidth": 1.5,
    "axes.spines.top": False,
    "axes.spines.right": False,
}


def use() -> None:
    """Set the course style (:data:`RC` and the :data:`OKABE_ITO` colour cycle) in matplotlib's rcParams."""
    matplotlib.rcParams.update(RC)
    matplotlib.rcParams["axes.prop_cycle"] = matplotlib.cycler(color=list(OKABE_ITO))


def figure(nrows: int = 1, ncols: int = 1, *, size: tuple[float, float] | None = None, title: str | None = None,
           sharex: bool = False, sharey: bool = False):
    """A new figure with ``nrows x ncols`` axes in the course style.

    Returns ``(fig, ax)`` for one panel and ``(fig, axes)`` (a flat array) for
    several. ``size`` defaults to the style's width and a height that grows
    with the rows; ``title`` becomes the figure's suptitle.
    """
    if nrows < 1 or ncols < 1:
        raise ValueError(f"figure needs at least one row and one column, got nrows={nrows}, ncols={ncols}")
    w, h = matplotlib.rcParams["figure.figsize"]
    if size is None:
        size = (w, h if nrows == 1 else 0.75 * h * nrows)
    fig, axes = plt.subplots(nrows, ncols, figsize=size, sharex=sharex, sharey=sharey, squeeze=False,
                             layout="constrained")
    if title:
        fig.suptitle(title)
    axes = axes.ravel()
    return (fig, axes[0]) if axes.size == 1 else (fig, axes)


def small_multiples(draw: Callable, values: Sequence, name: str | None = None, *, title: str | None = None,
                    size: tuple[float, float] | None = None, sharey: bool = True, **kwargs):
    """One panel per knob value: ``draw(value, ax=ax, **kwargs)`` for each of ``values``.

    This is what a static page shows in place of an ``ipywidgets.interact``
    slider. ``name`` (e.g. ``"kappa"``) titles each panel with
    :func:`param_label` unless ``draw`` set a title itself. Returns the figure.
    """
    values = list(values)
    if not values:
        raise ValueError("small_multiples needs at least one value")
    w, h = matplotlib.rcParams["figure.figsize"]
    fig, axes = figure(1, len(values), size=size or (w, 0.8 * h), title=title, sharey=sharey)
    axes = np.atleast_1d(axes)
    for v, ax in zip(values, axes):
        draw(v, ax=ax, **kwargs)
        if name is not None and not ax.get_title():
            ax.set_title(param_label(name, v))
    if sharey:  # one y label for the row
        for ax in axes[1:]:
            ax.set_ylabel("")
    return fig


def param_label(name: str, value=None, fmt: str = "g") -> str:
    """A parameter as the prose writes it: ``("kappa", 200)`` -> ``"κ = 200"``,
    ``("kappa",)`` -> ``"κ"``; names without a Greek letter stay as they are."""
    sym = GREEK.get(name, name)
    if value is None:
        return sym
    return f"{sym} = {format(value, fmt) if isinstance(value, (int, float, np.floating, np.integer)) else value}"


_PARAM_IN_NAME = re.compile(r"\b(" + "|".join(map(re.escape, GREEK)) + r")\s*=\s*([-+0-9.eE]+)")


def policy_label(name: str) -> str:
    """A policy or filter name for a legend: ``fixed-kappa=200`` -> ``fixed κ = 200``,
    ``UKF kappa=2`` -> ``UKF κ = 2``; other names are returned unchanged."""
    label = _PARAM_IN_NAME.sub(lambda m: param_label(m.group(1), m.group(2)), name)
    return re.sub(r"^fixed-", "fixed ", label)


def colors(n: int) -> list:
    """``n`` colours that can be told apart, in a fixed order.

    Up to 8: :data:`OKABE_ITO`; up to 20: matplotlib's ``tab20`` (dark/light
    pairs, so neighbours in an ordered grid share a hue but differ in
    lightness); beyond that a sequential map, which cannot keep ``n`` colours
    apart (label such figures directly).
    """
    if n < 0:
        raise ValueError(f"colors needs n >= 0, got {n}")
    if n <= len(OKABE_ITO):
        return list(OKABE_ITO[:n])
    if n <= 20:
        cmap = plt.get_cmap("tab20")
        return [cmap(i) for i in range(n)]
    cmap = plt.get_cmap("viridis")
    return [cmap(0.05 + 0.9 * i / (n - 1)) for i in range(n)]
