r"""Chapter 2, Gaussian-assumed filters: the unscented transform and its predicted measurement
covariance against ``kappa`` (:func:`unscented_moments`, :func:`unscented_pzz`, :func:`plot_unscented`,
widget :func:`show_unscented`), reference moments by Gauss-Hermite quadrature
(:func:`gauss_hermite_moments`) and the rules' errors against them (:func:`rule_errors`), the
stochastic rule's draws (:func:`plot_sif_draws`, widget :func:`show_sif_draws`), ANEES and per-run
RMSE figures and line-of-sight errors (:func:`line_of_sight_errors`), and the checks of the
chapter's implement-it-yourself exercises (:func:`check_unscented`, :func:`check_update`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from adaptfilt import metrics
from adaptfilt.course.common import Score, figure_axes, pyplot, chi2_median

__all__ = ["ungm_h", "bearing", "unscented_moments", "unscented_pzz", "plot_pzz_vs_kappa", "plot_unscented",
           "show_unscented", "gauss_hermite_moments", "RuleErrors", "rule_errors", "plot_rule_errors",
           "plot_sif_draws", "show_sif_draws", "plot_anees_k", "plot_per_run_rmse",
           "line_of_sight_errors", "plot_line_of_sight_errors", "check_unscented", "check_update"]


# ======================================================================== chapter 2
def ungm_h(X: np.ndarray) -> np.ndarray:
    """UNGM's measurement function ``x^2 / 20`` (any layout)."""
    return X ** 2 / 20


def bearing(X: np.ndarray) -> np.ndarray:
    """``atan2(x_2, x_1)`` in the rules' run-last layout: ``X (2, points, runs) -> (1, points, runs)``."""
    return np.arctan2(X[1:2], X[0:1])


def unscented_moments(h: Callable, kappas, m, P):
    """Unscented moments of ``h(x)``, ``x ~ N(m, P)``, for every ``kappa`` in one batched call.

    ``m (n,)``, ``P (n, n)``; returns :class:`~adaptfilt.rules.Moments` with
    the run axis (last) indexing ``kappas``.
    """
    from adaptfilt.rules import UnscentedRule

    kappas = np.atleast_1d(np.asarray(kappas, dtype=float))
    m, P = np.atleast_1d(np.asarray(m, dtype=float)), np.atleast_2d(np.asarray(P, dtype=float))
    G = kappas.size
    return UnscentedRule().moments(h, np.repeat(m[:, None], G, axis=1), np.repeat(P[:, :, None], G, axis=2), kappas)


def unscented_pzz(kappas, m: float, P: float, R: float = 0.1, h: Callable = ungm_h) -> np.ndarray:
    r"""``P^zz`` of the unscented rule for a scalar ``x ~ N(m, P)`` and each ``kappa``.

    For UNGM's ``h = x^2/20`` it is :math:`(4m^2P + \kappa P^2)/400 + R`
    (the exact value has :math:`2P^2` in place of :math:`\kappa P^2`).
    """
    return unscented_moments(h, kappas, [m], [[P]]).cov[0, 0] + R


def _pzz_exact_ungm(m: float, P: float, R: float) -> float:
    return (4 * m ** 2 * P + 2 * P ** 2) / 400 + R


def plot_pzz_vs_kappa(kappas, cases: Sequence[tuple[float, float]], R: float = 0.1, ax=None):
    """UNGM: ``P^zz`` of the unscented rule against ``kappa`` for each ``(m, P)``, with the exact value."""
    from adaptfilt.style import param_label

    fig, ax = figure_axes(ax)
    for m, P in cases:
        line, = ax.plot(kappas, unscented_pzz(kappas, m, P, R), label=f"UT, m = {m:g}, P = {P:g}")
        ax.axhline(_pzz_exact_ungm(m, P, R), color=line.get_color(), ls="--", lw=1, label=f"exact, m = {m:g}, P = {P:g}")
    ax.axvline(2, color="k", ls=":", lw=1)
    ax.annotate(r"$n+\kappa=3$", (2, 0), xytext=(4, 4), textcoords="offset points")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set(xlabel=param_label("kappa"), ylabel=r"$P^{zz}$",
           title=r"UNGM measurement $x^2/20$: $P^{zz}$ of the unscented rule vs " + param_label("kappa"))
    ax.legend(ncol=2)
    return fig


