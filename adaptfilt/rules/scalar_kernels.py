r"""Compiled kernels of the scalar unscented filter (a state and a measurement of one dimension each, as
UNGM's): numpy's numbers bit for bit, in one pass over the runs where numpy's form makes a dozen.

With ``n = 1`` the moment rule's arrays are rows of ``M`` runs and every step of the filter is a
chain of elementwise operations, each of which numpy makes as a pass over the runs with a
temporary (``bench_ukf_limit.py`` counts them). The kernels here make each chain in one loop over
the runs, element by element, with the operations numpy's form applies, in its order:

* :func:`moments`: the unscented rule's moments of ``g(x)``, ``x ~ N(m, P)``, for a scalar state and
  a scalar ``g``: the points ``m +- a``, ``a = sqrt(P) sqrt(1 + kappa)``
  (:func:`_points1`); ``g`` at them (numpy, the model's code); then (:func:`_sums1`) the deviations
  ``d = g(X) - g(m)``, ``w d``, ``ED = 0 + w d_+ + w d_-`` (numpy's reduction from 0),
  ``EDD = 0 + (w d_+) d_+ + (w d_-) d_-`` and ``EXD = 0 + a (w d_+) + (-a)(w d_-)`` (einsum's sums
  from 0, each product rounded: :func:`adaptfilt.linalg_kernels.einsum_is_plain`), the first
  set's ``+ 0``, ``Cov = EDD - ED ED`` and the mean ``g(m) + ED``
  (:meth:`adaptfilt.rules.MomentRule.moments`);
* :func:`update`: the update from the measurement moments
  (:meth:`adaptfilt.gaf.GaussianAssumedFilter._finish_update`): ``Pzz = S + R``, its factor
  ``sqrt(Pzz)``, ``K = Pxz / L_zz^2``, ``z~ = z - z_pred``, ``NIS = z~ (z~ / L_zz^2)``,
  ``x_filt = x_pred + (0 + K z~)``, ``P_filt = P - (0 + (0 + K Pzz) K)`` and its factor; the
  log-likelihood's logarithm stays numpy's (its SIMD logarithm is not correctly rounded, so no
  other code gives its bits), the rest of it is the kernel's second loop.

Only ``+``, ``-``, ``*``, ``/`` and ``sqrt``, each correctly rounded, and numba compiles without
``fastmath`` (no fused multiply-adds, no reordering, ``x + 0.0`` kept: it turns ``-0`` into ``+0``):
the same numbers on any CPU (``tests/test_scalar_kernels.py``, also with numpy's SIMD code off).
Where a kernel's result would be an error or a repair in numpy's form (a factor of a covariance that
is not positive, a non-finite mean), the caller computes the step again in numpy's form, which
raises or repairs as it always did. They are used where :func:`available` (numba installed,
:data:`adaptfilt.linalg_kernels.BACKEND` not ``"numpy"``, numpy's einsum without fused
multiply-adds) and for ``M >= 2`` runs (with one run numpy reduces a contiguous axis otherwise).
"""
from __future__ import annotations

import numpy as np

from adaptfilt.rules import _sif_kernels

__all__ = ["available", "moments", "update"]

_kernels = None  # (points, sums, update, loglik) once built; False where unusable


def _build():
    global _kernels
    if _kernels is None:
        if not _sif_kernels._build_sums():  # numba missing, or numpy's einsum fuses multiply-adds
            _kernels = False
            return _kernels
        import numba

        @numba.njit(cache=True, nogil=True)
        def _points1(m, L, scale, per_run, X, A):  # pragma: no cover - compiled
            """``A = L scale``, ``X[0] = m + A``, ``X[1] = m - A`` (``m - a`` is ``m + (-a)`` bit for bit);
            ``scale[r * per_run]``: one value (``per_run = 0``) or one per run (1)."""
            for r in range(m.shape[0]):
                a = L[r] * scale[r * per_run]
                A[r] = a
                X[0, r] = m[r] + a
                X[1, r] = m[r] - a

        @numba.njit(cache=True, nogil=True)
        def _sums1(G, g0, A, w, per_run, cross, mean, cov, EXD):  # pragma: no cover - compiled
            """The moments from ``G = g(X)``: the operations of ``_deviations``, ``_sums_numpy``, the first
            set's ``+ 0`` and the standard covariance, element by element; ``w`` as ``scale`` above."""
            for r in range(g0.shape[0]):
                d0 = G[0, r] - g0[r]
                d1 = G[1, r] - g0[r]
                wr = w[r * per_run]
                wd0 = d0 * wr
                wd1 = d1 * wr
                ed = ((0.0 + wd0) + wd1) + 0.0
                edd = ((0.0 + wd0 * d0) + wd1 * d1) + 0.0
                if cross:
                    EXD[r] = ((0.0 + A[r] * wd0) + (-A[r]) * wd1) + 0.0
                cov[r] = edd - ed * ed
                mean[r] = g0[r] + ed

        @numba.njit(cache=True, nogil=True, error_model="numpy")
        def _update1(m, P, z, z_pred, S, Pxz, R, Pzz, Lz, K, innov, nis, x_filt, P_filt, L_filt):  # pragma: no cover
            """The update's arithmetic up to the log-likelihood; returns whether numpy's form would have
            carried on: every ``Pzz > 0``, every ``x_filt`` finite, every ``P_filt > 0`` (NaN fails)."""
            ok = True
            for r in range(m.shape[0]):
                pzz = S[r] + R
                Pzz[r] = pzz
                ok = ok and pzz > 0.0
                lz = np.sqrt(pzz)
                Lz[r] = lz
                lz2 = lz * lz
                k = Pxz[r] / lz2
                K[r] = k
                v = z[r] - z_pred[r]
                innov[r] = v
                nis[r] = v * (v / lz2)
                x = m[r] + (0.0 + k * v)
                x_filt[r] = x
                ok = ok and np.isfinite(x)
                p = P[r] - (0.0 + (0.0 + k * pzz) * k)
                P_filt[r] = p
                ok = ok and p > 0.0
                L_filt[r] = np.sqrt(p)
            return ok

        @numba.njit(cache=True, nogil=True)
        def _loglik1(nis, log_lz, c, out):  # pragma: no cover - compiled
            """``-0.5 (NIS + 2 log L_zz + c)``, numpy's order."""
            for r in range(nis.shape[0]):
                out[r] = -0.5 * ((nis[r] + 2.0 * log_lz[r]) + c)

        _kernels = (_points1, _sums1, _update1, _loglik1)
    return _kernels


