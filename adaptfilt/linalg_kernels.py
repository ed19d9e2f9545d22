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
(:func:`einsum_is_plain`), then the subtraction, the square root and the
division, all correctly rounded: the same numbers on any CPU (``tests/test_linalg_kernels.py``, also
with numpy's SIMD code off). It applies to float64, C-ordered ``(n, n, M)`` batches with ``2 <= n <= 12``
and ``M >= 2`` (with one run numpy's einsum sums a contiguous axis otherwise), where
:func:`compiled_sums` says so; it reports whether every pivot
was positive, and where one was not the caller takes numpy's form, which names the runs.

**The switch of every compiled kernel** lives here, the lowest module that both the linear algebra and the
moment rules (:mod:`adaptfilt.rules`: the SIF's draws, sums and point sets, the scalar UKF's passes) read:
:data:`BACKEND` (``ADAPTFILT_SIF_BACKEND``: ``"auto"``, ``"numba"`` or ``"numpy"``), :data:`SUMS` and
:func:`compiled_sums` (the kernels that sum: those, numba importable, and numpy's einsum summing as they do).
"""
from __future__ import annotations

import os

import numpy as np

__all__ = ["BACKEND", "SUMS", "use_compiled", "einsum_is_plain", "compiled_sums", "available", "chol_positive"]

#: ``"auto"`` (the compiled kernels where numba is installed), ``"numba"`` (required) or ``"numpy"`` (numpy's
#: forms everywhere, e.g. to time them): every compiled kernel of the filters follows it.
BACKEND: str = os.environ.get("ADAPTFILT_SIF_BACKEND", "auto")
#: whether the kernels that sum (the Cholesky factor; the rules' point sets and weighted sums) are compiled
#: where :data:`BACKEND` allows it; False: numpy's forms, e.g. to time the kernels apart
SUMS: bool = True

_plain = None  # einsum_is_plain() once probed


def use_compiled() -> bool:
    """Whether :data:`BACKEND` lets compiled kernels run and numba can be imported (``"numba"`` without it is
    an ImportError; another value a ValueError naming the variable). Imports numba the first time."""
    if BACKEND == "numpy":
        return False
    if BACKEND not in ("auto", "numba"):
        raise ValueError(f"ADAPTFILT_SIF_BACKEND must be 'auto', 'numba' or 'numpy', got {BACKEND!r}")
    try:
        import numba  # noqa: F401
    except ImportError:
        if BACKEND == "numba":
            raise ImportError("ADAPTFILT_SIF_BACKEND=numba needs numba (the optional extra 'fast')") from None
        return False
    return True


def einsum_is_plain() -> bool:
    """Whether numpy's einsum adds its products as the kernels do: one rounded product, then one
    rounded sum, per term. A numpy built with fused multiply-adds in its baseline (aarch64's NEON;
    an x86-64 build with FMA3 in its baseline) rounds once per term instead, and no kernel without
    FMA can give its bits. Checked (once) on products whose fused and unfused sums differ."""
    global _plain
    if _plain is None:
        e = 2.0 ** -30
        M = 37  # SIMD blocks and a tail
        a = np.empty((1, 2, M))
        a[0, 0], a[0, 1] = 1.0 + e, 1.0 + e
        b = np.empty((1, 2, M))
        b[0, 0], b[0, 1] = -1.0, 1.0 - e  # 0 + -(1 + e), then + (1 + e)(1 - e) = 1 - e^2: 1 rounded, -e fused
        got = np.einsum("isM,jsM->ijM", a, b)  # fused: -e - e^2
        _plain = bool(np.all(got == -e))
    return _plain


def compiled_sums() -> bool:
    """The switch of the compiled kernels that sum (module docstring): :data:`SUMS`, :func:`use_compiled`
    and :func:`einsum_is_plain`."""
    return SUMS and use_compiled() and einsum_is_plain()

_kernel = None  # the compiled factorisation once built; False where unusable


def _build():
    global _kernel
    if _kernel is None:
        import numba  # use_compiled() has found it

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


def available() -> bool:
    """Whether the compiled factorisation is used (:func:`compiled_sums`); imports numba the first time."""
    return compiled_sums() and bool(_build())


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
