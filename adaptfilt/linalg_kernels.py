r"""The batched Cholesky factor compiled (:func:`chol_positive`): numpy's numbers bit for bit.

:func:`adaptfilt.linalg.chol` factors ``n x n`` matrices (``n <= 12``) for ``M`` runs at once with a
loop over the columns, each step a few numpy calls over the runs: for column ``j``

.. math::

    d = P_{jj} - \sum_{k \lt j} L_{jk}^2, \quad L_{jj} = \sqrt{d}, \quad
    L_{ij} = \Bigl(P_{ij} - \sum_{k \lt j} L_{ik} L_{jk}\Bigr) / L_{jj} \quad (i \gt j),

about ``3 n`` numpy calls with temporaries over the runs for a factor (the CTM's ``n = 5``: 15 calls,
a millisecond at 10^4 runs; its filters factor several covariances a step). The kernel here computes
each run's factor in one pass with the same operations in the same order: numpy's einsum adds the
products ``0 + p_0 + p_1 + ...`` in the order of ``k``, each product rounded first
(:func:`adaptfilt.rules._sif_kernels._einsum_is_plain`), then the subtraction, the square root and the
division, all correctly rounded: the same numbers on any CPU (``tests/test_linalg_kernels.py``, also
with numpy's SIMD code off). It applies to float64, C-ordered ``(n, n, M)`` batches with ``2 <= n <= 12``
and ``M >= 2`` (with one run numpy's einsum sums a contiguous axis otherwise), where
:func:`adaptfilt.rules.compiled_kernels` says so; it reports whether every pivot
was positive, and where one was not the caller takes numpy's form, which names the runs.
"""
from __future__ import annotations

import numpy as np

__all__ = ["available", "chol_positive"]

_kernel = None  # the compiled factorisation once built; False where unusable


def _build():
    global _kernel
    if _kernel is None:
        import numba  # the gate has found it

        @numba.njit(cache=True, nogil=True, error_model="numpy")
        def _chol(P, L, d):  # pragma: no cover - compiled
            """``L``: the lower factor of every ``P[:, :, r]``, zeros above the diagonal; returns the
            number of pivots that were not positive (NaN is not). In blocks of runs (``d``: a block's
            pivots), the runs innermost, as numpy's elementwise loops run: LLVM vectorises them, each
            operation still correctly rounded."""
            n, M = P.shape[0], P.shape[2]
            B = d.shape[0]
            bad = 0
            for r0 in range(0, M, B):
                r1 = min(r0 + B, M)
                for j in range(n):
                    for r in range(r0, r1):
                        s = 0.0
                        for k in range(j):
                            s = s + L[j, k, r] * L[j, k, r]
                        v = P[j, j, r] - s if j else P[j, j, r]
                        bad += 0 if v > 0.0 else 1
                        v = np.sqrt(v)
                        L[j, j, r] = v
                        d[r - r0] = v
                    for i in range(j):
                        for r in range(r0, r1):
                            L[i, j, r] = 0.0
                    for i in range(j + 1, n):
                        for r in range(r0, r1):
                            s = 0.0
                            for k in range(j):
                                s = s + L[i, k, r] * L[j, k, r]
                            L[i, j, r] = (P[i, j, r] - s if j else P[i, j, r]) / d[r - r0]
            return bad

        _kernel = _chol
    return _kernel


#: Whether compiled kernels may run: :func:`adaptfilt.rules.compiled_kernels`, the one switch of them all,
#: which :mod:`adaptfilt.rules` sets here when imported (the rules import :mod:`adaptfilt.linalg`, so this
#: module does not import them); None: numpy's form.
gate = None


def available() -> bool:
    """Whether the compiled factorisation is used (:data:`gate`); imports numba the first time."""
    return gate is not None and gate() and bool(_build())


def chol_positive(P: np.ndarray) -> np.ndarray | None | bool:
    """The factor :func:`adaptfilt.linalg._chol_positive` computes, compiled: ``L``, or None where a pivot
    is not positive; False where the kernel does not apply (then numpy's form)."""
    n = P.shape[0]
    if P.ndim != 3 or not 2 <= n <= 12 or P.shape[2] < 2 or P.dtype != np.float64 or not P.flags.c_contiguous:
        return False
    if not available():
        return False
    L = np.empty_like(P)
    return None if _kernel(P, L, np.empty(256)) else L
