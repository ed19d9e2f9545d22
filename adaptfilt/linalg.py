"""Batched small-matrix linear algebra with the Monte-Carlo run axis *last*.

Inside the filters a mean is stored as ``(n, M)`` and a covariance as
``(n, n, M)``: every entry ``P[i, j]`` is then a contiguous vector over the
``M`` runs, and a Cholesky factorisation of ten thousand 4x4 matrices is a
handful of vector operations instead of ten thousand LAPACK calls (about 10x
faster than ``np.linalg.cholesky`` on an ``(M, n, n)`` stack here). The public
API shows the same memory as ``(M, n)`` / ``(M, n, n)`` views.

Every function accepts any number of trailing batch axes (``...``).
"""
from __future__ import annotations

import numpy as np

from adaptfilt import linalg_kernels

__all__ = [
    "NotPositiveDefinite",
    "sym",
    "sym_fresh",
    "chol",
    "mm",
    "mv",
    "solve_spd",
    "logdet_chol",
    "clip_to_pd",
    "wrap_angle",
]

# Above this dimension a Python loop over matrix entries stops paying off.
_LOOP_MAX_N = 12


class NotPositiveDefinite(np.linalg.LinAlgError):
    """A batch of matrices had members that are not positive definite.

    ``runs`` holds the flat indices (over the trailing batch axes) of the
    offending members so that callers can name them in their own error.
    """

    def __init__(self, runs: np.ndarray, what: str = "matrix"):
        self.runs = np.asarray(runs)
        self.what = what
        shown = ", ".join(str(int(r)) for r in self.runs[:10])
        more = "" if self.runs.size <= 10 else f" (+{self.runs.size - 10} more)"
        super().__init__(f"{what} is not positive definite in run(s) {shown}{more}")

    def __reduce__(self):
        # rebuilt from its own arguments: a worker process that raises it must be able to send it back
        return (type(self), (self.runs, self.what))


def sym(P: np.ndarray) -> np.ndarray:
    """Symmetric part ``(P + P^T) / 2`` over the two leading axes."""
    S = P + P.swapaxes(0, 1)
    if S.dtype.kind != "f":
        return 0.5 * S
    S *= 0.5  # in place: one temporary fewer, the same numbers
    return S


def sym_fresh(P: np.ndarray) -> np.ndarray:
    """:func:`sym` of a covariance just computed (a fresh array, not shared), with a 1x1 matrix
    returned as it is: the symmetric part of a 1x1 matrix is itself, and ``(P + P) / 2`` equals ``P``
    bit for bit except where ``2 P`` overflows (``|P| > 8.9e307``, which it turns into inf). Saves
    the filters of a scalar state or measurement two passes over the runs per covariance."""
    return P if P.shape[0] == 1 else sym(P)


def _bad_runs(bad: np.ndarray) -> np.ndarray:
    return np.flatnonzero(np.broadcast_to(bad, bad.shape))


def chol(P: np.ndarray, what: str = "matrix") -> np.ndarray:
    """Lower Cholesky factor ``L`` with ``L L^T = P`` for ``P`` of shape ``(n, n, ...)``.

    Raises :class:`NotPositiveDefinite` naming the batch members whose pivot is
    not strictly positive (or not finite): never returns NaN.
    """
    n = P.shape[0]
    if P.shape[1] != n:
        raise ValueError(f"{what} must be square over its two leading axes, got shape {P.shape}")
    if n > _LOOP_MAX_N:
        Pm = np.moveaxis(P, (0, 1), (-2, -1))
        bad = ~np.isfinite(Pm).all(axis=(-2, -1))
        ok = ~bad
        L = np.zeros_like(Pm)
        try:
            L[ok] = np.linalg.cholesky(Pm[ok])
        except np.linalg.LinAlgError:
            ev = np.linalg.eigvalsh(Pm[ok])
            bad[ok] = ev[..., 0] <= 0
        if bad.any():
            raise NotPositiveDefinite(np.flatnonzero(bad.ravel()), what)
        return np.moveaxis(L, (-2, -1), (0, 1))
    if P.dtype == np.float64:
        L = _chol_positive(P)
        if L is not None:
            return L
    # some pivot is not positive: factor again, carrying on past the bad runs to name them all
    L = np.zeros_like(P)
    bad = np.zeros(P.shape[2:], dtype=bool)
    for j in range(n):
        d = P[j, j] - np.einsum("k...,k...->...", L[j, :j], L[j, :j]) if j else P[j, j].copy()
        bad |= ~(d > 0)  # also catches NaN
        d = np.sqrt(np.where(bad, 1.0, d))
        L[j, j] = d
        if j + 1 < n:
            s = P[j + 1 :, j] - np.einsum("ik...,k...->i...", L[j + 1 :, :j], L[j, :j]) if j else P[j + 1 :, j]
            L[j + 1 :, j] = s / d
    if bad.any():
        raise NotPositiveDefinite(_bad_runs(bad), what)
    return L


