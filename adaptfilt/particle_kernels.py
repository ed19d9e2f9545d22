r"""Compiled (numba) kernels of :class:`~adaptfilt.particles.ParticleCountFilter`: the same numbers, faster.

The particle filter's reference form is numpy (``backend="numpy"``), whose per-run work (re-pointing
two Philox streams, drawing, a ``searchsorted`` for the ancestors) is a Python loop over runs. These
kernels do that loop, and the weighting, in compiled code, and give the same bits:

* ``_philox_block`` is numpy's ``Philox`` bit generator (Philox4x64-10, Salmon et al. 2011, the
  Random123 form numpy wraps): a stream keyed ``(seed, run)`` with counter ``(0, t, stream, 0)`` draws
  blocks at counters ``(1, t, stream, 0), (2, t, stream, 0), ...``, four 64-bit words each;
  ``random()`` is ``(word >> 11) * 2**-53`` and ``standard_normal()`` numpy's 256-layer ziggurat
  (its tables are numba's copy of numpy's, ``numba.np.random._constants``).
* The ancestors are ``searchsorted(cdf, u * cdf[-1], side="right")`` (capped at ``n_old - 1``), found
  with a guide table instead of a binary search: the ``n_old`` cdf values are counted into ``4 n_old``
  equal buckets of ``[0, cdf[-1]]`` and a query scans from the first value of its bucket, an expected
  O(1) per particle. The bucket of a value is a monotone function of it, so the count of values
  ``<= q`` is exactly the binary search's.
* The weighting sums over particles in their order, as the reference's ``cumsum`` does.

``tests/test_particles.py`` checks the draws and ancestors bit for bit against numpy's generators
and ``searchsorted``, and whole runs of both backends against each other.

Across CPUs. The draws, the ancestors (given the weights) and the sums are exact on any CPU: integer
arithmetic, and IEEE additions and products in a fixed order. ``exp`` and ``log`` are not: the kernels
call the C library's, numpy its own SIMD code where the CPU has it (AVX-512 on x86-64), and even the C
library picks another variant on a CPU without FMA. They differ in the last bit of a few per cent of
values (4.6 % of 2e6 ``exp`` on an AVX-512 Xeon; the C library's FMA and plain variants in 0.05 %), so
whole runs of the two backends agree bit for bit where :func:`exp_log_agree` says so, and to rounding
elsewhere: relative differences of at most a few 1e-16 per value, tested at 1e-12 (``TOLERANCE``).
"""
from __future__ import annotations

import numpy as np

try:
    import numba
    from llvmlite import ir
    from numba.core import types
    from numba.extending import intrinsic
    from numba.np.random._constants import fi_double, ki_double, wi_double, ziggurat_nor_inv_r, ziggurat_nor_r
except ImportError:  # the optional extra "fast" is not installed: the numpy backend is used
    numba = None

__all__ = ["AVAILABLE", "TOLERANCE", "exp_log_agree"] + (["predict_particles", "weigh_particles", "gaussian_loglik", "philox_uniforms",
                          "philox_normals"] if numba is not None else [])

AVAILABLE = numba is not None

#: the relative tolerance to which the two backends, and the stored particle evaluations rerun on another
#: CPU, are claimed equal where :func:`exp_log_agree` is False (bit for bit where it is True)
TOLERANCE = 1e-12