def plot_unscented(kappa: float, ax=None, m: float = 5.0, P: float = 4.0, R: float = 0.1):
    r"""The unscented rule on UNGM's measurement for one ``kappa``: the sigma points of
    ``x ~ N(m, P)`` drawn as stems whose height is their weight, over the (scaled)
    density of ``x``, with ``P^zz`` of the rule and the exact value.

    Points :math:`m` and :math:`m\pm\sqrt{(1+\kappa)P}`, weights
    :math:`\kappa/(1+\kappa)` and :math:`1/(2(1+\kappa))`; a negative centre
    weight (``kappa < 0``) is drawn below zero. Returns the figure.
    """
    from adaptfilt.style import OKABE_ITO, param_label

    if not kappa > -1:
        raise ValueError(f"kappa must satisfy 1 + kappa > 0 for a scalar state, got {kappa}")
    fig, ax = figure_axes(ax)
    s = np.sqrt((1 + kappa) * P)
    pts, w = np.array([m - s, m, m + s]), np.array([0.5, kappa, 0.5]) / (1 + kappa)
    xs = np.linspace(m - 4.5 * np.sqrt(P), m + 4.5 * np.sqrt(P), 300)
    ax.fill_between(xs, np.exp(-0.5 * (xs - m) ** 2 / P), color="0.85", lw=0, label=r"$\mathcal{N}(m, P)$ (scaled)")
    ax.vlines(pts, 0, w, color=OKABE_ITO[0], lw=2)
    ax.plot(pts, w, "o", color=OKABE_ITO[0], label="sigma points (height: weight)")
    ax.axhline(0, color="k", lw=0.6)
    ax.margins(y=0.08)  # autoscaled: small multiples with a shared y axis then show every weight
    pzz = float(unscented_pzz([kappa], m, P, R)[0])
    ax.set(xlabel="$x$", ylabel="weight", xlim=(min(xs[0], pts[0]) - 1, max(xs[-1], pts[-1]) + 1),
           title=f"{param_label('kappa', round(float(kappa), 3))}\n$P^{{zz}}$ {pzz:.3g} (exact {_pzz_exact_ungm(m, P, R):.3g})")
    return fig


def show_unscented(kappa: float = 2.0, m: float = 5.0, P: float = 4.0) -> None:
    """Widget callback (``ipywidgets.interact``): draw :func:`plot_unscented` and show it."""
    plot_unscented(kappa, m=m, P=P)
    pyplot().show()


def gauss_hermite_moments(g: Callable, m, P, order: int = 60) -> tuple[float, float]:
    r"""Mean and variance of a scalar ``g(x)``, ``x ~ N(m, P)`` in ``n`` dimensions, by the
    tensor-product Gauss-Hermite rule with ``order`` nodes per axis (``order ** n``
    evaluations): the reference for the stochastic rules.

    ``g`` takes the rules' run-last layout ``(n, points, runs)`` and returns ``(1, points, runs)``.

    Example
    -------
    >>> m, v = gauss_hermite_moments(lambda X: X[0:1] ** 2, [1.0], [[2.0]], order=10)
    >>> round(m, 10), round(v, 10)                     # E[x^2] = m^2 + P, Var[x^2] = 4 m^2 P + 2 P^2
    (3.0, 16.0)
    """
    from numpy.polynomial.hermite_e import hermegauss

    m, P = np.atleast_1d(np.asarray(m, dtype=float)), np.atleast_2d(np.asarray(P, dtype=float))
    n = m.size
    nodes, w = hermegauss(order)
    w = w / w.sum()
    U = np.stack(np.meshgrid(*[nodes] * n, indexing="ij")).reshape(n, -1)
    W = np.prod(np.stack(np.meshgrid(*[w] * n, indexing="ij")).reshape(n, -1), axis=0)
    X = m[:, None] + np.linalg.cholesky(P) @ U
    G = np.asarray(g(X[:, :, None]))[0, :, 0]
    mean = float(W @ G)
    return mean, float(W @ (G - mean) ** 2)


