r"""Performance metrics of Section VI-E, with their uncertainty.

* ``RMSE_k = sqrt( (1/M) sum_l  e_l^T e_l )``, ``e_l = x_k(l) - x_{k|k}(l)``
* ``ANEES_k = (1/M) sum_l e_l^T P_{k|k}(l)^{-1} e_l`` (ideal value ``nx``; the
  paper's definition, not divided by ``nx``)
* ``NIS_k`` per run, ideal mean ``nz``.

Time averages, standard errors, bootstrap confidence intervals (resampling
Monte-Carlo runs, paired across filters when given the same resamples) and
chi-square acceptance bounds for an average of NEES/NIS values.
"""
from __future__ import annotations

from typing import Literal

import numpy as np

from adaptfilt.linalg import NotPositiveDefinite, chol, solve_spd

__all__ = [
    "errors", "squared_error", "rmse", "nees", "anees", "time_average", "rmse_time_average",
    "bootstrap_counts", "resampled_sums", "bootstrap_rmse", "bootstrap_mean", "percentile_ci", "mean_ci", "chi2_bounds",
    "rate_ci", "DIVERGED_NEES", "divergent", "divergence_step",
]

#: The one definition of a diverged run used everywhere in adaptfilt (evaluation, experiments,
#: course): its time-averaged NEES exceeds ``DIVERGED_NEES * nx`` (or its estimate is not finite).
#: A consistent filter has a time-averaged NEES near ``nx``; 10^4 times that is an error of 100
#: standard deviations on average, a filter that has lost the state, not a merely overconfident one.
DIVERGED_NEES = 1e4


