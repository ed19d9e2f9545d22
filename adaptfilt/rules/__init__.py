r"""Moment rules: E[g(x)], Cov[g(x)] and Cov[x, g(x)] for x ~ N(m, P).

A Gaussian-assumed filter (Algorithm 1 of the paper) is one recursion plus a
moment rule; this module holds the rules. All rules here are *fully symmetric*:
with ``P = L L^T`` they evaluate ``g`` at the centre ``m`` and at pairs of
points ``m +- L a_k`` that share a weight ``w_k``; the centre carries
``1 - 2 sum_k w_k``.

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
round-off small. For linear ``g`` the deterministic rules and the stochastic
rules of degree 3 and 5 are exact, whatever their parameter: all those filters
then agree with the Kalman filter.

Rules
-----
* :class:`UnscentedRule` (Julier's sigma points, parameter ``kappa``):
  ``a_j = sqrt(n + kappa) e_j``, ``w = 1 / (2 (n + kappa))``; the centre
  weight ``kappa / (n + kappa)`` is negative for ``kappa < 0``. ``form``
  selects Julier and Uhlmann's *modified* form for that case (the covariance
  taken about ``g0``: ``Cov[g] = sum_i w_i D_i D_i^T``, positive semidefinite
  whatever ``kappa``).
* :class:`CubatureRule`: the unscented rule at ``kappa = 0``.
* :class:`StochasticIntegrationRule` (parameter ``n_iter``): Genz and
  Monahan's stochastic spherical-radial rules of degree 1, 3 or 5 as used by
  Dunik, Straka and Simandl's stochastic integration filter, averaged over
  ``n_iter`` independent draws, with the options of the authors' reference
  implementations (separate mean / covariance passes, the integration-error
  term, tolerance stopping).

The rules live in :mod:`adaptfilt.rules.base` (:class:`Moments`, :class:`MomentRule`),
:mod:`adaptfilt.rules.unscented` (the deterministic rules) and :mod:`adaptfilt.rules.stochastic` (the
stochastic integration rule); this package exports their public names.
"""
from adaptfilt.rules import _sif_kernels
from adaptfilt.rules.base import MomentRule, Moments
from adaptfilt.rules.stochastic import StochasticIntegrationRule, haar_rotations, stochastic_rule_points
from adaptfilt.rules.unscented import CubatureRule, UnscentedRule

__all__ = [
    "Moments", "MomentRule", "UnscentedRule", "CubatureRule", "StochasticIntegrationRule",
    "haar_rotations", "stochastic_rule_points", "compiled_kernels",
]


def compiled_kernels() -> bool:
    """Whether the filters' compiled kernels run (the SIF's sums and draws, the scalar UKF's passes, the
    Cholesky factor): numba installed (the extra ``fast``), ``ADAPTFILT_SIF_BACKEND`` not ``numpy``, and
    numpy's einsum summing without fused multiply-adds, as the kernels do (their numbers are numpy's bit
    for bit). The switch is :mod:`adaptfilt.linalg_kernels`'s (:func:`~adaptfilt.linalg_kernels.compiled_sums`),
    which the Cholesky factor reads too. Imports numba the first time."""
    return _sif_kernels.sums_available()