@dataclass
class RuleErrors:
    """RMS errors (over repetitions) of a rule's ``E[g]`` and ``Var[g]`` against a reference, one per setting."""

    mean: np.ndarray
    var: np.ndarray


def rule_errors(rule, g: Callable, m, P, params, reference: tuple[float, float], n_batch: int = 1,
                seed: int = 0) -> RuleErrors:
    """Errors of a moment rule's mean and variance of scalar ``g(x)``, ``x ~ N(m, P)``.

    For each parameter value the rule runs on ``n_batch`` identical "runs" (a
    stochastic rule then gives ``n_batch`` independent estimates, drawn from
    ``default_rng(seed)``); the errors are root-mean-square over them.
    """
    m, P = np.atleast_1d(np.asarray(m, dtype=float)), np.atleast_2d(np.asarray(P, dtype=float))
    mb, Pb = np.repeat(m[:, None], n_batch, axis=1), np.repeat(P[:, :, None], n_batch, axis=2)
    err_m, err_v = [], []
    for p in np.atleast_1d(params):
        rng = np.random.default_rng(seed) if rule.stochastic else None
        mo = rule.moments(g, mb, Pb, p, rng=rng)
        err_m.append(np.sqrt(np.mean((mo.mean[0] - reference[0]) ** 2)))
        err_v.append(np.sqrt(np.mean((mo.cov[0, 0] - reference[1]) ** 2)))
    return RuleErrors(np.array(err_m), np.array(err_v))


def plot_rule_errors(n_iters, sir: RuleErrors, ut: RuleErrors, ax=None):
    """Log-log errors of the stochastic rule against iterations, the ``N^-1/2`` slope and the UT's bias."""
    from adaptfilt.style import OKABE_ITO

    fig, ax = figure_axes(ax)
    n_iters = np.asarray(n_iters, dtype=float)
    ax.loglog(n_iters, sir.mean, "o-", color=OKABE_ITO[0], label=r"SIR: RMS error of $\mathrm{E}[g]$")
    ax.loglog(n_iters, sir.var, "s-", color=OKABE_ITO[1], label=r"SIR: RMS error of $\mathrm{Var}[g]$")
    ax.loglog(n_iters, sir.mean[0] * n_iters ** -0.5, "k:", label=r"slope $-1/2$")
    ax.axhline(ut.mean[0], color=OKABE_ITO[0], ls="--", lw=1, label=r"UT ($\kappa = 1$): error of $\mathrm{E}[g]$")
    ax.axhline(ut.var[0], color=OKABE_ITO[1], ls="--", lw=1, label=r"UT ($\kappa = 1$): error of $\mathrm{Var}[g]$")
    ax.set(xlabel=r"iterations $N_\mathrm{it}$", ylabel="error vs Gauss-Hermite",
           title="Stochastic integration: error vs iterations (bearing function)")
    ax.legend(ncol=2, fontsize="small")
    return fig


_BEARING_M = (20.0, 5.0)
_BEARING_P = ((25.0, 5.0), (5.0, 16.0))


