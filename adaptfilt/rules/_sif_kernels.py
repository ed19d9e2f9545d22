r"""The stochastic integration rule's Gram-Schmidt (:func:`gram_schmidt`): numpy's numbers, compiled when numba is there.

The reference form is numpy, vectorised over runs (:func:`gram_schmidt_numpy`): per column ``j`` of
each ``G[:, :, r]``, modified Gram-Schmidt against the columns before it, then normalisation,

.. math::

    v \leftarrow v - (q_k^T v)\, q_k \quad (k < j), \qquad q_j = v / \sqrt{v^T v}.

Its cost at the sizes the filters use (``n = 5``, a few hundred runs) is Python's: ``n (n + 1) / 2``
small array operations per draw. The compiled kernel (numba, the optional extra ``fast``) does the
same arithmetic in the same order and gives the same bits:

* numpy's ``(Q[:, k] * v).sum(axis=0)`` on an ``(n, M)`` array (``M >= 2``) starts from ``+0.0`` and
  adds the rows in order (the run axis is the inner loop, the reduction the outer one); the kernel
  sums ``0.0 + p_0 + p_1 + ...`` left to right. With one run numpy reduces a contiguous axis by its
  pairwise sum instead (8 accumulators from 9 terms on): the numpy form is used there.
* Only ``+``, ``-``, ``*``, ``/`` and ``sqrt``, each correctly rounded in IEEE arithmetic, so the
  numbers are the same on any CPU. numba compiles without ``fastmath``, so LLVM neither contracts
  ``v - s q`` into a fused multiply-add nor reorders the sums
  (``tests/test_sif_kernels.py`` checks the bits against numpy, also with numpy's SIMD code disabled).

The kernel also gathers the runs it is asked for (``runs``: a subset of the draws' runs, or the copies
of a tiled batch), which the numpy form does with an explicit ``G[..., runs]`` first. numba is
imported on first use, not with :mod:`adaptfilt`. ``ADAPTFILT_SIF_BACKEND=numpy`` (or
:data:`BACKEND` set to ``"numpy"``) selects the numpy form everywhere, e.g. to time it.
"""
from __future__ import annotations

import os

import numpy as np

__all__ = ["BACKEND", "available", "gram_schmidt", "gram_schmidt_numpy"]

#: ``"auto"`` (the compiled kernel where numba is installed), ``"numba"`` (required) or ``"numpy"``
BACKEND: str = os.environ.get("ADAPTFILT_SIF_BACKEND", "auto")

_kernel = None  # the compiled kernel once built; False where numba is missing


def _build():
    global _kernel
    if _kernel is None:
        try:
            import numba
        except ImportError:  # the optional extra "fast" is not installed: numpy it is
            _kernel = False
            return _kernel

        @numba.njit(cache=True, nogil=True)
        def _gram_schmidt_runs(G, runs, Q, V, s):  # pragma: no cover - compiled
            """``Q[:, :, r]`` = the Q factor of ``G[:, :, runs[r]]``, numpy's operation order; ``V (n, K)``,
            ``s (K,)``: scratch. The run loop innermost, as numpy's elementwise loops run."""
            n, K = G.shape[0], Q.shape[2]
            for j in range(n):
                for i in range(n):
                    for r in range(K):
                        V[i, r] = G[i, j, runs[r]]
                for k in range(j):  # modified Gram-Schmidt
                    for r in range(K):
                        s[r] = 0.0
                    for i in range(n):
                        for r in range(K):
                            s[r] += Q[i, k, r] * V[i, r]
                    for i in range(n):
                        for r in range(K):
                            V[i, r] = V[i, r] - s[r] * Q[i, k, r]
                for r in range(K):
                    s[r] = 0.0
                for i in range(n):
                    for r in range(K):
                        s[r] += V[i, r] * V[i, r]
                for r in range(K):
                    s[r] = np.sqrt(s[r])
                for i in range(n):
                    for r in range(K):
                        Q[i, j, r] = V[i, r] / s[r]

        _kernel = _gram_schmidt_runs
    return _kernel


def available() -> bool:
    """Whether the compiled kernel can be used (numba importable); imports numba the first time."""
    return bool(_build())


def _use_kernel() -> bool:
    if BACKEND == "numpy":
        return False
    if BACKEND == "numba":
        if not available():
            raise ImportError("ADAPTFILT_SIF_BACKEND=numba needs numba (the optional extra 'fast')")
        return True
    if BACKEND != "auto":
        raise ValueError(f"ADAPTFILT_SIF_BACKEND must be 'auto', 'numba' or 'numpy', got {BACKEND!r}")
    return available()


def gram_schmidt_numpy(G: np.ndarray) -> np.ndarray:
    """The Q factor (positive diagonal R) of each ``G[:, :, j]``, ``(n, n, M)``: the numpy reference."""
    n = G.shape[0]
    Q = np.empty_like(G)
    for j in range(n):
        v = G[:, j]
        for k in range(j):  # modified Gram-Schmidt
            v = v - (Q[:, k] * v).sum(axis=0) * Q[:, k]
        Q[:, j] = v / np.sqrt((v * v).sum(axis=0))
    return Q


def gram_schmidt(G: np.ndarray, runs: np.ndarray | None = None) -> np.ndarray:
    """The Q factors of ``G[:, :, runs]`` (all runs when None), ``(n, n, len(runs))``, C-contiguous:
    bit for bit ``gram_schmidt_numpy(np.ascontiguousarray(G[..., runs]))``."""
    K = G.shape[2] if runs is None else len(runs)
    if K < 2 or not _use_kernel():
        return gram_schmidt_numpy(G if runs is None else np.ascontiguousarray(G[..., runs]))
    n = G.shape[0]
    idx = np.arange(K, dtype=np.intp) if runs is None else np.asarray(runs, dtype=np.intp)
    Q = np.empty((n, n, K))
    _kernel(np.asarray(G, dtype=float), idx, Q, np.empty((n, K)), np.empty(K))
    return Q