def _check(x: np.ndarray, mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x, mean = np.asarray(x, dtype=float), np.asarray(mean, dtype=float)
    if x.shape != mean.shape:
        raise ValueError(f"true states {x.shape} and estimates {mean.shape} must have the same shape (M, T, nx)")
    return x, mean


def errors(x: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Estimate errors ``x - mean``, ``(M, T, nx)``."""
    x, mean = _check(x, mean)
    return x - mean


def squared_error(x: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """``e^T e`` per run and step, ``(M, T)``."""
    e = errors(x, mean)
    return (e * e).sum(axis=-1)


def rmse(x: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """``RMSE_k`` over runs, ``(T,)``."""
    return np.sqrt(squared_error(x, mean).mean(axis=0))


def _where(flat: int, shape: tuple[int, ...]) -> str:
    """``run r, step k`` of a flat index over the ``(M, T)`` leading axes."""
    idx = np.unravel_index(int(flat), shape)
    if len(shape) == 2:
        return f"run {idx[0]}, step {idx[1]}"
    return "index " + str(tuple(int(i) for i in idx))


def _indefinite_error(bad: np.ndarray, shape: tuple[int, ...], cov: np.ndarray,
                      singular: bool = False) -> ValueError:
    """ValueError naming the first (run, step) of ``bad`` (flat indices over
    ``shape``) whose covariance in ``cov (*shape, nx, nx)`` has no NEES."""
    first = int(bad[0])
    P = cov[np.unravel_index(first, shape)]
    why = "is not finite" if not np.isfinite(P).all() else "is singular" if singular else "is not positive definite"
    n = int(bad.size) - 1
    more = f" (and {n} more (run, step) pair{'s' if n > 1 else ''})" if n else ""
    hint = "on_indefinite='nan' gives NaN there" if singular else "pass on_indefinite='nan' or 'solve' to accept such covariances"
    return ValueError(f"covariance P {why} at {_where(first, shape)}{more}: the NEES e^T P^-1 e is undefined there; {hint}")


def nees(x: np.ndarray, mean: np.ndarray, cov: np.ndarray,
         on_indefinite: Literal["raise", "nan", "solve", "inf"] = "raise") -> np.ndarray:
    r"""Normalised estimation error squared per run and step, ``(M, T)``.

    ``NEES_k(l) = e^T P^{-1} e`` with ``e = x_k(l) - x_{k|k}(l)`` and
    ``P = P_{k|k}(l)``, through the run-last batched Cholesky ``P = L L^T`` of
    :mod:`adaptfilt.linalg` (``NEES = ||L^{-1} e||^2``), which also names the
    (run, step) pairs whose ``P`` has no Cholesky factor.

    Parameters
    ----------
    x, mean : (M, T, nx)
        True states and estimates.
    cov : (M, T, nx, nx)
        Estimate covariances ``P_{k|k}``.
    on_indefinite : "raise", "nan" or "solve"
        What to do where ``P`` is not positive definite (or not finite), where
        the NEES is undefined:

        * ``"raise"`` (default): ``ValueError`` naming the first such (run, step);
        * ``"nan"``: NaN there (an explicit opt-in; average with ``np.nanmean``);
        * ``"solve"``: ``e^T P^{-1} e`` of the indefinite matrix itself through a
          plain solve (it may be negative; a singular ``P`` is still an error);
        * ``"inf"``: infinity there: a particle cloud whose weight sits on one point
          claims certainty (:mod:`adaptfilt.particles`), and the run counts as diverged
          (:func:`divergent`).

        The filters return positive definite ``P_{k|k}`` (with
        ``on_indefinite="clip"`` they repair it before returning it), so
        :func:`adaptfilt.evaluation.evaluate` keeps the default ``"raise"``: an
        indefinite covariance reaching the metrics would be a bug.

    Example
    -------
    >>> import numpy as np
    >>> from adaptfilt import metrics
    >>> e = np.array([[[1.0, 2.0]]])                 # M = 1 run, T = 1 step, nx = 2
    >>> float(metrics.nees(e, np.zeros_like(e), np.diag([1.0, 4.0])[None, None])[0, 0])
    2.0
    >>> metrics.nees(e, np.zeros_like(e), -np.eye(2)[None, None])
    Traceback (most recent call last):
    ...
    ValueError: covariance P is not positive definite at run 0, step 0: ...
    """
    if on_indefinite not in ("raise", "nan", "solve", "inf"):
        raise ValueError(f"on_indefinite must be 'raise', 'nan', 'solve' or 'inf', got {on_indefinite!r}")
    e = errors(x, mean)
    cov = np.asarray(cov, dtype=float)
    if cov.shape != e.shape + e.shape[-1:]:
        raise ValueError(f"covariances must have shape {e.shape + e.shape[-1:]}, got {cov.shape}")
    lead, nx = e.shape[:-1], e.shape[-1]
    if nx == 1:
        P = cov[..., 0, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            out = e[..., 0] ** 2 / P
        if on_indefinite == "solve":
            bad = np.flatnonzero(P == 0.0)
            if bad.size:
                raise _indefinite_error(bad, lead, cov, singular=True)
            return out
        bad = np.flatnonzero(~(P > 0.0) | ~np.isfinite(P))
        if bad.size:
            if on_indefinite == "raise":
                raise _indefinite_error(bad, lead, cov)
            out.reshape(-1)[bad] = np.inf if on_indefinite == "inf" else np.nan
        return out
    er = e.reshape(-1, nx).T  # (nx, N) run-last
    flat_cov = cov.reshape(-1, nx, nx)  # one copy when cov is a transposed view (FilterRun.cov)
    P = np.moveaxis(flat_cov, 0, -1)  # (nx, nx, N)
    bad = np.empty(0, dtype=np.int64)
    try:
        L = chol(P)
    except NotPositiveDefinite as ex:
        bad = ex.runs
        if on_indefinite == "raise":
            raise _indefinite_error(bad, lead, cov) from None
        P = P.copy()
        while True:  # chol names the members that fail at its first failing column: repeat until none is left
            P[:, :, bad] = np.eye(nx)[:, :, None]
            try:
                L = chol(P)
                break
            except NotPositiveDefinite as again:
                bad = np.union1d(bad, again.runs)
    out = (er * solve_spd(L, er[:, None, :])[:, 0, :]).sum(axis=0)
    if bad.size:
        if on_indefinite in ("nan", "inf"):
            out[bad] = np.nan if on_indefinite == "nan" else np.inf
        else:
            eb, Pb = er[:, bad].T, flat_cov[bad]
            try:
                out[bad] = (eb * np.linalg.solve(Pb, eb[..., None])[..., 0]).sum(-1)
            except np.linalg.LinAlgError:  # a singular member: name the first
                singular = [i for i, Pi in zip(bad, Pb) if np.isfinite(Pi).all() and np.linalg.matrix_rank(Pi) < nx]
                raise _indefinite_error(np.asarray(singular or bad), lead, cov, singular=True) from None
    return out.reshape(lead)


def anees(x: np.ndarray, mean: np.ndarray, cov: np.ndarray,
          on_indefinite: Literal["raise", "nan", "solve"] = "raise") -> np.ndarray:
    """``ANEES_k``: NEES averaged over runs, ``(T,)``; ideal value ``nx``.

    ``on_indefinite`` as in :func:`nees` (with ``"nan"`` a step with an
    indefinite covariance averages to NaN: average with ``np.nanmean`` yourself).
    """
    return nees(x, mean, cov, on_indefinite=on_indefinite).mean(axis=0)


def divergent(nees_runs: np.ndarray, nx: int, mean: np.ndarray | None = None) -> np.ndarray:
    r"""Which runs diverged: ``(M,)`` bool from the per-step NEES ``(M, T)``.

    .. math:: \text{divergent}_i \iff \tfrac1T \sum_k \text{NEES}_{i,k} > 10^4 n_x
              \ \text{(or not finite)}

    ``mean`` (``(M, T, nx)``, optional) also marks runs whose estimate is not finite.

    >>> divergent(np.array([[1.0, 3.0], [1.0, 3e5]]), nx=2).tolist()
    [False, True]
    """
    nees_runs = np.asarray(nees_runs, dtype=float)
    if nees_runs.ndim != 2:
        raise ValueError(f"nees_runs must be (M, T), got shape {nees_runs.shape}")
    bad = ~(nees_runs.mean(axis=1) <= DIVERGED_NEES * nx)  # NaN counts as diverged
    if mean is not None:
        bad |= ~np.isfinite(np.asarray(mean)).reshape(len(bad), -1).all(axis=1)
    return bad


def divergence_step(nees_runs: np.ndarray, nx: int) -> np.ndarray:
    r"""When each run diverged: the first step ``k`` at which its running time average
    :math:`\tfrac1{k+1}\sum_{l\le k}\text{NEES}_l` exceeds ``DIVERGED_NEES * nx``, or -1.

    The same threshold as :func:`divergent`, applied to the average so far, so that a run with a
    step is exactly a run that crossed the line once; for a run that ends divergent it is the
    step from which the time average over the steps so far already says so.

    >>> divergence_step(np.array([[1.0, 1.0, 9e4, 1.0], [1.0, 1.0, 1.0, 1.0]]), nx=2).tolist()
    [2, -1]
    """
    nees_runs = np.asarray(nees_runs, dtype=float)
    if nees_runs.ndim != 2:
        raise ValueError(f"nees_runs must be (M, T), got shape {nees_runs.shape}")
    running = np.cumsum(np.where(np.isfinite(nees_runs), nees_runs, np.inf), axis=1) / np.arange(1, nees_runs.shape[1] + 1)
    bad = ~(running <= DIVERGED_NEES * nx)
    return np.where(bad.any(axis=1), bad.argmax(axis=1), -1)


def time_average(series: np.ndarray, start: int = 0) -> float:
    """Average over time steps ``start..T-1`` of a ``(T,)`` series."""
    return float(np.mean(np.asarray(series)[start:]))


def rmse_time_average(se: np.ndarray) -> float:
    """Time-averaged RMSE from squared errors ``(M, T)``: ``mean_k sqrt(mean_l se)``."""
    return float(np.sqrt(se.mean(axis=0)).mean())


def bootstrap_counts(n_runs: int, n_boot: int = 1000, rng: np.random.Generator | int | None = 0) -> np.ndarray:
    """Multinomial resampling counts ``(n_boot, n_runs)``: resample ``b`` takes
    run ``l`` ``counts[b, l]`` times. Reuse the same counts for several filters
    to get *paired* bootstrap differences."""
    rng = np.random.default_rng(rng)
    return rng.multinomial(n_runs, np.full(n_runs, 1.0 / n_runs), size=n_boot).astype(float)


def resampled_sums(counts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``counts @ values``: per resample, the sum of the runs' values (``values (M,)`` or ``(M, T)``), each
    run as often as the resample draws it. A run whose value is not finite (a diverged filter's infinite
    error) makes the sums of the resamples that draw it infinite (NaN for NaN, or for +inf and -inf
    together) and leaves the others alone: in the plain product a count of 0 times ``inf`` would be NaN.
    With finite values it is the plain product, bit for bit.

    >>> counts = np.array([[2.0, 0.0], [1.0, 1.0]])
    >>> resampled_sums(counts, np.array([1.0, np.inf])).tolist()
    [2.0, inf]
    """
    finite = np.isfinite(values)
    if finite.all():
        return counts @ values
    out = counts @ np.where(finite, values, 0.0)
    for bad, fill in ((np.isposinf(values), np.inf), (np.isneginf(values), -np.inf), (np.isnan(values), np.nan)):
        if bad.any():
            out = np.where(counts @ bad.astype(float) > 0, out + fill, out)
    return out


def bootstrap_rmse(se: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Bootstrap replicates ``(n_boot,)`` of the time-averaged RMSE from squared errors ``se (M, T)``
    (a resample that draws a run with an infinite error has an infinite RMSE: :func:`resampled_sums`)."""
    M = se.shape[0]
    return np.sqrt(resampled_sums(counts, se) / M).mean(axis=1)


def bootstrap_mean(per_run: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Bootstrap replicates ``(n_boot,)`` of the mean over runs of ``per_run (M,)``
    (e.g. a time-averaged NEES per run: the time-averaged ANEES is its mean; non-finite values:
    :func:`resampled_sums`)."""
    return resampled_sums(counts, per_run) / per_run.shape[0]


def percentile_ci(replicates: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    r"""Percentile interval of bootstrap replicates: the ``(1 - level) / 2`` and ``(1 + level) / 2``
    quantiles (``np.quantile``, linear interpolation between order statistics).

    A diverged run makes replicates infinite, and the interval says so: an end that falls on or next to an
    infinite replicate is that infinity (``np.quantile`` would give NaN between two infinite or between an
    infinite and a finite neighbour). A replicate that is undefined (NaN: the difference of two infinite
    replicates, both sides diverged) may be anything, so it counts as :math:`-\infty` for the lower end and
    :math:`+\infty` for the upper: it can only widen the interval. The ends are never NaN.

    >>> percentile_ci(np.array([1.0, 2.0, 3.0, np.inf, np.inf, np.inf]))
    (1.125, inf)
    >>> percentile_ci(np.array([1.0, 2.0, np.nan]))
    (-inf, inf)
    """
    a = (1.0 - level) / 2.0
    x = np.asarray(replicates, dtype=float).ravel()
    if np.isfinite(x).all():
        lo, hi = np.quantile(x, [a, 1.0 - a])
        return float(lo), float(hi)
    undefined = np.isnan(x)
    return (_quantile_with_infinities(np.where(undefined, -np.inf, x), a, lower=True),
            _quantile_with_infinities(np.where(undefined, np.inf, x), 1.0 - a, lower=False))


def _quantile_with_infinities(x: np.ndarray, q: float, lower: bool) -> float:
    """``np.quantile(x, q)`` for ``x`` with infinite (never NaN) values: between an infinite order statistic
    and its neighbour the quantile is the infinity (between -inf and +inf: the one that widens the interval,
    -inf for a lower end); exactly on an order statistic, that statistic."""
    with np.errstate(invalid="ignore"):
        v = float(np.quantile(x, q))
    if not np.isnan(v):
        return v
    below, above = float(np.quantile(x, q, method="lower")), float(np.quantile(x, q, method="higher"))
    h = (x.size - 1) * q
    if below == above or h == np.floor(h):
        return below
    if below == -np.inf and above == np.inf:
        return -np.inf if lower else np.inf
    return below if below == -np.inf else above


def mean_ci(values: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """Mean, and its normal-approximation confidence interval from the standard error."""
    v = np.asarray(values, dtype=float).ravel()
    m = float(v.mean())
    se = float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan")
    from scipy import stats  # on first use: scipy.stats is most of the import time of the library

    zq = stats.norm.ppf(0.5 + level / 2.0)
    return m, m - zq * se, m + zq * se


def chi2_bounds(dof: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Acceptance interval for the average of ``n`` independent chi2(``dof``)
    values (NEES with ``dof = nx``, NIS with ``dof = nz``): a consistent filter's
    average falls inside with probability ``level``."""
    a = (1.0 - level) / 2.0
    from scipy import stats

    lo, hi = stats.chi2.ppf([a, 1.0 - a], dof * n) / n
    return float(lo), float(hi)


def rate_ci(k: int, n: int, level: float = 0.95) -> tuple[float, float, float]:
    """A rate ``k / n`` (e.g. divergent runs) and its exact (Clopper-Pearson) interval ``(rate, lo, hi)``.

    Zero events in ``n`` runs is not a rate of zero: the interval's upper end is about
    ``3.7 / n`` at 95 % (``3 / n``, the rule of three, one-sided).

    >>> rate, lo, hi = rate_ci(0, 10_000)
    >>> rate, lo, round(hi, 6)
    (0.0, 0.0, 0.000369)
    """
    from scipy.stats import binomtest

    k, n = int(k), int(n)
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n and n >= 1, got k = {k}, n = {n}")
    ci = binomtest(k, n).proportion_ci(confidence_level=level, method="exact")
    return k / n, float(ci.low), float(ci.high)