def plot_sif_draws(n_iter: int, ax=None, m=_BEARING_M, P=_BEARING_P, g: Callable = bearing, n_batch: int = 2000,
                   seed: int = 0, legend: bool = True, half_width: float = 0.025):
    """Histogram of ``n_batch`` independent stochastic-integration estimates of ``E[g(x)]``
    with ``n_iter`` iterations each, against the Gauss-Hermite value (black) and the unscented
    rule's (dashed, ``kappa = 3 - n``), on a fixed axis ``reference +- half_width``.
    The spread (its RMS error is in the title) shrinks like ``n_iter ** -0.5``; returns the figure.
    """
    from adaptfilt.rules import StochasticIntegrationRule, UnscentedRule
    from adaptfilt.style import OKABE_ITO

    if int(n_iter) < 1:
        raise ValueError(f"n_iter must be a positive integer, got {n_iter}")
    fig, ax = figure_axes(ax)
    m, P = np.asarray(m, dtype=float), np.asarray(P, dtype=float)
    ref = gauss_hermite_moments(g, m, P)[0]
    mb, Pb = np.repeat(m[:, None], n_batch, axis=1), np.repeat(P[:, :, None], n_batch, axis=2)
    est = StochasticIntegrationRule().moments(g, mb, Pb, int(n_iter), rng=np.random.default_rng(seed)).mean[0]
    ut = float(UnscentedRule().moments(g, m[:, None], P[:, :, None], 3.0 - m.size).mean[0, 0])
    half = float(half_width)  # a fixed axis: the narrowing is the lesson
    ax.hist(est, bins=np.linspace(ref - half, ref + half, 51), color=OKABE_ITO[0], alpha=0.8)
    ax.axvline(ref, color="k", lw=1.2, label="Gauss-Hermite")
    ax.axvline(ut, color=OKABE_ITO[3], ls="--", lw=1.2, label="unscented")
    ax.set(xlabel=r"estimate of $\mathrm{E}[g(x)]$", ylabel="repetitions", xlim=(ref - half, ref + half),
           title=f"$N_\\mathrm{{it}}$ = {int(n_iter)}\nRMS error {np.sqrt(np.mean((est - ref) ** 2)):.2g}")
    if legend:
        ax.legend(loc="upper right", fontsize="small")
    return fig


def show_sif_draws(n_iter: int = 8, m=_BEARING_M, P=_BEARING_P) -> None:
    """Widget callback (``ipywidgets.interact``): draw :func:`plot_sif_draws` and show it."""
    plot_sif_draws(n_iter, m=m, P=P)
    pyplot().show()


def plot_anees_k(scores: Mapping[str, Score], nx: int, median_of: Mapping[str, Score] | None = None,
                 level: float = 0.95, ax=None, title: str | None = None):
    """``ANEES_k`` of each score (log scale) with the chi2 acceptance band for ``M`` runs;
    ``median_of`` adds the median NEES of other scores (dashed) and the chi2(nx) median line."""
    from adaptfilt.style import policy_label

    fig, ax = figure_axes(ax)
    for n, s in scores.items():
        k = np.arange(1, s.anees_k.size + 1)
        ax.semilogy(k, s.anees_k, label=f"{policy_label(n)}: ANEES")
    M = next(iter(scores.values())).nees.shape[0]
    for n, s in (median_of or {}).items():
        k = np.arange(1, s.anees_k.size + 1)
        ax.semilogy(k, np.median(s.nees, axis=0), ls="--", label=f"{policy_label(n)}: median NEES")
    lo, hi = metrics.chi2_bounds(nx, M, level)
    ax.axhspan(lo, hi, color="grey", alpha=0.35, lw=0, label=f"{level:.0%} $\\chi^2$ band of ANEES, M = {M}")
    if median_of:
        ax.axhline(chi2_median(nx), color="k", ls=":", lw=1, label=rf"median of $\chi^2_{{{nx}}}$ = {chi2_median(nx):.3f}")
    ax.set(xlabel="time step $k$", ylabel=r"ANEES$_k$ / median NEES", title=title or f"consistency (ideal ANEES = {nx})")
    ax.legend(ncol=2, loc="upper center", bbox_to_anchor=(0.5, -0.2))  # below the axes: the curves fill them
    return fig