def _all_positive(d: np.ndarray) -> bool:
    """Every entry ``> 0`` (NaN is not); one pass where ``(d > 0).all()`` takes two."""
    return d.size == 0 or bool(d.min() > 0)


def _chol_positive(P: np.ndarray) -> np.ndarray | None:
    """:func:`chol`'s factor when every pivot is positive (the same operations, without the
    per-run bookkeeping of bad pivots), else None."""
    n = P.shape[0]
    if n == 1:  # a 1x1 factor is the square root
        if not _all_positive(P):
            return None
        return np.sqrt(P, out=np.empty_like(P))
    L = linalg_kernels.chol_positive(P)  # compiled, numpy's bits; False: numpy's form below
    if L is not False:
        return L
    L = np.zeros_like(P)  # the layout of P, as in the bookkeeping loop: einsum's order follows it
    for j in range(n):
        d = P[j, j] - np.einsum("k...,k...->...", L[j, :j], L[j, :j]) if j else P[j, j]
        if not _all_positive(d):
            return None
        d = np.sqrt(d)
        L[j, j] = d
        if j + 1 < n:
            s = P[j + 1 :, j] - np.einsum("ik...,k...->i...", L[j + 1 :, :j], L[j, :j]) if j else P[j + 1 :, j]
            L[j + 1 :, j] = s / d
    return L


def mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Batched matrix product ``(n, k, ...) x (k, m, ...) -> (n, m, ...)``."""
    return np.einsum("ik...,kj...->ij...", A, B)


def mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Batched matrix-vector product ``(n, k, ...) x (k, ...) -> (n, ...)``."""
    return np.einsum("ik...,k...->i...", A, x)


def _forward(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Solve ``L Y = B`` for lower-triangular ``L (m, m, ...)`` and ``B (m, k, ...)``."""
    m = L.shape[0]
    Y = np.empty(np.broadcast_shapes(B.shape, (m,) + B.shape[1:2] + L.shape[2:]), dtype=float)
    for i in range(m):
        s = B[i] - np.einsum("j...,jk...->k...", L[i, :i], Y[:i]) if i else B[i]
        Y[i] = s / L[i, i]
    return Y


def _backward(L: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Solve ``L^T X = Y`` for lower-triangular ``L``."""
    m = L.shape[0]
    X = np.empty_like(Y)
    for i in reversed(range(m)):
        s = Y[i] - np.einsum("j...,jk...->k...", L[i + 1 :, i], X[i + 1 :]) if i + 1 < m else Y[i]
        X[i] = s / L[i, i]
    return X


def solve_spd(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^{-1} B`` given the Cholesky factor ``L`` of ``A (m, m, ...)`` and ``B (m, k, ...)``."""
    if L.shape[0] == 1:
        return B / (L[0, 0] ** 2)
    return _backward(L, _forward(L, B))


def logdet_chol(L: np.ndarray) -> np.ndarray:
    """``log det A`` from the Cholesky factor of ``A``."""
    if L.shape[0] == 1:  # the sum of one log: 0 + log(l) = log(l) (a log is never -0)
        return 2.0 * np.log(L[0, 0])
    return 2.0 * np.log(np.diagonal(L, axis1=0, axis2=1)).sum(axis=-1)


def clip_to_pd(P: np.ndarray, runs: np.ndarray, floor: float = 1e-9) -> np.ndarray:
    """Copy of ``P (n, n, M)`` whose listed runs are replaced by their nearest
    positive-definite matrix: eigenvalues clipped below at
    ``floor * max(1, largest |eigenvalue|)``.

    The explicit, opt-in repair for covariances that lost definiteness through
    negative weights (``on_indefinite="clip"`` in the filters).
    """
    P = P.copy()
    Pm = np.moveaxis(P[:, :, runs], -1, 0)
    w, V = np.linalg.eigh(sym(np.moveaxis(Pm, 0, -1)).transpose(2, 0, 1))
    lo = floor * np.maximum(1.0, np.abs(w).max(axis=-1, keepdims=True))
    w = np.maximum(w, lo)
    fixed = np.einsum("mik,mk,mjk->mij", V, w, V)
    P[:, :, runs] = np.moveaxis(fixed, 0, -1)
    return P


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles to ``(-pi, pi]``.

    Angles already inside are returned unchanged (exactly); only the others
    go through the (slow) floating-point modulo.
    """
    a = np.asarray(a, dtype=float)
    outside = (a > np.pi) | (a <= -np.pi)
    if not outside.any():
        return a.copy()
    out = a.copy()
    w = np.mod(a[outside] + np.pi, 2.0 * np.pi) - np.pi
    # mod maps +pi to -pi; the convention here is the half-open (-pi, pi].
    out[outside] = np.where(w == -np.pi, np.pi, w)
    return out
