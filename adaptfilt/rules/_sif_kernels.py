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
  The kernels that divide are compiled with numba's ``error_model="numpy"``: a zero divisor gives
  ``inf``/``nan`` as numpy does instead of raising ``ZeroDivisionError``, and without that check per
  division LLVM vectorises the divisions (each still correctly rounded: the same bits).

The kernel also gathers the runs it is asked for (``runs``: a subset of the draws' runs, or the copies
of a tiled batch), which the numpy form does with an explicit ``G[..., runs]`` first. numba is
imported on first use, not with :mod:`adaptfilt`. ``ADAPTFILT_SIF_BACKEND=numpy`` (or
:data:`adaptfilt.linalg_kernels.BACKEND` set to ``"numpy"``, the one switch of every compiled kernel) selects
the numpy form everywhere, e.g. to time it.
"""
from __future__ import annotations

import threading

import numpy as np

from adaptfilt import linalg_kernels

__all__ = ["available", "fused_available", "gram_schmidt", "gram_schmidt_numpy", "points", "rule3_draws",
           "rule3_points", "rule3_accumulate", "sums_available", "weighted_sums"]

_kernel = None  # the compiled kernel once built; False where numba is missing
_sums = None  # (points kernel, sums kernel) once built and checked against numpy; False where unusable
_fused = None  # (points of a degree-3 draw, sums and recursion state) once built; False where unusable
_draws = None  # the compiled random variates of a degree-3 draw once built and checked; False where unusable
_BLOCK = 256  # runs per block of the compiled sums (operands of a block stay in the first-level caches)


def _build():
    global _kernel
    if _kernel is None:
        try:
            import numba
        except ImportError:  # the optional extra "fast" is not installed: numpy it is
            _kernel = False
            return _kernel

        @numba.njit(cache=True, nogil=True, error_model="numpy")
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
    """The switch (:func:`adaptfilt.linalg_kernels.use_compiled`) and this kernel built."""
    return linalg_kernels.use_compiled() and available()


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


# ------------------------------------------------------------------ the point sets' weighted sums
def _build_sums():
    """The compiled point construction and weighted sums, or False: numba missing, or numpy's einsum
    found to sum otherwise than the kernel (a build whose baseline fuses multiply-adds, see
    :func:`adaptfilt.linalg_kernels.einsum_is_plain`)."""
    global _sums
    if _sums is None:
        if not available():
            _sums = False
            return _sums
        import numba

        @numba.njit(cache=True, nogil=True)
        def _points(m, L, Q, rotate, scale, X, A):  # pragma: no cover - compiled
            """``A = mm(L, Q) * scale`` (``L * scale`` without ``rotate``), ``X[:, :K] = m + A``,
            ``X[:, K:] = m - A``: numpy's einsum sums ``0 + p_0 + p_1 + ...`` over ``k`` per element.
            In blocks of runs (each run's arithmetic is its own: the blocks keep the operands in cache;
            the rows as 1-D views, loops LLVM vectorises along the runs)."""
            n, M = m.shape
            K = A.shape[1]
            for r0 in range(0, M, _BLOCK):
                r1 = min(r0 + _BLOCK, M)
                sc = scale[r0:r1]
                for i in range(n):
                    mi = m[i, r0:r1]
                    for j in range(K):
                        a = A[i, j, r0:r1]
                        B = a.shape[0]
                        if rotate:
                            for b in range(B):
                                a[b] = 0.0
                            for k in range(L.shape[1]):
                                lk, qk = L[i, k, r0:r1], Q[k, j, r0:r1]
                                for b in range(B):
                                    a[b] = a[b] + lk[b] * qk[b]
                        else:
                            lj = L[i, j, r0:r1]
                            for b in range(B):
                                a[b] = lj[b]
                        xp, xm = X[i, j, r0:r1], X[i, K + j, r0:r1]
                        for b in range(B):
                            v = a[b] * sc[b]
                            a[b] = v
                            xp[b] = mi[b] + v
                            xm[b] = mi[b] - v

        @numba.njit(cache=True, nogil=True)
        def _pair_sums_kernel(D, W, A, cross, wD, ED, EDD, EXD):  # pragma: no cover - compiled
            """``wD = D * w`` (``W (K, M)``, the weight of ``+a_k`` and ``-a_k``), ``ED = sum_s wD``,
            ``EDD = sum_s wD_i D_j``, ``EXD = sum_s dX_i wD_j`` (``dX = [A, -A]``), each sum from ``0``
            in the order of ``s``, as numpy's reduction and einsum add them; in blocks of runs, as above."""
            ng, S, M = D.shape
            K = S // 2
            for r0 in range(0, M, _BLOCK):
                r1 = min(r0 + _BLOCK, M)
                for i in range(ng):
                    e = ED[i, r0:r1]
                    B = e.shape[0]
                    for b in range(B):
                        e[b] = 0.0
                    for s in range(S):
                        d, w, wd = D[i, s, r0:r1], W[s if s < K else s - K, r0:r1], wD[i, s, r0:r1]
                        for b in range(B):
                            v = d[b] * w[b]
                            wd[b] = v
                            e[b] = e[b] + v
                for i in range(ng):
                    for j in range(ng):
                        e = EDD[i, j, r0:r1]
                        for b in range(B):
                            e[b] = 0.0
                        for s in range(S):
                            wd, d = wD[i, s, r0:r1], D[j, s, r0:r1]
                            for b in range(B):
                                e[b] = e[b] + wd[b] * d[b]
                if cross:
                    for i in range(A.shape[0]):
                        for j in range(ng):
                            e = EXD[i, j, r0:r1]
                            for b in range(B):
                                e[b] = 0.0
                            for s in range(K):
                                a, wd = A[i, s, r0:r1], wD[j, s, r0:r1]
                                for b in range(B):
                                    e[b] = e[b] + a[b] * wd[b]
                            for s in range(K):
                                a, wd = A[i, s, r0:r1], wD[j, K + s, r0:r1]
                                for b in range(B):
                                    e[b] = e[b] + (-a[b]) * wd[b]

        _sums = (_points, _pair_sums_kernel)
        if not linalg_kernels.einsum_is_plain():
            _sums = False
    return _sums