def plot_per_run_rmse(scores: Mapping[str, Score], bins=None, ax=None, title: str = ""):
    """Histograms (log x) of the per-run RMS errors, with each filter's median in the legend."""
    from adaptfilt.style import policy_label

    fig, ax = figure_axes(ax)
    bins = np.logspace(-1.5, 1.7, 50) if bins is None else bins
    for n, s in scores.items():
        ax.hist(s.run_rmse, bins=bins, histtype="step", lw=1.5, label=f"{policy_label(n)} (median {s.median_run_rmse:.2f})")
    ax.set(xscale="log", xlabel="per-run RMSE (over the run's steps)", ylabel="runs", title=title)
    # below the axes: the histograms spread over the whole log range, up to a spike at ~25
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
    return fig


def line_of_sight_errors(x: np.ndarray, mean: np.ndarray, pos: Sequence[int] = (0, 2)) -> tuple[np.ndarray, np.ndarray]:
    r"""Position errors split along and across the line of sight from the origin, ``(M, T)`` each.

    With the true position :math:`\mathbf p` and :math:`\mathbf u = \mathbf p/\|\mathbf p\|`,
    the radial (range) error is :math:`\mathbf e^T\mathbf u` and the cross-range
    error :math:`\mathbf e^T\mathbf u_\perp`, :math:`\mathbf u_\perp = [-u_2, u_1]`.
    """
    p = np.asarray(x, dtype=float)[..., list(pos)]
    e = p - np.asarray(mean, dtype=float)[..., list(pos)]
    norm = np.linalg.norm(p, axis=-1, keepdims=True)
    if (norm == 0).any():
        raise ValueError("a true position is at the origin: the line of sight is undefined there")
    u = p / norm
    return (e * u).sum(-1), e[..., 1] * u[..., 0] - e[..., 0] * u[..., 1]


def plot_line_of_sight_errors(radial: np.ndarray, cross: np.ndarray, ax=None, unit: str = "m"):
    """RMS over runs of the radial and cross-range position errors against time."""
    fig, ax = figure_axes(ax)
    k = np.arange(1, radial.shape[1] + 1)
    ax.plot(k, np.sqrt((radial ** 2).mean(0)), label="along the line of sight (range)")
    ax.plot(k, np.sqrt((cross ** 2).mean(0)), label="across the line of sight")
    ax.set(xlabel=r"time step $k$ ($\Delta t$ = 1 s)", ylabel=f"RMS position error ({unit})", ylim=(0, None),
           title="CTM, UKF: the error lies along the line of sight")
    ax.legend()
    return fig


# ============================================================ implement it yourself (chapter 2)
def _pointwise(f: Callable) -> Callable:
    """A function of one point ``(n,) -> (nf,)`` in the rules' run-last layout ``(n, S, M) -> (nf, S, M)``."""
    def g(X):
        out = np.array([[np.atleast_1d(np.asarray(f(X[:, s, r]), dtype=float)) for r in range(X.shape[2])]
                        for s in range(X.shape[1])])                                   # (S, M, nf)
        return np.moveaxis(out, -1, 0)
    return g