if AVAILABLE:
    _M0, _M1 = np.uint64(0xD2E7470EE14C6C93), np.uint64(0xCA5A826395121157)  # Philox4x64 multipliers
    _W0, _W1 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBB67AE8584CAA73B)  # its Weyl key increments
    _KI, _WI, _FI = ki_double.astype(np.uint64), wi_double.astype(np.float64), fi_double.astype(np.float64)
    _R, _INV_R = float(ziggurat_nor_r), float(ziggurat_nor_inv_r)
    _TO_DOUBLE = 1.0 / 9007199254740992.0  # 2**-53
    _BUCKETS = 4  # guide-table buckets per old particle
    def _jit(fn=None, **kw):
        return numba.njit(cache=True, nogil=True, **kw) if fn is None else numba.njit(cache=True, nogil=True)(fn)

    @intrinsic
    def _mulhilo64(typingctx, a, b):
        """High and low 64 bits of the 128-bit product ``a * b`` (Random123's ``mulhilo64``): one multiply."""
        def codegen(context, builder, signature, args):
            i64, i128 = ir.IntType(64), ir.IntType(128)
            p = builder.mul(builder.zext(args[0], i128), builder.zext(args[1], i128))
            hi = builder.trunc(builder.lshr(p, ir.Constant(i128, 64)), i64)
            return context.make_tuple(builder, signature.return_type, (hi, builder.trunc(p, i64)))
        return types.UniTuple(types.uint64, 2)(types.uint64, types.uint64), codegen

    @_jit(inline="always")
    def _philox_block(c0, c1, c2, c3, k0, k1):
        """Philox4x64-10 of the counter ``(c0, c1, c2, c3)`` under the key ``(k0, k1)``: four uint64."""
        for r in range(10):
            if r:
                k0 += _W0
                k1 += _W1
            hi0, lo0 = _mulhilo64(_M0, c0)
            hi1, lo1 = _mulhilo64(_M1, c2)
            c0, c1, c2, c3 = hi1 ^ c1 ^ k0, lo1, hi0 ^ c3 ^ k1, lo0
        return c0, c1, c2, c3

    @_jit(inline="always")
    def _fill(st, buf):
        """The next ``len(buf)`` (a multiple of 4) words of the stream ``st`` into ``buf``. ``st (6,) uint64``:
        key (seed, run), counter words 1-2 (t, stream), the last block drawn; block ``b`` is counter
        ``(b, t, stream, 0)``, the first ``b = 1`` (numpy increments the counter before each block).
        The blocks are independent, so the loop runs several at once."""
        b0 = st[5]
        for b in range(len(buf) // 4):
            c0 = b0 + np.uint64(b + 1)  # the 256-bit counter's carry never reaches beyond word 0 here
            buf[4 * b], buf[4 * b + 1], buf[4 * b + 2], buf[4 * b + 3] = _philox_block(
                c0, st[2], st[3], np.uint64(0), st[0], st[1])
        st[5] = b0 + np.uint64(len(buf) // 4)

    @_jit(inline="always")
    def _open(st, seed, run_id, t, stream):
        """Point ``st`` at the stream of ``(seed, run_id)`` with counter ``(0, t, stream, 0)``: a fresh numpy Philox."""
        st[0], st[1], st[2], st[3], st[5] = np.uint64(seed), np.uint64(run_id), np.uint64(t), np.uint64(stream), 0

    @_jit(inline="always")
    def _word(st, buf, p):
        """Word ``p`` of the buffered stream and the next position (``buf`` refilled when used up)."""
        if p == len(buf):
            _fill(st, buf)
            p = 0
        return buf[p], p + 1

    @_jit(inline="always")
    def _double(st, buf, p):
        w, p = _word(st, buf, p)
        return float(w >> np.uint64(11)) * _TO_DOUBLE, p

    @_jit
    def _normal(st, buf, p):
        """numpy's ``random_standard_normal`` (ziggurat) from word ``p`` of the buffered stream: the
        normal and the next position. Every branch and draw is numpy's, in its order."""
        while True:
            r, p = _word(st, buf, p)
            idx = int(r & np.uint64(0xFF))
            r = r >> np.uint64(8)
            sign = r & np.uint64(1)
            rabs = (r >> np.uint64(1)) & np.uint64(0x000FFFFFFFFFFFFF)
            x = float(rabs) * _WI[idx]
            if sign:
                x = -x
            if rabs < _KI[idx]:
                return x, p
            if idx == 0:  # the tail beyond r
                while True:
                    u, p = _double(st, buf, p)
                    xx = -_INV_R * np.log1p(-u)
                    u, p = _double(st, buf, p)
                    yy = -np.log1p(-u)
                    if yy + yy > xx * xx:
                        return (-(_R + xx) if (rabs >> np.uint64(8)) & np.uint64(1) else _R + xx), p
            else:
                u, p = _double(st, buf, p)
                if (_FI[idx - 1] - _FI[idx]) * u + _FI[idx] < np.exp(-0.5 * x * x):
                    return x, p

    @_jit
    def _uniforms(st, out, buf):
        """``out[:] =`` the stream's first ``len(out)`` doubles (``buf``: scratch of at least that many words)."""
        n = len(out)
        words = buf[:4 * ((n + 3) // 4)]
        _fill(st, words)
        for j in range(n):
            out[j] = float(words[j] >> np.uint64(11)) * _TO_DOUBLE

    @_jit
    def _normals(st, out, buf):
        """``out[:] =`` the stream's first ``len(out)`` standard normals; ``buf``: scratch words (refilled
        when the ziggurat's rejections use them up)."""
        n = len(out)
        size = min(len(buf), 4 * ((n + n // 32 + 64) // 4))  # one word per normal, 1.2 % more on average
        words = buf[:size]
        _fill(st, words)
        L, p = len(words), 0
        for j in range(n):
            if p < L:  # the ziggurat's first test inline: it accepts 98.8 % of the words
                r = words[p]
                idx = int(r & np.uint64(0xFF))
                rabs = (r >> np.uint64(9)) & np.uint64(0x000FFFFFFFFFFFFF)
                if rabs < _KI[idx]:
                    # the sign as a factor, not a branch (a random bit mispredicts half the time); exact
                    out[j] = float(rabs) * _WI[idx] * (1.0 - 2.0 * float((r >> np.uint64(8)) & np.uint64(1)))
                    p += 1
                    continue
            out[j], p = _normal(st, words, p)

    @_jit
    def _resample(cdf, n_old, u, n, x_old, x_new, start, anc):
        """``x_new[j] = x_old[a_j]`` for ``j < n``, ``a_j = min(searchsorted(cdf[:n_old], u[j] * cdf[n_old - 1],
        "right"), n_old - 1)``: multinomial resampling as the reference computes it; ``x_old[0]`` beyond ``n``."""
        c_last = cdf[n_old - 1]
        B = _BUCKETS * n_old  # several buckets a value: most queries find theirs empty and stop at once
        scale = B / c_last
        start[:B + 1] = 0
        for k in range(n_old):  # start[b + 1]: the values in bucket b; then a running sum
            start[min(int(cdf[k] * scale), B - 1) + 1] += 1
        acc = 0
        for b in range(B + 1):
            acc += start[b]
            start[b] = acc
        for j in range(n):
            q = u[j] * c_last
            k = start[min(int(q * scale), B - 1)]  # the first value of q's bucket: all before it are < q
            while k < n_old and cdf[k] <= q:
                k += 1
            anc[j] = min(k, n_old - 1)
        # the copy in a loop of its own: its loads do not wait on the search's mispredicted branches
        nx = x_old.shape[1]
        for j in range(x_new.shape[0]):
            k = anc[j] if j < n else 0
            for a in range(nx):
                x_new[j, a] = x_old[k, a]

    @_jit
    def predict_particles(seed, ids, t, n, nx, x_old, w_old, n_old, x_anc, noise):
        """Per run ``i``: ``noise[i, :n[i]]`` standard normals (stream 1) and, for ``t > 0``,
        ``x_anc[i, :n[i]] = x_old[i, anc]`` with multinomial ancestors from the uniforms of stream 0
        and the weights ``w_old``; beyond ``n[i]``, zero noise and particle 0 (the reference's padding)."""
        M, cap_old, nmax = n.shape[0], w_old.shape[1], n.max()
        st = np.empty(6, dtype=np.uint64)
        u = np.empty(nmax)
        buf = np.empty(4 * ((nmax * nx + nmax * nx // 32 + 64) // 4) + 4, dtype=np.uint64)
        cdf = np.empty(cap_old)
        start = np.empty(_BUCKETS * cap_old + 1, dtype=np.int64)
        anc = np.empty(nmax, dtype=np.int64)
        for i in range(M):
            ni = n[i]
            _open(st, seed, ids[i], t, 1)
            _normals(st, noise[i, :ni].reshape(ni * nx), buf)
            noise[i, ni:] = 0.0
            if t:  # (the reference also draws the uniforms at t = 0, from a stream of their own, unused)
                _open(st, seed, ids[i], t, 0)
                _uniforms(st, u[:ni], buf)
                acc = 0.0
                for k in range(n_old[i]):  # the reference's cumsum (its padding beyond n_old is not read)
                    acc += w_old[i, k]
                    cdf[k] = acc
                _resample(cdf, n_old[i], u, ni, x_old[i], x_anc[i], start, anc)

    @_jit
    def weigh_particles(logl, n, x, w, mean, cov, loglik, ess, amax):
        """The reference ``weigh`` from the particles' log-likelihoods ``logl (M, cap)``: fills ``w``,
        ``mean``, ``cov``, ``loglik``, ``ess`` and ``amax`` (the largest log-likelihood, NaN or inf
        where no particle explains the measurement: the caller raises)."""
        M, cap, nx = x.shape
        for i in range(M):
            ni = n[i]
            m = -np.inf
            for j in range(ni):
                v = logl[i, j]
                if v > m or v != v:  # NaN propagates, as numpy's max
                    m = v
                    if v != v:
                        break
            amax[i] = m
            s = 0.0
            for j in range(ni):
                e = np.exp(logl[i, j] - m)
                w[i, j] = e
                s += e
            w[i, ni:] = 0.0
            s2 = 0.0
            if nx == 1:  # scalar sums (kept in registers): the common 1-D case twice as fast
                m1 = 0.0
                for j in range(ni):
                    wj = w[i, j] / s
                    w[i, j] = wj
                    s2 += wj * wj
                    m1 += wj * x[i, j, 0]
                c1 = 0.0
                for j in range(ni):
                    c1 += (w[i, j] * (x[i, j, 0] - m1)) * (x[i, j, 0] - m1)
                mean[i, 0], cov[i, 0, 0] = m1, c1
            else:
                mean[i] = 0.0
                for j in range(ni):
                    wj = w[i, j] / s
                    w[i, j] = wj
                    s2 += wj * wj
                    for a in range(nx):
                        mean[i, a] += wj * x[i, j, a]
                cov[i] = 0.0
                for j in range(ni):
                    wj = w[i, j]
                    for a in range(nx):
                        da = wj * (x[i, j, a] - mean[i, a])
                        for b in range(nx):
                            cov[i, a, b] += da * (x[i, j, b] - mean[i, b])
            loglik[i] = np.log(s) + m - np.log(ni)
            ess[i] = 1.0 / s2

    @_jit
    def gaussian_loglik(r, Rinv, logdetR, const, out):
        """``out (M, N) = -0.5 * ((r' Rinv r + logdetR) + const)`` of every residual ``r (M, N, nz)``, the
        quadratic form summed term by term (i outer, j inner), as the reference does."""
        M, N, nz = r.shape
        if nz == 1:
            R = Rinv[0, 0]
            for i in range(M):
                for j in range(N):
                    out[i, j] = -0.5 * (((r[i, j, 0] * R) * r[i, j, 0] + logdetR) + const)
            return out
        for i in range(M):
            for j in range(N):
                q = (r[i, j, 0] * Rinv[0, 0]) * r[i, j, 0]
                for a in range(nz):
                    for b in range(nz):
                        if a or b:
                            q += (r[i, j, a] * Rinv[a, b]) * r[i, j, b]
                out[i, j] = -0.5 * ((q + logdetR) + const)
        return out

    @_jit
    def philox_uniforms(seed, run_id, t, stream, size):
        """``Generator(Philox(key=[seed, run_id], counter=[0, t, stream, 0])).random(size)``."""
        st = np.empty(6, dtype=np.uint64)
        _open(st, seed, run_id, t, stream)
        out = np.empty(size)
        _uniforms(st, out, np.empty(4 * ((size + 3) // 4), dtype=np.uint64))
        return out

    @_jit
    def philox_normals(seed, run_id, t, stream, size, scratch=64):
        """``Generator(Philox(key=[seed, run_id], counter=[0, t, stream, 0])).standard_normal(size)``
        (``scratch``: words buffered at once, small in tests to exercise the refill)."""
        st = np.empty(6, dtype=np.uint64)
        _open(st, seed, run_id, t, stream)
        out = np.empty(size)
        _normals(st, out, np.empty(4 * max(scratch // 4, 1), dtype=np.uint64))
        return out


def exp_log_agree(n: int = 200_000, seed: int = 0) -> bool:
    """Whether numpy's ``exp`` and ``log`` give the compiled kernels' (the C library's) bits on this CPU, on
    ``n`` values spanning what the filter takes (``exp`` of ``[-745, 0]``, ``log`` of ``[1e-300, 1e6]``):
    where they do, both backends give the same numbers bit for bit; where not (numpy's AVX-512 code),
    to rounding (:data:`TOLERANCE`). False without numba."""
    if not AVAILABLE:
        return False
    rng = np.random.default_rng(seed)
    a = np.concatenate([-rng.exponential(5.0, n // 2), rng.uniform(-745.0, 0.0, n - n // 2)])
    b = np.exp(rng.uniform(np.log(1e-300), np.log(1e6), n))
    e, lg = _exp_log(a, b)
    return bool(np.array_equal(e, np.exp(a)) and np.array_equal(lg, np.log(b)))


if AVAILABLE:
    @_jit
    def _exp_log(a, b):
        e, lg = np.empty_like(a), np.empty_like(b)
        for i in range(a.size):  # scalar calls, as in the kernels (not numba's array ufunc)
            e[i] = np.exp(a[i])
        for i in range(b.size):
            lg[i] = np.log(b[i])
        return e, lg