def sums_available() -> bool:
    """Whether :func:`points` and :func:`weighted_sums` are compiled (the switch,
    :func:`adaptfilt.linalg_kernels.compiled_sums`, and these kernels built); imports numba the first time."""
    return linalg_kernels.compiled_sums() and _use_kernel() and bool(_build_sums())


def _buffer(work: dict | None, key: str, shape: tuple) -> np.ndarray:
    """A scratch array of ``shape``, kept in ``work`` between calls (first-touch paging of fresh large
    arrays costs about as much as the kernels); a new one without ``work``."""
    if work is None:
        return np.empty(shape)
    a = work.get(key)
    if a is None or a.shape != shape:
        a = work[key] = np.empty(shape)
    return a


def points(m: np.ndarray, L: np.ndarray, rotation: np.ndarray | None, scale, work: dict | None = None):
    """The points ``X (n, 2K, M)`` = ``[m + A, m - A]`` and ``A = mm(L, rotation) * scale`` (``L * scale``
    when ``rotation`` is None), compiled, bit for bit numpy's (:func:`adaptfilt.rules.base._pair_sums`);
    None where the kernels do not apply (then the caller takes numpy's form): not compiled, one run
    (numpy's reductions then sum a contiguous axis pairwise), a scalar state (``n = 1``: no sums to
    fuse, the kernels' checks cost more than numpy's few calls), not float64 throughout. With ``work``,
    ``X`` and ``A`` are buffers kept there: valid until the next call with the same ``work``."""
    n, M = m.shape
    if M < 2 or n < 2 or not sums_available():  # n = 1 (the UNGM's UKF): numpy's few calls cost less than the checks
        return None
    K = n if rotation is None else rotation.shape[1]
    if (m.dtype != np.float64 or L.dtype != np.float64 or L.shape != (n, n, M)
            or (rotation is not None and (rotation.dtype != np.float64 or rotation.shape != (n, K, M)))):
        return None
    scale = np.asarray(scale)
    if scale.dtype != np.float64 or scale.shape not in ((), (M,)):
        return None
    X, A = _buffer(work, "points X", (n, 2 * K, M)), _buffer(work, "points A", (n, K, M))
    _sums[0](m, L, L if rotation is None else rotation, rotation is not None, np.broadcast_to(scale, (M,)), X, A)
    return X, A