def _unscented_cases() -> list[tuple[str, Callable, np.ndarray, np.ndarray, float]]:
    """``(name, f, m, P, kappa)``: the settings :func:`check_unscented` tries, ``f`` a function of one point."""
    sq = lambda x: np.array([x[0] ** 2 / 20])                                        # noqa: E731
    bear_range = lambda x: np.array([np.arctan2(x[1], x[0]), np.hypot(x[0], x[1])])  # noqa: E731
    ctm_bearing = lambda x: np.array([np.arctan2(x[2], x[0])])                       # noqa: E731
    P2, P4 = np.array([[25.0, 5.0], [5.0, 16.0]]), np.diag([1000.0, 100.0, 1000.0, 100.0])
    return [("x^2/20, n = 1, kappa = 2", sq, np.array([5.0]), np.array([[4.0]]), 2.0),
            ("x^2/20, n = 1, kappa = 0.5", sq, np.array([1.0]), np.array([[12.0]]), 0.5),
            ("bearing and range, n = 2, kappa = 1", bear_range, np.array([20.0, 5.0]), P2, 1.0),
            ("bearing and range, n = 2, kappa = 10", bear_range, np.array([20.0, 5.0]), P2, 10.0),
            ("CTM bearing, n = 4, kappa = -0.5 (negative centre weight)", ctm_bearing,
             np.array([80.0, 0.0, 0.0, 20.0]), P4, -0.5)]


def _differs(mine, ref, rtol: float = 1e-8) -> bool:
    mine = np.asarray(mine, dtype=float)
    return mine.shape != ref.shape or not np.allclose(mine, ref, rtol=rtol, atol=rtol * (1 + np.abs(ref).max()))


def _call(fn, args) -> tuple[tuple | None, str | None]:
    """``fn(*args)`` as a pair of arrays, or the reason it is not one."""
    try:
        out = fn(*args)
    except Exception as e:  # the reader's code: say what went wrong instead of a traceback
        return None, f"raised {type(e).__name__}: {e}"
    if out is None:
        return None, "returned None (fill in the function and return the two arrays)"
    if not isinstance(out, (tuple, list)) or len(out) != 2:
        return None, f"returned {type(out).__name__}, not a pair of arrays"
    return out, None


def check_unscented(my_unscented: Callable) -> None:
    r"""Check a reader's unscented transform ``my_unscented(f, m, P, kappa) -> (mean, cov)``
    against the library's :class:`~adaptfilt.rules.UnscentedRule` (and, for UNGM's
    :math:`x^2/20`, against the closed form of chapter 2) on five settings, from one to four
    dimensions, with a negative centre weight among them.

    ``f`` maps one point ``(n,)`` to ``(nf,)`` values; ``mean`` is ``(nf,)`` and ``cov``
    ``(nf, nf)``. Prints ``correct`` or, for each setting, what differs.
    """
    from adaptfilt.rules import UnscentedRule

    problems = []
    for name, f, m, P, kappa in _unscented_cases():
        ref = UnscentedRule().moments(_pointwise(f), m[:, None], P[:, :, None], kappa, cross=False)
        mean, cov = ref.mean[:, 0], ref.cov[:, :, 0]
        out, why = _call(my_unscented, (f, m.copy(), P.copy(), kappa))
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        problems += _differences(name, (("the mean", np.atleast_1d(out[0]), mean),
                                        ("the covariance", np.atleast_2d(out[1]), cov)))
    if problems:
        print("not yet:\n  " + "\n  ".join(problems))
        print("hints: the points are m and m +- sqrt(n + kappa) L[:, j] with L = np.linalg.cholesky(P), the lower "
              "Cholesky factor (another square root of P, e.g. a symmetric sqrtm, gives other points, equally "
              "valid, which this check does not accept: the library's are Cholesky's); the centre "
              "weighs kappa / (n + kappa), every other point 1 / (2 (n + kappa)); the covariance sums "
              "w_i (f(X_i) - mean)(f(X_i) - mean)^T over all 2n + 1 points, the centre included")
        return
    m, P, kappa = 5.0, 4.0, 2.0                                    # the closed form of chapter 2, once more
    closed = (m ** 2 + P) / 20, (4 * m ** 2 * P + kappa * P ** 2) / 400
    mine = _call(my_unscented, (_unscented_cases()[0][1], np.array([m]), np.array([[P]]), kappa))[0]
    ok = not _differs(np.ravel(mine[0]), np.array([closed[0]])) and not _differs(np.ravel(mine[1]), np.array([closed[1]]))
    print(f"correct: your unscented transform agrees with adaptfilt's UnscentedRule in all {len(_unscented_cases())} "
          f"settings" + (" and with the closed form for x^2/20" if ok else ""))


