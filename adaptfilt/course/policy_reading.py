r"""Reading what policies choose, as chapter 8 (Reading the stored policies) does: over time, by grid
value, against a feature, and at one UNGM information state; chapter 7 uses the last as its widget
and chapter 12 the usage lines.

========================================  =========================================================
function                                  what
========================================  =========================================================
plot_share_over_time                      the share of runs at a parameter ``>=`` a value, per step
                                          (a seed group: averaged over its seeds)
usage_lines                               per policy: RMSE and the grid values it uses
equal_count_bins                          medians of x and means of y in bins of equal count of x
plot_switch_off                           the probability of the large values against a feature
ungm_state, plot_policy_probs             every policy's ``pi(theta | s)`` at one raw UNGM state
show_policy_probs                         the widget body (chapters 7 and 8)
========================================  =========================================================

Tested in ``tests/test_course_policy_reading.py``; figures use :mod:`adaptfilt.style`.
"""
from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np

from adaptfilt.course.common import figure_axes
from adaptfilt.seed_stats import seed_groups

__all__ = ["plot_share_over_time", "usage_lines", "equal_count_bins", "plot_switch_off", "ungm_state",
           "plot_policy_probs", "show_policy_probs"]


def plot_share_over_time(results, policies: Sequence[str], at_least: float, ax=None,
                         overlay: Callable[[np.ndarray], np.ndarray] | None = None, overlay_label: str = ""):
    r"""Share of runs whose parameter is ``>= at_least`` at each step ``k``, per policy
    (from ``Results[...].choices``; a seed group's choices are averaged over seeds),
    with an optional ``overlay(k)`` on a second axis (e.g. the forcing of the dynamics)."""
    fig, ax = figure_axes(ax)
    grid = results.grid
    for name in policies:
        members = seed_groups(results.names).get(name, [name])
        ch = np.mean([results[m].choices for m in members], axis=0)
        k = np.arange(1, ch.shape[0] + 1)
        ax.plot(k, ch[:, grid >= at_least].sum(axis=1), label=name)
    ax.set(xlabel="time step k", ylabel=f"share of runs with $\\kappa \\geq$ {at_least:g}", ylim=(0, None))
    if overlay is not None:
        ax2 = ax.twinx()
        ax2.plot(k, overlay(k), color="0.55", lw=1, ls="--")
        ax2.set_ylabel(overlay_label, color="0.4")
        ax2.grid(False)
        ax2.spines["right"].set_visible(True)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=len(policies))  # below the axes, off the data
    return fig


def usage_lines(results, names: Sequence[str], split: float = 50.0, min_share: float = 0.01) -> str:
    r"""One line per policy: its RMSE, the share of steps with a parameter ``<= split``
    and every grid value used in at least ``min_share`` of the steps."""
    grid = results.grid
    out = []
    for n in names:
        u = np.asarray(results[n].usage, dtype=float)
        u = u / u.sum()
        used = ", ".join(f"{g:g}: {x:.0%}" for g, x in zip(grid, u) if x >= min_share)
        out.append(f"{n:12s} RMSE {results[n].rmse:5.3g} | {split:g} or less: {u[grid <= split].sum():4.0%} | {used}")
    return "\n".join(out)


def equal_count_bins(x: np.ndarray, y: np.ndarray, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Medians of ``x`` and means of ``y`` in ``n_bins`` bins of equal count of ``x``."""
    order = np.argsort(x)
    parts = np.array_split(order, n_bins)
    return np.array([np.median(x[p]) for p in parts]), np.array([y[p].mean() for p in parts])


def plot_switch_off(policies: Sequence, states: np.ndarray, columns: Mapping[str, int], at_least: float,
                    n_bins: int = 12):
    r"""The probability ``pi(theta >= at_least | s)`` that each policy puts on the large
    parameter values, averaged in bins of equal count of one feature (``|feature|``),
    one panel per entry of ``columns`` (label -> column of ``states``), one line per
    policy. All policies are probed on the same raw ``states`` (their own scalers
    apply), so the lines compare functions, not the states each policy visits."""
    from adaptfilt import style

    states = states[np.isfinite(states).all(axis=1)]
    fig, axes = style.figure(1, len(columns), size=(4.2 * len(columns), 3.3), sharey=True)
    axes = np.atleast_1d(axes)
    cols = style.colors(len(policies))
    for ax, (label, j) in zip(axes, columns.items()):
        x = np.abs(states[:, j])
        for pol, c in zip(policies, cols):
            p = pol.probs(states)[:, np.asarray(pol.grid) >= at_least].sum(axis=1)
            mid, mean = equal_count_bins(x, p, n_bins)
            ax.plot(mid, mean, "o-", ms=3, color=c, label=pol.name)
        ax.set(xscale="log", xlabel=f"{label} (bins of equal count)", ylim=(-0.02, 1.02))
    axes[0].set_ylabel(f"$\\pi(\\kappa \\geq$ {at_least:g}$\\,|\\,s)$")
    axes[-1].legend(loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8)
    return fig


def ungm_state(P_pred: float, innov: float, x_pred: float = 5.0, k: int = 100) -> np.ndarray:
    r"""A raw UNGM information state ``(1, 7)`` at step ``k`` (the paper's index) in the layout
    ``paper+time``: ``[x_pred, tr P, log det P, z, innov, cos 0.05k, sin 0.05k]``, consistent with
    the default-parameter update: the unscented mean of ``x^2/20`` is exact for every
    kappa, ``(x_pred^2 + P_pred)/20``, so ``z = (x_pred^2 + P_pred)/20 + innov``."""
    from adaptfilt.models import ungm

    if not P_pred > 0:
        raise ValueError(f"P_pred must be > 0, got {P_pred}")
    z = (x_pred ** 2 + P_pred) / 20.0 + innov
    phase = np.asarray(ungm().time_features(k), dtype=float)
    return np.array([[x_pred, P_pred, np.log(P_pred), z, innov, *phase]])


def plot_policy_probs(policies: Sequence, state: np.ndarray, ax=None, title: str | None = None,
                      colorbar: bool = False):
    r"""``pi(theta | s)`` of each policy at one raw information state ``(1, d)`` as a heat map:
    one row per policy, one column per grid value, the most probable value of each row marked."""
    fig, ax = figure_axes(ax)
    P = np.concatenate([p.probs(state) for p in policies])          # (n_policies, G)
    grid = np.asarray(policies[0].grid)
    im = ax.imshow(P, vmin=0.0, vmax=1.0, cmap="Blues", aspect="auto", interpolation="nearest")
    ax.plot(P.argmax(axis=1), np.arange(len(policies)), "o", ms=3, color="#D55E00")
    ax.set_xticks(np.arange(grid.size), [f"{g:g}" for g in grid], rotation=90)
    ax.set_yticks(np.arange(len(policies)), [p.name for p in policies])
    ax.set_xlabel(r"$\kappa$")
    ax.grid(False)
    if title:
        ax.set_title(title)
    if colorbar:
        fig.colorbar(im, ax=ax, label=r"$\pi(\kappa\,|\,s)$")
    return fig


def show_policy_probs(policies: Sequence, P_pred: float = 1.0, innov: float = 0.0, x_pred: float = 5.0,
                      k: int = 100) -> None:
    """The widget body of chapter 7: :func:`plot_policy_probs` at :func:`ungm_state`."""
    import matplotlib.pyplot as plt

    plot_policy_probs(policies, ungm_state(P_pred, innov, x_pred, k), colorbar=True,
                      title=f"tr P = {P_pred:.3g}, innovation = {innov:+.2f}, x_pred = {x_pred:g}, k = {k}")
    plt.show()