def weighted_sums(D: np.ndarray, A: np.ndarray, weight, cross: bool, work: dict | None = None):
    """``(ED, EDD, EXD)`` of the deviations ``D (ng, 2K, M)`` at the points ``m +- A[:, k]`` with weight
    ``weight`` (scalar, ``(M,)`` or ``(K, M)``) for ``+a_k`` and ``-a_k``, compiled, bit for bit numpy's;
    None where the kernels do not apply (as :func:`points`)."""
    n, K, M = A.shape
    w = np.asarray(weight)
    if (M < 2 or not sums_available() or D.dtype != np.float64 or A.dtype != np.float64 or D.ndim != 3
            or D.shape[1:] != (2 * K, M) or w.dtype != np.float64 or w.shape not in ((), (M,), (K, M))):
        return None
    D = np.ascontiguousarray(D)
    ng = D.shape[0]
    ED, EDD = np.empty((ng, M)), np.empty((ng, ng, M))
    EXD = np.empty((n, ng, M)) if cross else np.empty((0, ng, M))
    _sums[1](D, np.broadcast_to(w, (K, M)), A, cross, _buffer(work, "sums wD", D.shape), ED, EDD, EXD)
    return ED, EDD, EXD if cross else None


# ------------------------------------------------------------------ one SIR iteration in two calls
def _build_fused():
    """The kernels of one degree-3 iteration of the SIR recursion (:func:`rule3_points`,
    :func:`rule3_accumulate`), made of the kernels above (the same compiled arithmetic), or False where
    those are unusable."""
    global _fused, _gs_jit, _points_jit, _sums_jit
    if _fused is None:
        if not _build_sums():
            _fused = False
            return _fused
        import numba

        # module globals, so that the kernels below call them as compiled functions (and can be cached)
        _gs_jit, (_points_jit, _sums_jit) = _kernel, _sums

        @numba.njit(cache=True, nogil=True, error_model="numpy")
        def _rule3_points(G, chi2, sel, m, L, Q, V, s, scale, weight, X, A):  # pragma: no cover - compiled
            """The degree-3 point set of the draw ``(G, chi2)`` for its runs ``sel``: ``Q`` = the Q factor
            of ``G[:, :, sel]`` (:func:`gram_schmidt`), ``scale = sqrt(chi2[sel])``, ``weight = 0.5 /
            chi2[sel]``, then the points as :func:`points` makes them."""
            _gs_jit(G, sel, Q, V, s)
            for c in range(sel.shape[0]):
                r2 = chi2[sel[c]]
                scale[c] = np.sqrt(r2)
                weight[c] = 0.5 / r2
            _points_jit(m, L, Q, True, scale, X, A)

        @numba.njit(cache=True, nogil=True, error_model="numpy")
        def _rule3_accumulate(D, A, weight, W, cross, wD, ED, EDD, EXD, compute, runs, n_runs, S0, S1, S2, N, track, I,
                              V, full, Vfull, dv):  # pragma: no cover - compiled
            """``(ED, EDD, EXD)`` of the draw (:func:`weighted_sums`; ``compute`` False: given), added to the
            running sums ``S0, S1, S2`` of the runs ``runs[:n_runs]`` (columns of the whole batch) and, with
            ``track``, the Welford state of the mean, at the draw count ``N`` (the same for every run still
            iterating):  ``D = (e - I) / N``, ``I = I + D``, ``V = (N - 2) / N V + D D`` for ``N >= 2``, and
            ``Vfull`` likewise with ``D D^T`` (``full``); element by element the numpy expressions of the
            recursion. The run loops innermost (``dv (ng, K)``: scratch)."""
            if compute:
                K = A.shape[1]
                for k in range(K):
                    for c in range(weight.shape[0]):
                        W[k, c] = weight[c]
                _sums_jit(D, W, A, cross, wD, ED, EDD, EXD)
            ng = ED.shape[0]
            for i in range(ng):
                for c in range(n_runs):
                    r = runs[c]
                    S0[i, r] = S0[i, r] + ED[i, c]
            for i in range(ng):
                for j in range(ng):
                    for c in range(n_runs):
                        r = runs[c]
                        S1[i, j, r] = S1[i, j, r] + EDD[i, j, c]
            if cross:
                for i in range(S2.shape[0]):
                    for j in range(ng):
                        for c in range(n_runs):
                            r = runs[c]
                            S2[i, j, r] = S2[i, j, r] + EXD[i, j, c]
            if track:
                later = N >= 2
                f = (N - 2) / N
                for i in range(ng):
                    for c in range(n_runs):
                        r = runs[c]
                        d = (ED[i, c] - I[i, r]) / N
                        dv[i, c] = d
                        I[i, r] = I[i, r] + d
                        if later:
                            V[i, r] = f * V[i, r] + d * d
                if full and later:
                    for i in range(ng):
                        for j in range(ng):
                            for c in range(n_runs):
                                r = runs[c]
                                Vfull[i, j, r] = f * Vfull[i, j, r] + dv[i, c] * dv[j, c]

        _fused = (_rule3_points, _rule3_accumulate)
    return _fused