def _differences(case: str, pairs) -> list[str]:
    """One line per ``(what, yours, the library's)`` that differs, both shown rounded."""
    return [f"{case}: {what} differs: yours {np.round(np.asarray(mine, dtype=float), 6).tolist()}, "
            f"the library's {np.round(lib, 6).tolist()}" for what, mine, lib in pairs if _differs(mine, lib)]


def _update_cases() -> list[tuple[str, object]]:
    """``(name, Update)``: updates of the library's filters (public layout, one row per case)."""
    from adaptfilt.gaf import UKF
    from adaptfilt.models import coordinated_turn, linear_gaussian, ungm as ungm_model

    ungm = UKF(ungm_model())
    ungm_u = ungm.update(np.array([[5.0], [-3.0], [0.5]]), np.array([[[4.0]], [[12.0]], [[1.0]]]),
                         np.array([[1.6], [0.2], [0.05]]), t=1)
    ctm = coordinated_turn()
    x_pred = np.array([[80.0, 0.0, 0.0, 20.0], [60.0, -5.0, 40.0, 15.0]])
    ctm_u = UKF(ctm).update(x_pred, np.repeat(ctm.P0[None], 2, axis=0), np.array([[0.3], [0.5]]), t=0)
    lin = linear_gaussian(F=np.eye(3), H=[[1.0, 0.0, 0.0], [0.5, 1.0, 0.2]], Q=np.eye(3),
                                    R=[[0.5, 0.1], [0.1, 0.3]], m0=np.zeros(3), P0=np.eye(3))
    A = np.array([[2.0, 0.3, 0.1], [0.3, 1.0, -0.2], [0.1, -0.2, 3.0]])
    lin_u = UKF(lin).update(np.array([[1.0, -2.0, 0.5]]), A[None], np.array([[1.5, -1.0]]), t=0)
    return [("UNGM, UKF, n_x = 1", ungm_u), ("CTM, UKF, n_x = 4, one bearing", ctm_u),
            ("linear model, n_x = 3, two measurements", lin_u)]


def check_update(my_update: Callable) -> None:
    r"""Check a reader's Gaussian-assumed update
    ``my_update(x_pred, P_pred, z, z_pred, Pzz, Pxz) -> (x_filt, P_filt)`` (one run: ``(n_x,)``,
    ``(n_x, n_x)``, ``(n_z,)``, ``(n_z,)``, ``(n_z, n_z)``, ``(n_x, n_z)``) against the updates of
    ``adaptfilt.gaf`` (:meth:`~adaptfilt.gaf.GaussianAssumedFilter.update`: UNGM's and the CTM's UKF
    and a linear model with two measurements). Prints ``correct`` or what differs.
    """
    problems, n = [], 0
    for name, u in _update_cases():
        for r in range(u.x_pred.shape[0]):
            n += 1
            args = tuple(a[r].copy() for a in (u.x_pred, u.P_pred, u.innovation + u.z_pred, u.z_pred, u.Pzz, u.Pxz))
            out, why = _call(my_update, args)
            if why:
                problems.append(f"{name} (case {r}): your function {why}")
                continue
            problems += _differences(f"{name} (case {r})", (("x_filt", out[0], u.x_filt[r]), ("P_filt", out[1], u.P_filt[r])))
    if problems:
        print("not yet:\n  " + "\n  ".join(problems))
        print("hints: the gain K = Pxz Pzz^-1 has shape (n_x, n_z) (a matrix inverse, not a division, when n_z > 1); "
              "the mean moves by K times the innovation z - z_pred; the covariance loses K Pzz K^T")
        return
    print(f"correct: your update agrees with adaptfilt's (gaf.GaussianAssumedFilter.update) in all {n} cases")
