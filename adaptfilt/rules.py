r"""Moment rules: E[g(x)], Cov[g(x)] and Cov[x, g(x)] for x ~ N(m, P).

A Gaussian-assumed filter (Algorithm 1 of the paper) is one recursion plus a
moment rule; this module holds the rules. All rules here are *fully symmetric
axis rules*: with ``P = L L^T`` they evaluate ``g`` at the centre ``m`` and at
``2n`` points ``m +- s L u_j`` that all carry the same weight ``w``; the centre
carries ``1 - 2 n w``.

Deviations are taken about the centre value ``g0 = g(m)`` (through the model's
``residual``, which wraps angles), so the centre contributes nothing to

.. math::

    \bar D = \sum_i w_i D_i,\quad
    \mathrm{Cov}[g] = \sum_i w_i D_i D_i^T - \bar D \bar D^T,\quad
    \mathrm{Cov}[x, g] = \sum_i w_i (X_i - m) D_i^T,

with ``D_i = residual(g(X_i), g0)`` and ``E[g] = g0 + \bar D``. The two
covariance forms are algebraically equal to the textbook
``sum_i w_i (g_i - E[g])(.)^T`` because the weights sum to one; the centred form
is what makes a bearing's predicted mean a circular mean about ``g0`` and keeps
round-off small. For linear ``g`` every rule here is exact, whatever its
parameter: all filters then agree with the Kalman filter.

Rules
-----
* :class:`UnscentedRule` (Julier's sigma points, parameter ``kappa``):
  ``s = sqrt(n + kappa)``, ``u_j = e_j``, ``w = 1 / (2 (n + kappa))``; the
  centre weight ``kappa / (n + kappa)`` is negative for ``kappa < 0``.
* :class:`CubatureRule`: the unscented rule at ``kappa = 0``.
* :class:`StochasticIntegrationRule` (parameter ``n_iter``): Genz-Monahan's
  stochastic spherical-radial rule of degree 3 as used by Dunik, Straka and
  Simandl's SIF, averaged over ``n_iter`` independent draws.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from adaptfilt.linalg import chol, mm, sym

__all__ = ["Moments", "MomentRule", "UnscentedRule", "CubatureRule", "StochasticIntegrationRule"]

#: ``g`` maps points ``(n, S, M)`` to values ``(ng, S, M)`` (run axis last).
BatchFn = Callable[[np.ndarray], np.ndarray]
Residual = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class Moments:
    """Moments of ``g(x)``, run axis last: ``mean (ng, M)``, ``cov (ng, ng, M)``, ``cross (n, ng, M)``."""

    mean: np.ndarray
    cov: np.ndarray
    cross: np.ndarray | None


@dataclass
class _PointSet:
    scale: np.ndarray | float  # s, scalar or (M,)
    rotation: np.ndarray | None  # u_j as columns, (n, n, M); None = identity
    weight: np.ndarray | float  # w of each axis point, scalar or (M,)
    mask: np.ndarray | None  # (M,) runs that use this set; None = all


class MomentRule(ABC):
    """A rule for the Gaussian moments of a function, with one scalar parameter.

    Subclasses say how their axis point sets are drawn (:meth:`_point_sets`);
    the moment arithmetic is shared. ``param`` may be a scalar or one value per
    run ``(M,)``.
    """

    #: name of the parameter, as in the paper ("kappa", "n_iter")
    param_name: str = "param"
    #: whether the rule draws random numbers (then ``moments`` needs ``rng``)
    stochastic: bool = False

    @abstractmethod
    def default_param(self, n: int) -> float:
        """The parameter a practitioner would use for state dimension ``n``."""

    @abstractmethod
    def check_param(self, param, n: int) -> np.ndarray:
        """Validated parameter as an array (scalar or ``(M,)``); ValueError if invalid."""

    @abstractmethod
    def _point_sets(self, n: int, M: int, param: np.ndarray, rng: np.random.Generator | None) -> Iterator[_PointSet]:
        ...

    def n_points(self, n: int, param) -> np.ndarray:
        """Number of function evaluations the rule spends (centre included)."""
        return 1 + 2 * n * np.ones_like(np.asarray(param, dtype=float))

    def moments(
        self,
        g: BatchFn,
        m: np.ndarray,
        P: np.ndarray,
        param,
        residual: Residual | None = None,
        rng: np.random.Generator | None = None,
        L: np.ndarray | None = None,
        cross: bool = True,
    ) -> Moments:
        """Moments of ``g(x)`` for ``x ~ N(m, P)``, ``m (n, M)``, ``P (n, n, M)``.

        ``L`` may pass a Cholesky factor of ``P`` that the caller already has.
        Raises :class:`~adaptfilt.linalg.NotPositiveDefinite` when ``P`` is not
        positive definite.
        """
        n, M = m.shape
        param = self.check_param(param, n)
        if L is None:
            L = chol(sym(P), "P")
        g0 = g(m[:, None, :])[:, 0, :]
        ED = np.zeros_like(g0)
        EDD = np.zeros((g0.shape[0], g0.shape[0], M))
        EXD = np.zeros((n, g0.shape[0], M)) if cross else None
        count = 0.0
        for ps in self._point_sets(n, M, param, rng):
            A = L if ps.rotation is None else mm(L, ps.rotation)
            A = A * ps.scale
            dX = np.concatenate([A, -A], axis=1)  # (n, 2n, M)
            G = g(m[:, None, :] + dX)
            D = G - g0[:, None, :] if residual is None else residual(G, g0[:, None, :])
            # A model function returns (..., ng) with ng fastest; moved to run-last
            # its runs are strided, which makes the einsums below ~6x slower for
            # ng > 1. One contiguous copy (a no-op when ng = 1) pays for itself.
            D = np.ascontiguousarray(D)
            w = ps.weight if ps.mask is None else ps.weight * ps.mask
            wD = D * w
            ED += wD.sum(axis=1)
            EDD += np.einsum("isM,jsM->ijM", wD, D)
            if cross:
                EXD += np.einsum("isM,jsM->ijM", dX, wD)
            count = count + (1.0 if ps.mask is None else ps.mask)
        ED /= count
        EDD /= count
        cov = EDD - ED[:, None, :] * ED[None, :, :]
        if cross:
            EXD /= count
        return Moments(mean=g0 + ED, cov=sym(cov), cross=EXD)


class UnscentedRule(MomentRule):
    r"""Julier's unscented transform with scaling parameter ``kappa``.

    Sigma points ``m``, ``m +- sqrt(n + kappa) L e_j`` (``P = L L^T``) with
    weights ``W_0 = kappa / (n + kappa)``, ``W_j = 1 / (2 (n + kappa))``;
    the same weights for mean and covariance (no alpha/beta scaling).
    Requires ``n + kappa > 0``. Exact for polynomials of degree 3; the fourth
    moment of a scalar Gaussian is matched only at ``n + kappa = 3``, which is
    why ``kappa`` changes ``Pzz`` of UNGM's quadratic measurement.

    Example
    -------
    >>> import numpy as np
    >>> from adaptfilt.rules import UnscentedRule
    >>> m, P = np.zeros((1, 1)), np.ones((1, 1, 1))
    >>> mo = UnscentedRule().moments(lambda X: X**2, m, P, param=2.0)
    >>> float(mo.mean[0, 0]), float(mo.cov[0, 0, 0])  # E[x^2] = 1, Var[x^2] = 2
    (1.0, 2.0)
    """

    param_name = "kappa"

    def __init__(self, default_kappa: float | None = None):
        self._default = default_kappa

    def default_param(self, n: int) -> float:
        return float(max(0, 3 - n)) if self._default is None else float(self._default)

    def check_param(self, param, n: int) -> np.ndarray:
        kappa = np.asarray(param, dtype=float)
        if not np.isfinite(kappa).all():
            raise ValueError(f"kappa must be finite, got {param!r}")
        if (n + kappa <= 0).any():
            bad = np.unique(kappa[n + kappa <= 0]) if kappa.ndim else kappa
            raise ValueError(f"kappa must satisfy n + kappa > 0 (n = {n}); got kappa = {bad}")
        return kappa

    def _point_sets(self, n, M, kappa, rng):
        c = n + kappa
        yield _PointSet(scale=np.sqrt(c), rotation=None, weight=0.5 / c, mask=None)


class CubatureRule(UnscentedRule):
    """The third-degree spherical-radial cubature rule: the unscented rule at ``kappa = 0``."""

    def __init__(self):
        super().__init__(default_kappa=0.0)


def haar_rotations(n: int, M: int, rng: np.random.Generator) -> np.ndarray:
    """``M`` independent Haar-distributed orthogonal ``n x n`` matrices, ``(n, n, M)``.

    Gram-Schmidt on i.i.d. Gaussian columns, i.e. the Q of a QR factorisation
    with positive diagonal R, which is Haar distributed; vectorised over runs.
    """
    G = rng.standard_normal((n, n, M))
    Q = np.empty_like(G)
    for j in range(n):
        v = G[:, j]
        for k in range(j):  # modified Gram-Schmidt
            v = v - (Q[:, k] * v).sum(axis=0) * Q[:, k]
        Q[:, j] = v / np.sqrt((v * v).sum(axis=0))
    return Q


class StochasticIntegrationRule(MomentRule):
    r"""Stochastic integration rule of degree 3 (Genz & Monahan), as in the SIF.

    One draw uses a radius ``rho ~ sqrt(chi2(n + 2))`` and a Haar-random
    rotation ``Q``: points ``m``, ``m +- rho L Q e_j`` with weights
    ``1 - n / rho^2`` (centre) and ``1 / (2 rho^2)``. The estimate is unbiased
    for any integrand and exact for polynomials of degree 3; ``n_iter``
    independent draws are averaged (the running average of Dunik, Straka and
    Simandl's SIF with a fixed iteration count), so its error shrinks like
    ``1 / sqrt(n_iter)``.

    Variant: the *axes* points (``2n + 1`` per draw) rather than the simplex
    (``n + 2``): fully symmetric, so odd moments vanish exactly, linear
    functions are integrated exactly in every single draw (the SIF equals the
    Kalman filter on linear models for any ``n_iter``), and the rule shares
    its arithmetic with the unscented rule. The centre weight ``1 - n/rho^2``
    is negative with probability ``P(chi2(n+2) < n)`` (0.32 for ``n = 4``).

    Per-run ``n_iter`` draws ``max(n_iter)`` sets; a run averages its first
    ``n_iter`` of them. Draw ``i`` consumes the same random numbers whatever
    the iteration counts, so policies that differ in ``n_iter`` see common
    random numbers.
    """

    param_name = "n_iter"
    stochastic = True

    def __init__(self, default_n_iter: int = 10):
        self._default = int(default_n_iter)

    def default_param(self, n: int) -> float:
        return float(self._default)

    def check_param(self, param, n: int) -> np.ndarray:
        it = np.asarray(param, dtype=float)
        if not np.isfinite(it).all() or (it < 1).any() or (it != np.round(it)).any():
            raise ValueError(f"n_iter must be a positive integer (or one per run), got {param!r}")
        return it

    def n_points(self, n: int, param) -> np.ndarray:
        return 1 + 2 * n * np.asarray(param, dtype=float)

    def _point_sets(self, n, M, n_iter, rng):
        if rng is None:
            raise ValueError("the stochastic integration rule needs a numpy Generator (rng)")
        per_run = n_iter.ndim > 0
        for i in range(int(n_iter.max())):
            Q = haar_rotations(n, M, rng)
            rho2 = rng.chisquare(n + 2, size=M)
            mask = (n_iter > i).astype(float) if per_run else None
            yield _PointSet(scale=np.sqrt(rho2), rotation=Q, weight=0.5 / rho2, mask=mask)