def fused_available() -> bool:
    """Whether :func:`rule3_points` and :func:`rule3_accumulate` apply: :func:`sums_available` (imports numba the
    first time)."""
    return sums_available() and bool(_build_fused())


def rule3_points(G, chi2, sel, m, L, work: dict) -> tuple:
    """The points ``X (n, 2n, K)`` and directions ``A (n, n, K)`` of one degree-3 draw for the runs ``sel``
    of its variates (``G (n, n, M0)``, ``chi2 (M0,)``) at ``m (n, K)``, ``L (n, n, K)``, and the weights
    ``0.5 / chi2[sel]``: bit for bit :func:`gram_schmidt`, ``np.sqrt``, the division and :func:`points`.
    Needs :func:`fused_available`. ``work`` holds the buffers (valid until the next call with the same
    ``work`` and ``K``; the caller keeps one ``work`` per run set)."""
    bufs = work.get("rule3 points")
    if bufs is None:
        n, K = m.shape
        bufs = work["rule3 points"] = (np.empty((n, n, K)), np.empty((n, K)), np.empty(K), np.empty(K), np.empty(K),
                                       np.empty((n, 2 * n, K)), np.empty((n, n, K)))
    Q, V, s, scale, weight, X, A = bufs
    _fused[0](G, chi2, sel, m, L, Q, V, s, scale, weight, X, A)
    return X, A, weight


def rule3_accumulate(D, A, weight, cross: bool, runs, n_runs: int, sums: tuple, N: float, welford: tuple | None,
                     work: dict, given: tuple | None = None) -> None:
    """Add the draw's weighted sums (:func:`weighted_sums` of ``D``, ``A``, ``weight``; or ``given``,
    ``(ED, EDD, EXD)`` of the runs, made elsewhere) to ``sums = (S0, S1, S2)`` at the columns
    ``runs[:n_runs]`` and update ``welford = (I, V, Vfull or None)`` (None: not tracked) at draw count
    ``N``, in place. ``D`` C-contiguous float64 ``(ng, 2n, K)``."""
    S0, S1, S2 = sums
    ng, K = S0.shape[0], A.shape[2]
    bufs = work.get("rule3 sums")
    if bufs is None or bufs[1].shape != D.shape:
        n = A.shape[0]
        bufs = work["rule3 sums"] = (np.empty((n, K)), np.empty(D.shape), np.empty((ng, K)), np.empty((ng, ng, K)),
                                     np.empty((n if cross else 0, ng, K)), np.empty((ng, K)))
    W, wD, ED, EDD, EXD, dv = bufs
    compute = given is None
    if not compute:
        ED, EDD = given[0], given[1]
        EXD = given[2] if cross else EXD
    track = welford is not None
    I, V, Vfull = welford if track else (S0, S0, None)
    full = Vfull is not None
    _fused[1](D, A, weight, W, cross, wD, ED, EDD, EXD, compute, runs, n_runs, S0, S1, S2, float(N), track, I, V, full,
              Vfull if full else S1, dv)


