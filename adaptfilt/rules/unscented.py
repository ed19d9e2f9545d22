r"""The deterministic moment rules: :class:`UnscentedRule` (Julier's sigma points, parameter ``kappa``,
with the modified form for ``kappa < 0``) and :class:`CubatureRule` (the unscented rule at ``kappa = 0``).
"""
from __future__ import annotations

import math
from typing import Literal

import numpy as np

from adaptfilt.rules.base import MomentRule, _PointSet

__all__ = ["UnscentedRule", "CubatureRule"]


class UnscentedRule(MomentRule):
    r"""Julier's unscented transform with scaling parameter ``kappa``.

    Sigma points ``m``, ``m +- sqrt(n + kappa) L e_j`` (``P = L L^T``) with
    weights ``W_0 = kappa / (n + kappa)``, ``W_j = 1 / (2 (n + kappa))``;
    the same weights for mean and covariance (no alpha/beta scaling).
    Requires ``n + kappa > 0``. Exact for polynomials of degree 3; the fourth
    moment of a scalar Gaussian is matched only at ``n + kappa = 3``, which is
    why ``kappa`` changes ``Pzz`` of UNGM's quadratic measurement.

    Negative ``kappa`` and the modified form
    ----------------------------------------
    With ``W_0 < 0`` the standard covariance
    ``sum_i W_i (Y_i - y)(Y_i - y)^T`` (``y`` the weighted mean) can be
    indefinite. Julier and Uhlmann's *modified form* takes the covariance
    about the transformed centre point ``Y_0 = g(m)`` instead:

    .. math::

        P_{yy}^{\rm mod} = \sum_{i} W_i (Y_i - Y_0)(Y_i - Y_0)^T
        = P_{yy} + (y - Y_0)(y - Y_0)^T .

    Here deviations are already taken about ``Y_0`` (``D_i = Y_i - Y_0``,
    ``D_0 = 0``), so the modified form is ``sum_{i>0} W_i D_i D_i^T``: it only
    drops the ``- ED ED^T`` term. Every remaining weight is positive, so it
    is positive semidefinite for any ``kappa > -n`` (and the filter's
    ``P_pred``, ``Pzz`` and ``P_filt`` stay positive definite). The mean and
    the cross-covariance are unchanged (``sum_i W_i (X_i - m) = 0``). It
    over-states the covariance by the squared bias ``(y - Y_0)(y - Y_0)^T``,
    a fourth-order term, and leaves the mean and ``Pxz`` exact to the same
    orders as the standard form.

    Parameters
    ----------
    default_kappa : float, optional
        ``None``: ``max(0, 3 - n)``.
    form : "standard", "modified" or "auto"
        ``"standard"`` (default): the covariance about the mean, as always.
        ``"modified"``: about ``Y_0`` for every ``kappa``.
        ``"auto"``: the modified form only where ``W_0 < 0`` (``kappa < 0``,
        per run for per-run ``kappa``), the standard one elsewhere, so
        ``kappa >= 0`` results are bit-for-bit those of ``"standard"``.

    Example
    -------
    >>> import numpy as np
    >>> from adaptfilt.rules import UnscentedRule
    >>> m, P = np.zeros((1, 1)), np.ones((1, 1, 1))
    >>> mo = UnscentedRule().moments(lambda X: X**2, m, P, param=2.0)
    >>> round(float(mo.mean[0, 0]), 12), round(float(mo.cov[0, 0, 0]), 12)  # E[x^2] = 1, Var[x^2] = 2
    (1.0, 2.0)
    >>> mo = UnscentedRule(form="auto").moments(lambda X: X**2, m, P, param=-0.5)
    >>> round(float(mo.cov[0, 0, 0]), 12)  # (1 + kappa) P^2 = 0.5 >= 0; the standard form gives kappa P^2 = -0.5
    0.5
    """

    param_name = "kappa"
    FORMS = ("standard", "modified", "auto")

    def __init__(self, default_kappa: float | None = None, form: Literal["standard", "modified", "auto"] = "standard"):
        if form not in self.FORMS:
            raise ValueError(f"form must be one of {self.FORMS}, got {form!r}")
        self._default = default_kappa
        self.form = form

    @property
    def _scalar_kernel(self) -> bool:  # one point set; the compiled kernels take the standard covariance
        return self.form == "standard"

    def default_param(self, n: int) -> float:
        return float(max(0, 3 - n)) if self._default is None else float(self._default)

    def check_param(self, param, n: int) -> np.ndarray:
        kappa = np.asarray(param, dtype=float)
        if kappa.ndim == 0 and math.isfinite(kappa) and n + float(kappa) > 0:  # one value: no array checks
            return kappa
        if not np.isfinite(kappa).all():
            raise ValueError(f"kappa must be finite, got {param!r}")
        if (n + kappa <= 0).any():
            bad = np.unique(kappa[n + kappa <= 0]) if kappa.ndim else kappa
            raise ValueError(f"kappa must satisfy n + kappa > 0 (n = {n}); got kappa = {bad}")
        return kappa

    def _point_sets(self, n, M, kappa, rng):
        # one kappa in Python floats (the same IEEE operations, without 0-d array overhead)
        c = n + (float(kappa) if kappa.ndim == 0 else kappa)
        yield _PointSet(scale=math.sqrt(c) if kappa.ndim == 0 else np.sqrt(c), rotation=None, weight=0.5 / c)

    def _cov_from_sums(self, EDD, ED, kappa):
        if self.form == "standard":
            return super()._cov_from_sums(EDD, ED, kappa)
        if self.form == "modified":
            return EDD.copy()
        keep = (kappa >= 0).astype(float)  # auto: drop the -ED ED^T term where W_0 < 0
        return EDD - keep * (ED[:, None, :] * ED[None, :, :])


class CubatureRule(UnscentedRule):
    """The third-degree spherical-radial cubature rule: the unscented rule at ``kappa = 0``."""

    def __init__(self):
        super().__init__(default_kappa=0.0)