def available() -> bool:
    """Whether the scalar kernels are used (numba importable, :data:`~adaptfilt.linalg_kernels.BACKEND`
    and :data:`~adaptfilt.linalg_kernels.SUMS` allow compiled sums, numpy's einsum sums as they do)."""
    return _sif_kernels.sums_available() and bool(_build())


def _row(a: np.ndarray, M: int) -> np.ndarray | None:
    """The ``(M,)`` run row of a ``(1, M)`` or ``(1, 1, M)`` float64 array, else None."""
    if a.dtype != np.float64 or a.shape[-1] != M or a.size != M:
        return None
    return a.reshape(M)


def _runs(v, M: int) -> tuple[np.ndarray | None, int]:
    """A float parameter as the kernels take it: ``(array of one value, 0)``, ``(the (M,) values, 1)``,
    or ``(None, 0)`` for anything else."""
    if type(v) is float:
        return np.array((v,)), 0
    v = np.asarray(v)
    if v.dtype != np.float64 or v.shape not in ((), (M,)):
        return None, 0
    return (v.reshape(1), 0) if v.ndim == 0 else (v, 1)


def moments(g, m: np.ndarray, g0: np.ndarray, L: np.ndarray, scale, weight, cross: bool):
    """``(mean (1, M), cov (1, 1, M), cross (1, 1, M) or None)`` of the unscented rule's one point set
    with ``scale`` and ``weight`` (scalars or ``(M,)``) for a scalar state ``m (1, M)`` with factor
    ``L (1, 1, M)`` and a scalar ``g`` (``g0 = g(m) (1, M)``), the standard covariance; None where the
    kernels do not apply (then numpy's form, which calls ``g`` again)."""
    M = m.shape[1]
    if m.shape[0] != 1 or g0.shape != (1, M) or L.shape != (1, 1, M) or M < 2 or not available():
        return None
    mr, gr, Lr, (sc, sc_runs), (w, w_runs) = _row(m, M), _row(g0, M), _row(L, M), _runs(scale, M), _runs(weight, M)
    if mr is None or gr is None or Lr is None or sc is None or w is None:
        return None
    points, sums = _kernels[0], _kernels[1]
    X, A = np.empty((1, 2, M)), np.empty(M)
    points(mr, Lr, sc, sc_runs, X[0], A)
    G = g(X)
    if G.shape != (1, 2, M) or G.dtype != np.float64:
        return None
    mean, cov = np.empty((1, M)), np.empty((1, 1, M))
    EXD = np.empty((1, 1, M)) if cross else None
    sums(G[0], gr, A, w, w_runs, cross, mean[0], cov[0, 0], A if EXD is None else EXD[0, 0])
    return mean, cov, EXD


def update(m: np.ndarray, P: np.ndarray, z: np.ndarray, z_pred: np.ndarray, S: np.ndarray, Pxz: np.ndarray,
           R: np.ndarray, log2pi: float):
    """The scalar update's ``(Pzz, K, innov, nis, loglik, x_filt, P_filt, L_filt)``, each in the filter's
    run-last layout, or None: the kernels do not apply (not every array a float64 run row of one
    dimension) or numpy's form would raise or repair (a ``Pzz`` or ``P_filt`` that is not positive, a
    non-finite ``x_filt``): then numpy's form does the step."""
    M = m.shape[-1]
    if M < 2 or R.size != 1 or not available():
        return None
    rows = [_row(a, M) for a in (m, P, z, z_pred, S, Pxz)]
    if any(r is None for r in rows) or R.dtype != np.float64:
        return None
    Pzz, Lz, K, P_filt, L_filt = (np.empty((1, 1, M)) for _ in range(5))
    innov, x_filt = np.empty((1, M)), np.empty((1, M))
    nis = np.empty(M)
    if not _kernels[2](*rows, float(R.reshape(())), Pzz[0, 0], Lz[0, 0], K[0, 0], innov[0], nis, x_filt[0],
                       P_filt[0, 0], L_filt[0, 0]):
        return None
    loglik = np.empty(M)
    _kernels[3](nis, np.log(Lz[0, 0]), log2pi, loglik)
    return Pzz, Lz, K, innov, nis, loglik, x_filt, P_filt, L_filt