# ------------------------------------------------------------------ the random variates of degree-3 draws
_DRAWS_MIN = 2048  # normals per call from which the compiled draw pays for numba's unboxing of the generator


def _build_draws():
    """numba's own port of numpy's Generator methods (the bit generator through its ctypes interface,
    numpy's ziggurat and Marsaglia-Tsang gamma with the same tables and the same calls to the C
    library's ``exp`` and ``log``), compiled, or False: numba missing, the backend is numpy, or the
    port found to draw otherwise than numpy on a throwaway generator."""
    global _draws
    if not _use_kernel():
        return False
    if _draws is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def _rule3_draws(rng, n, M, df, G, chi2):  # pragma: no cover - compiled
            for k in range(G.shape[0]):
                G[k] = rng.standard_normal((n, n, M))
                chi2[k] = rng.chisquare(df, M)

        a, b = np.random.default_rng(20261127), np.random.default_rng(20261127)
        G, chi2 = np.empty((2, 5, 5, 2000)), np.empty((2, 2000))
        _rule3_draws(a, 5, 2000, 7.0, G, chi2)  # 10^5 normals: several hundred take the slow path
        same = all(np.array_equal(G[k], b.standard_normal((5, 5, 2000))) and np.array_equal(chi2[k], b.chisquare(7.0, 2000))
                   for k in range(2))
        _draws = _rule3_draws if same and a.bit_generator.state == b.bit_generator.state else False
    return _draws


def rule3_draws(rng: np.random.Generator, n: int, M: int, count: int = 1,
                scratch: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The variates of ``count`` degree-3 draws for ``M`` runs, ``G (count, n, n, M)`` and
    ``chi2 (count, M)``: for each draw in turn ``rng.standard_normal((n, n, M))``, then
    ``rng.chisquare(n + 2, size=M)``, bit for bit, leaving ``rng`` in the state those calls leave it.
    numpy spends most of a normal variate outside the ziggurat itself (about 13 ns a variate against
    3 for the bit generator's raw output on this project's Xeon); numba's compiled port of the same
    algorithms takes about 4 ns, but unboxing the generator costs some 20 us a call, so the compiled
    form is used from :data:`_DRAWS_MIN` normals a call (``benchmarks/bench_sif.py --draws``).
    ``scratch``: the arrays are this thread's scratch buffers, valid until its next such call (a
    fresh array of a few MB costs about as much in first-touch page faults as drawing into it)."""
    shape_G, shape_c = (count, n, n, M), (count, M)
    if scratch:
        G, chi2 = _scratch_array("draws G", shape_G), _scratch_array("draws chi2", shape_c)
    else:
        G, chi2 = np.empty(shape_G), np.empty(shape_c)
    kernel = _build_draws() if count * n * n * M >= _DRAWS_MIN else False
    if kernel:
        kernel(rng, n, M, float(n + 2), G, chi2)
        return G, chi2
    for k in range(count):
        G[k] = rng.standard_normal((n, n, M))
        chi2[k] = rng.chisquare(n + 2, size=M)
    return G, chi2


_local = threading.local()


def _scratch_array(key: str, shape: tuple) -> np.ndarray:
    """A view of shape ``shape`` into this thread's scratch buffer ``key`` (grown when too small)."""
    bufs = _local.__dict__.setdefault("buffers", {})
    size = int(np.prod(shape))
    a = bufs.get(key)
    if a is None or a.size < size:
        a = bufs[key] = np.empty(size)
    return a[:size].reshape(shape)
