r"""A particle filter whose particle count is a parameter, per run and per step; KLD-sampling's count.

The paper names the number of particles as the first example of a filter parameter that could be
adapted. :class:`ParticleCountFilter` makes it one, in the layout of the other filters here
(``M`` runs batched, a parameter per run and step, a :class:`~adaptfilt.filters.FilterRun` out):

.. math::
    \mathbf x^{(j)}_k = \mathbf f\big(\mathbf x^{(a_j)}_{k-1}, k-1\big) + \mathbf w^{(j)}_k,\qquad
    a_j \sim \mathrm{Cat}\big(w^{(1)}_{k-1}, \dots, w^{(N_{k-1})}_{k-1}\big),\qquad
    j = 1..N_k,

.. math::
    w^{(j)}_k \propto \mathcal N\big(\mathbf z_k - \mathbf h(\mathbf x^{(j)}_k); \mathbf 0, \mathbf R\big),\qquad
    \hat p(\mathbf z_k \mid \mathbf z^{k-1}) = \frac1{N_k} \sum_j
    \mathcal N\big(\mathbf z_k - \mathbf h(\mathbf x^{(j)}_k); \mathbf 0, \mathbf R\big):

the bootstrap filter (Gordon, Salmond and Smith, 1993) that resamples at every step, as a
particle filter whose count changes from step to step must (the ``N_k`` new particles are drawn
from the ``N_{k-1}`` weighted old ones), with multinomial resampling.

**Random numbers, by run and by particle.** The draws of run ``i`` at step ``k`` (its ancestor
uniforms and its process noise) come from streams of their own, keyed by ``(seed, run_ids[i], k)``,
and particle ``j`` uses the ``j``-th draw of each whatever ``N_k`` is. So a run filtered alone
(``run_ids``) gives the same numbers as in a batch, whatever the other runs' counts, and at a step
the first ``n`` particles drawn for a count ``n`` are the first ``n`` of any larger count: what
KLD-sampling's sequential stopping rule (draw until the count meets the bound) needs. Multinomial,
not systematic, resampling is the price (systematic positions ``(u + j)/N`` depend on ``N``). Two
different counts on the same run decouple from the next resampling on (the ancestors of particle
``j`` are drawn from different sets), so a paired comparison of counts shares the trajectories and
measurements, not the particles.

**Two backends, one set of numbers.** ``backend="numpy"`` is the reference: a Python loop over runs
re-points two Philox generators per run and step and finds the ancestors with ``searchsorted``.
``backend="numba"`` (the default where the optional extra ``fast`` is installed) runs that loop and the
weighting as compiled kernels (:mod:`adaptfilt.particle_kernels`: numpy's Philox and ziggurat
re-implemented, the same sums in the same order) and gives the same numbers, about 4x faster: bit for bit
where numpy's ``exp`` and ``log`` are the C library's, to rounding where numpy has SIMD code of its own
(AVX-512; relative 1e-12 is tested, :func:`adaptfilt.particle_kernels.exp_log_agree` says which). Either way
:meth:`ParticleCountFilter.run` filters the runs in blocks of about ``block_particles`` particles, so that
the arrays of a step stay in cache; a run's numbers do not depend on its block.

:func:`kld_bound` is Fox's (2003) sample size for ``k`` occupied bins, and :func:`kld_count` the
KLD-sampling count of a set of drawn particles.

Example
-------
>>> import numpy as np, adaptfilt as af
>>> from adaptfilt.particles import ParticleCountFilter
>>> model = af.models.ungm()
>>> traj = model.simulate(n_runs=3, n_steps=20, rng=0)
>>> pf = ParticleCountFilter(model, seed=0)
>>> run = pf.run(traj.z, n_particles=[100, 500, 2000])      # one count per run (or (M, T))
>>> run.mean.shape, run.params[:, 0].tolist()
((3, 20, 1), [100.0, 500.0, 2000.0])
>>> alone = pf.run(traj.z[1:2], n_particles=500, run_ids=[1])
>>> bool(np.array_equal(alone.mean[0], run.mean[1]))
True
"""
from __future__ import annotations

import numbers
import os
from typing import Sequence

import numpy as np

from adaptfilt.filters import FilterRun
from adaptfilt.models import StateSpaceModel

__all__ = ["ParticleCountFilter", "ParticleMemoryError", "kld_bound", "kld_count", "kld_counts", "BACKENDS"]

#: how :class:`ParticleCountFilter` computes: numpy (the reference, a Python loop over runs) or
#: numba's compiled kernels (:mod:`adaptfilt.particle_kernels`, the optional extra ``fast``), the same
#: numbers (to rounding on a CPU where numpy's exp has code of its own); "auto" takes numba where installed.
BACKENDS = ("auto", "numpy", "numba")


class ParticleMemoryError(MemoryError, ValueError):
    """A particle count whose arrays cannot fit in this machine's memory, refused before anything is allocated.

    A ``MemoryError``, as numpy's own refusal (later, after the smaller arrays, naming a shape, not the
    count) would have been, and a ``ValueError``: the input is what is wrong, and the command line reports
    it as one. ``count`` is the largest count asked for, ``needed`` and ``available`` are bytes."""

    def __init__(self, message: str, count: int, needed: int, available: int):
        super().__init__(message)
        self.count, self.needed, self.available = int(count), int(needed), int(available)


def _memory_bytes() -> tuple[int, str]:
    """The memory a request is held against and its name in an error: the machine's physical memory, or,
    where the system does not say, the 256 TiB a 64-bit process can address (only the absurd is refused)."""
    try:
        pages, size = os.sysconf("SC_PHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):  # no sysconf (Windows), or no such name
        pages = size = -1
    if pages > 0 and size > 0:
        return pages * size, "this machine's {} of memory"
    return 2**48, "the {} a 64-bit process can address"


def _size(n_bytes: float) -> str:
    """``n_bytes`` in binary units, three figures: ``7.28 TiB``."""
    if n_bytes < 1024:
        return f"{n_bytes:.0f} B"
    for unit in ("KiB", "MiB", "GiB", "TiB"):
        n_bytes /= 1024
        if n_bytes < 1024:
            return f"{n_bytes:.3g} {unit}"
    return f"{n_bytes / 1024:.3g} PiB"


def _check_kld_params(epsilon: float, delta: float) -> None:
    if not (np.isfinite(epsilon) and epsilon > 0):
        raise ValueError(f"epsilon must be finite and > 0, got {epsilon}")
    if not 0 < delta < 1:  # NaN fails this too
        raise ValueError(f"delta must be in (0, 1), got {delta}")


def _check_count_arg(name: str, value) -> int:
    try:
        ok = not isinstance(value, (bool, np.bool_)) and int(value) == value and value >= 1
    except (TypeError, ValueError, OverflowError):  # NaN, inf, a string
        ok = False
    if not ok:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def _cells(x: np.ndarray, bin_size, axes: tuple[str, ...]) -> np.ndarray:
    """The bin of every particle of ``x (..., n, nx)``, int64 ``x``'s shape; ValueError naming a bad ``x``
    (``axes`` names its axes but the last) or ``bin_size`` (a scalar or one per dimension, finite and > 0)."""
    nx = x.shape[-1]
    if x.shape[-2] < 1 or nx < 1:
        raise ValueError(f"x must hold at least one particle of at least one dimension, got shape {x.shape}")
    b = np.asarray(bin_size, dtype=float)
    if b.shape not in ((), (nx,)):
        raise ValueError(f"bin_size must be a scalar or one per state dimension ({nx},), got shape {b.shape}")
    if not (np.isfinite(b).all() and (b > 0).all()):
        raise ValueError(f"bin_size must be finite and > 0, got {b.tolist()}")
    finite = np.isfinite(x)
    if not finite.all():
        bad = np.argwhere(~finite)[0]
        where = ", ".join(f"{name} {int(i)}" for name, i in zip(axes, bad))
        raise ValueError(f"x has non-finite values (first at {where})")
    q = np.floor(x / b)
    # a bin index beyond int64 would wrap: far-apart particles would share a bin
    if np.abs(q).max() >= 2.0**63:
        raise ValueError(f"bin_size {b.tolist()} is too small for x: x / bin_size reaches {np.abs(q).max():.3g}, "
                         f"beyond the 2**63 bins that can be told apart")
    return q.astype(np.int64)


def kld_bound(k: np.ndarray | int, epsilon: float = 0.05, delta: float = 0.01) -> np.ndarray:
    r"""Fox's (2003) KLD-sampling bound: the number of particles that keeps the Kullback-Leibler
    divergence between the sample-based and the true (binned) posterior below ``epsilon`` with
    probability ``1 - delta``, when the particles occupy ``k`` bins,

    .. math::
        n = \frac{k-1}{2\epsilon}\left(1 - \frac{2}{9(k-1)} + \sqrt{\frac{2}{9(k-1)}}\, z_{1-\delta}\right)^3,

    the Wilson-Hilferty approximation of :math:`\chi^2_{k-1,1-\delta}/(2\epsilon)`. ``k <= 1``
    gives 1 (one bin: any one particle describes it).

    >>> from scipy import stats
    >>> round(float(kld_bound(10)), 1), round(float(stats.chi2.ppf(0.99, 9) / 0.1), 1)
    (217.0, 216.7)
    """
    _check_kld_params(epsilon, delta)
    k = np.asarray(k, dtype=float)
    km1 = np.maximum(k - 1.0, 1.0)
    a = 2.0 / (9.0 * km1)
    from scipy import stats  # on first use (the library's import time)

    n = km1 / (2.0 * epsilon) * (1.0 - a + np.sqrt(a) * stats.norm.ppf(1.0 - delta)) ** 3
    return np.where(k > 1, n, 1.0)


def kld_count(x: np.ndarray, bin_size: float | np.ndarray, epsilon: float = 0.05, delta: float = 0.01,
              n_min: int = 1, n_max: int | None = None) -> int:
    """KLD-sampling's stopping rule on particles ``x (n, nx)`` in the order they were drawn: the
    smallest ``n >= n_min`` with ``n >= kld_bound(k(n))``, ``k(n)`` the bins of width ``bin_size``
    (a scalar or one per dimension) that the first ``n`` occupy; ``n_max`` (default ``len(x)``) if never met.
    ValueError naming a bad ``x`` (its shape, a non-finite particle), ``bin_size`` (not finite and > 0, or
    not one per dimension), ``epsilon``, ``delta``, ``n_min`` or ``n_max`` (integers >= 1)."""
    _check_kld_params(epsilon, delta)
    n_min = _check_count_arg("n_min", n_min)
    x = np.atleast_2d(np.asarray(x, dtype=float))
    if x.ndim != 2:
        raise ValueError(f"x must be (n, nx), got shape {x.shape}")
    n_max = len(x) if n_max is None else min(_check_count_arg("n_max", n_max), len(x))
    cells = _cells(x[:n_max], bin_size, ("particle",))
    _, first = np.unique(cells, axis=0, return_index=True)
    new = np.zeros(n_max, dtype=int)
    new[first] = 1
    k = np.cumsum(new)  # bins occupied by the first n particles, n = 1..n_max
    n = np.arange(1, n_max + 1)
    ok = (n >= n_min) & (n >= kld_bound(k, epsilon, delta))
    return int(n[ok.argmax()]) if ok.any() else n_max


def kld_counts(x: np.ndarray, bin_size: float | np.ndarray, epsilon: float = 0.05, delta: float = 0.01,
               n_min: int = 1) -> np.ndarray:
    """:func:`kld_count` of every run of ``x (M, n, nx)`` at once, ``(M,)`` (``n_max = n``): the bins of
    each run are told apart by sorting its cells, not by a set, so that a batch costs one sort. ValueError
    as :func:`kld_count`'s."""
    _check_kld_params(epsilon, delta)
    n_min = _check_count_arg("n_min", n_min)
    x = np.asarray(x, dtype=float)
    if x.ndim != 3:
        raise ValueError(f"x must be (M, n, nx), got shape {x.shape}")
    M, n, nx = x.shape
    cells = _cells(x, bin_size, ("run", "particle"))
    # one key per cell (mixing the dimensions; a collision of two cells in one run is ~n^2 / 2^64)
    key = cells[..., 0].astype(np.uint64)
    for i in range(1, nx):
        key = key * np.uint64(0x9E3779B97F4A7C15) + cells[..., i].astype(np.uint64)
    order = np.argsort(key, axis=1, kind="stable")  # equal cells keep their draw order: the first comes first
    ks = np.take_along_axis(key, order, axis=1)
    start = np.ones((M, n), dtype=bool)
    start[:, 1:] = ks[:, 1:] != ks[:, :-1]
    new = np.zeros((M, n), dtype=np.int64)
    np.put_along_axis(new, order, start.astype(np.int64), axis=1)
    k = np.cumsum(new, axis=1)  # bins occupied by the first j particles
    j = np.arange(1, n + 1)[None, :]
    ok = (j >= n_min) & (j >= kld_bound(k, epsilon, delta))
    return np.where(ok.any(axis=1), ok.argmax(axis=1) + 1, n)


def _buffer(work: dict | None, key: str, shape: tuple) -> np.ndarray:
    """An uninitialised array of ``shape``: a fresh one, or with ``work`` the front of ``work[key]``
    (grown when too small)."""
    if work is None:
        return np.empty(shape)
    size = int(np.prod(shape))
    if key not in work or work[key].size < size:
        work[key] = np.empty(size)
    return work[key][:size].reshape(shape)


def _sum(a: np.ndarray) -> np.ndarray:
    """Sum over particles (axis 1) in order: unlike numpy's pairwise ``sum``, the result does not
    depend on how many zero-weight padding particles follow, so a run gives the same bits in a
    batch (padded to the batch's largest count) as alone."""
    return np.cumsum(a, axis=1)[:, -1]


class ParticleCountFilter:
    r"""Bootstrap particle filter with a particle count per run and step (see the module docstring).

    ``run(z, n_particles)`` filters ``z (M, T, nz)`` with ``n_particles`` a scalar, ``(M,)`` or
    ``(M, T)`` integers >= 1; ``params`` of the result holds the counts used, ``info["ess"]`` the
    effective sample size :math:`1/\sum_j (w^{(j)})^2` after each update, ``loglik`` the log of
    :math:`\hat p(\mathbf z_k \mid \mathbf z^{k-1})`. ``nis`` is NaN (not defined for a particle cloud).

    When the weights collapse onto one point (few particles, an informative measurement) the
    weighted covariance is singular: the cloud claims certainty. ``info["on_indefinite"] = "inf"``
    tells :func:`~adaptfilt.evaluation.evaluate` to read that as an infinite NEES (a diverged run).

    For models with additive Gaussian noise. ``seed``: an int; the same seed and ``run_ids``, the
    same numbers, whatever the ``backend`` ("auto", "numpy" or "numba", see the module docstring) and
    ``block_particles``. Compute grows with the total number of particles, ``params.sum()``.
    """

    #: what ``run(z, n_particles).params`` holds (:class:`~adaptfilt.filters.Filter`, at a given count)
    param_name = "n_particles"

    def __init__(self, model: StateSpaceModel, seed: int = 0, backend: str = "auto", block_particles: int = 1 << 16):
        if int(seed) != seed or seed < 0:
            raise ValueError(f"seed must be a non-negative integer (it keys the random streams), got {seed!r}")
        if int(block_particles) != block_particles or block_particles < 1:
            raise ValueError(f"block_particles must be a positive integer, got {block_particles!r}")
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        from adaptfilt import particle_kernels  # here: numba loads with the first particle filter, not with adaptfilt

        if backend == "numba" and not particle_kernels.AVAILABLE:
            raise ImportError("backend='numba' needs numba: pip install 'adaptfilt[fast]'")
        self.model, self.seed = model, int(seed)
        #: particles (times nx) per block of runs that :meth:`run` filters at once (at least one run a block);
        #: 2**16 keeps a step's arrays (0.5 MB each) in a core's cache
        self.block_particles = int(block_particles)
        #: "numba" (compiled kernels) where numba is installed, else "numpy": the same numbers either way
        self.backend = ("numba" if particle_kernels.AVAILABLE else "numpy") if backend == "auto" else backend
        self._Lq, self._L0 = np.linalg.cholesky(model.Q), np.linalg.cholesky(model.P0)
        self._Rinv = np.linalg.inv(model.R)
        self._logdetR = float(np.linalg.slogdet(model.R)[1])

    def __repr__(self) -> str:
        return f"ParticleCountFilter(model={self.model.name!r}, seed={self.seed})"

    def _rngs(self, run_id: int, t: int) -> tuple[np.random.Generator, np.random.Generator]:
        # two streams, so that particle j's ancestor uniform and its noise are the j-th draws of
        # their own stream whatever the count (one stream would shift the noise by N uniforms).
        # Philox is counter-based: key (seed, run), counter (0, t, stream, 0) address a stream directly.
        # A draw advances the counter's lowest word, so t and the stream sit above it: with t in the lowest
        # word, step t + 1's stream would be step t's shifted by one block of four draws.
        # Two generators are kept and re-pointed by assigning their state, 5x cheaper than opening
        # new ones (one pair per run and step); the draws are the same as from fresh generators.
        if not hasattr(self, "_streams"):
            self._streams = [np.random.Generator(np.random.Philox(key=[0, 0])) for _ in range(2)]
        for stream, g in enumerate(self._streams):
            st = g.bit_generator.state
            st["state"]["counter"][:] = (0, t, stream, 0)
            st["state"]["key"][:] = (self.seed, int(run_id))
            st["buffer_pos"], st["has_uint32"], st["uinteger"] = 4, 0, 0  # an empty buffer: a fresh stream
            g.bit_generator.state = st
        return self._streams[0], self._streams[1]

    def _counts(self, n_particles, M: int, T: int) -> np.ndarray:
        """``n_particles`` as ``(M, T)`` floats, checked to be integers >= 1 (float: a count too large for
        int64 must reach the memory check, not wrap)."""
        n = np.array(n_particles, dtype=float)  # a copy: it becomes the result's params
        if n.ndim == 0:
            n = np.full((M, T), n)
        elif n.shape == (M,):
            n = np.repeat(n[:, None], T, axis=1)
        elif n.shape != (M, T):
            raise ValueError(f"n_particles must be a scalar, (M,) = ({M},) or (M, T) = ({M}, {T}), got shape {n.shape}")
        if not np.all(np.isfinite(n)) or np.any(n < 1) or np.any(n != np.round(n)):
            raise ValueError(f"n_particles must be integers >= 1, got values in [{n.min():g}, {n.max():g}]")
        return n

    @staticmethod
    def _run_ids(run_ids, M: int) -> np.ndarray:
        """``run_ids`` checked: one non-negative integer below 2**64 per run (a Philox key word); int64,
        or uint64 where an id needs it."""
        if run_ids is None:
            return np.arange(M, dtype=np.int64)
        a = np.asarray(run_ids, dtype=object)  # the ids as given: no float rounds an integer near 2**64
        if a.shape != (M,):
            raise ValueError(f"run_ids must name one id per run ({M}), got shape {a.shape}")
        values = a.tolist()
        for i, v in enumerate(values):
            # a bool is refused: a mask passed as ids would silently key every run 0 or 1
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real) or not 0 <= v < 2**64 or v != int(v):
                raise ValueError(f"run_ids must be integers in [0, 2**64) (they key the random streams), "
                                 f"got {v!r} for run {i}")
        return np.array([int(v) for v in values], dtype=np.int64 if max(values, default=0) < 2**63 else np.uint64)

    def particle_bytes(self, n_particles: int, n_runs: int = 1) -> int:
        """About the peak bytes of one step's arrays for ``n_runs`` runs of ``n_particles`` each, filtered at
        once: per particle, measured (peak resident memory) on UNGM and the CTM, the state copies (predicted,
        ancestors, noise, ``f``'s output), ``h``'s output and the residual, weights and log-likelihoods, the
        resampling's work arrays, and in the numpy backend the ``(nx, nx)`` outer products of the covariance."""
        nx, nz = self.model.nx, self.model.nz
        words = 4 * nx + 2 * nz + 7 if self.backend == "numba" else 9 * nx + 2 * nx * nx + 2 * nz + 2
        return 8 * words * int(n_particles) * int(n_runs)

    def check_memory(self, n_particles: int, n_runs: int = 1, result_bytes: int = 0, label: str | None = None) -> None:
        """Refuse, with a :class:`ParticleMemoryError` naming the count and the bytes, ``n_runs`` runs of
        ``n_particles`` particles filtered at once (:meth:`particle_bytes`) plus ``result_bytes`` of results
        beyond this machine's memory; nothing is allocated."""
        particles = self.particle_bytes(n_particles, n_runs)
        need = particles + int(result_bytes)
        available, where = _memory_bytes()
        if need <= available:
            return
        arrays = "one run's particle arrays" if n_runs == 1 else f"the particle arrays of {n_runs} runs at once"
        if result_bytes:
            arrays = f"{_size(need)} ({_size(particles)} for {arrays}, {_size(result_bytes)} for the results)"
        else:
            arrays = f"{_size(need)} for {arrays}"
        raise ParticleMemoryError(f"{label or f'n_particles = {int(n_particles)}'} needs about {arrays}, "
                                  f"more than {where.format(_size(available))}", n_particles, need, available)

    def predict(self, x_old: np.ndarray | None, w_old: np.ndarray | None, n_old: np.ndarray | None, t: int,
                n: np.ndarray, ids: np.ndarray, work: dict | None = None) -> np.ndarray:
        """The ``n[i]`` predicted particles of run ``i`` at step ``t``, ``(M, max n, nx)`` (zeros beyond
        ``n[i]``): drawn from the prior at ``t = 0``, else resampled from the weighted ``x_old (M, ., nx)``
        (``w_old``, ``n_old`` particles each) and propagated. Particle ``j`` is the same whatever ``n[i] > j``.
        ``work``: buffers the compiled backend reuses from step to step (:meth:`run`'s); the result is then
        one of them, overwritten by the next call."""
        model, nx, M = self.model, self.model.nx, len(n)
        cap = int(n.max())
        if self.backend == "numba":
            noise = _buffer(work, "noise", (M, cap, nx))
            x_anc = _buffer(work, "x_anc", (M, cap, nx)) if t else noise
            from adaptfilt import particle_kernels

            particle_kernels.predict_particles(self.seed, ids, t, n, nx, x_old if t else noise,
                                               w_old if t else np.zeros((M, 1)), n_old if t else n, x_anc, noise)
            scaled = self._scale(noise, self._L0 if t == 0 else self._Lq, inplace=True)
            # x_old was read above: the new particles may take its place
            return np.add(model.m0 if t == 0 else model.f(x_anc, t), scaled, out=_buffer(work, "x", (M, cap, nx)))
        noise = np.zeros((M, cap, nx))
        anc = np.zeros((M, cap), dtype=np.int64)
        if t:
            cdf = np.cumsum(w_old, axis=1)
        for i in range(M):  # each run's own streams: its draws do not depend on the other runs' counts
            gu, gw = self._rngs(ids[i], t)
            u = gu.random(n[i])
            noise[i, :n[i]] = gw.standard_normal((n[i], nx))
            if t:  # multinomial resampling: particle j's ancestor is where its uniform falls in the cdf
                c = cdf[i, :n_old[i]]
                anc[i, :n[i]] = np.minimum(np.searchsorted(c, u * c[-1], side="right"), n_old[i] - 1)
        if t == 0:
            return model.m0 + self._scale(noise, self._L0)
        return model.f(np.take_along_axis(x_old, anc[..., None], axis=1), t) + self._scale(noise, self._Lq)

    @staticmethod
    def _scale(noise: np.ndarray, L: np.ndarray, inplace: bool = False) -> np.ndarray:
        """``noise @ L.T``; in 1-D the same single product without matmul's per-row overhead."""
        if L.shape == (1, 1):
            return np.multiply(noise, L[0, 0], out=noise if inplace else None)
        return noise @ L.T

    def loglik_particles(self, x: np.ndarray, z_t: np.ndarray, t: int, work: dict | None = None) -> np.ndarray:
        """``log N(z_t - h(x_j); 0, R)`` of every particle ``x (M, N, nx)``, ``z_t (M, nz)``: ``(M, N)``
        (``work``: as in :meth:`predict`)."""
        model = self.model
        r = model.diff_z(z_t[:, None, :], model.h(x, t + 1))
        const = model.nz * np.log(2 * np.pi)
        if self.backend == "numba":
            out = _buffer(work, "logl", x.shape[:2])
            from adaptfilt import particle_kernels

            particle_kernels.gaussian_loglik(r, self._Rinv, self._logdetR, const, out)
            return out
        quad = 0.0  # r' R^-1 r term by term, in the order the kernel sums it (einsum's, in 1-D)
        for i in range(model.nz):
            for j in range(model.nz):
                term = (r[..., i] * self._Rinv[i, j]) * r[..., j]
                quad = term if i == j == 0 else quad + term
        return -0.5 * ((quad + self._logdetR) + const)

    def weigh(self, x: np.ndarray, n: np.ndarray, z_t: np.ndarray, t: int, ids: np.ndarray,
              logl: np.ndarray | None = None, work: dict | None = None) -> dict:
        """Weight the first ``n[i]`` particles of ``x (M, cap, nx)`` by ``z_t (M, nz)``: a dict of ``w (M, cap)``
        (zero beyond ``n``), ``mean (M, nx)``, ``cov (M, nx, nx)``, ``loglik (M,)`` (log p-hat(z_t | z^{t-1}))
        and ``ess (M,)``. FloatingPointError naming the step and runs where no particle explains ``z_t``.
        ``logl``: :meth:`loglik_particles` of these particles, when the caller has it already; ``work``: as in
        :meth:`predict` (``w`` is then a buffer, overwritten by the next call)."""
        if self.backend == "numba":
            logl = self.loglik_particles(x, z_t, t, work) if logl is None else logl
            M, cap, nx = x.shape
            out = {"w": _buffer(work, "w", (M, cap)), "mean": np.empty((M, nx)), "cov": np.empty((M, nx, nx)),
                   "loglik": np.empty(M), "ess": np.empty(M)}
            amax = np.empty(M)
            from adaptfilt import particle_kernels

            particle_kernels.weigh_particles(logl, n, x, out["w"], out["mean"], out["cov"], out["loglik"], out["ess"],
                                             amax)
            self._check_explained(amax, t, ids)
            return out
        valid = np.arange(x.shape[1])[None, :] < n[:, None]
        logl = np.where(valid, self.loglik_particles(x, z_t, t) if logl is None else logl, -np.inf)
        amax = logl.max(axis=1, keepdims=True)
        self._check_explained(amax[:, 0], t, ids)
        e = np.exp(logl - amax)
        s = _sum(e)
        w = e / s[:, None]
        mean = _sum(w[..., None] * x)
        d = x - mean[:, None, :]
        cov = _sum(w[..., None, None] * d[..., :, None] * d[..., None, :])
        return {"w": w, "mean": mean, "cov": cov, "loglik": np.log(s) + amax[:, 0] - np.log(n),
                "ess": 1.0 / _sum(w * w)}

    @staticmethod
    def _check_explained(amax: np.ndarray, t: int, ids: np.ndarray) -> None:
        if not np.isfinite(amax).all():
            bad = np.flatnonzero(~np.isfinite(amax))
            raise FloatingPointError(f"particle filter: no particle explains the measurement at step t={t} in runs "
                                     f"{ids[bad[:10]].tolist()}: use more particles")

    def check_z(self, z) -> np.ndarray:
        """``z`` as ``(M, T, nz)`` floats; ValueError naming a wrong shape or a non-finite value."""
        z = np.asarray(z, dtype=float)
        if z.ndim == 2 and self.model.nz == 1:
            z = z[..., None]
        if z.ndim != 3 or z.shape[2] != self.model.nz:
            raise ValueError(f"z must have shape (M, T, {self.model.nz}), got {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ValueError("z holds non-finite values")
        return z

    def run(self, z, n_particles, run_ids: Sequence[int] | None = None) -> FilterRun:
        """Filter ``z (M, T, nz)`` (or ``(M, T)`` when ``nz = 1``) with ``n_particles`` (a scalar, ``(M,)`` or
        ``(M, T)`` integers >= 1); run ``i`` draws from the streams of ``run_ids[i]`` (default ``i``; integers
        in ``[0, 2**64)``).

        ValueError naming a bad ``z``, ``n_particles`` or ``run_ids``; :class:`ParticleMemoryError` (a
        ``MemoryError`` and a ``ValueError``) naming the count and the bytes when the particle arrays of a
        block of runs and the results would not fit in this machine's memory, before they are allocated."""
        z = self.check_z(z)
        M, T, _ = z.shape
        if M < 1 or T < 1:
            raise ValueError(f"z must hold at least one run and one step, got shape {z.shape}")
        counts = self._counts(n_particles, M, T)
        ids = self._run_ids(run_ids, M)
        nx = self.model.nx
        cap = int(counts.max())
        block = min(M, max(1, self.block_particles // (cap * nx)))
        label = f"n_particles = {cap}" if counts.min() == cap else f"n_particles up to {cap}"
        # mean, cov, loglik, ess, nis, params: (M, T) floats each, times nx and nx * nx for mean and cov
        self.check_memory(cap, block, 8 * M * T * (nx + nx * nx + 4), label)
        params, counts = counts, counts.astype(np.int64)
        mean, cov = np.empty((M, T, nx)), np.empty((M, T, nx, nx))
        ll, ess = np.empty((M, T)), np.empty((M, T))
        # Runs are independent (each draws from its own streams), so they are filtered a block at a time:
        # a block's particle arrays stay in cache and its buffers are reused, where fresh whole-batch
        # temporaries would cost a page fault per 4 KiB. The numbers are those of one batch, bit for bit.
        for lo in range(0, M, block):
            b = slice(lo, min(lo + block, M))
            x_old = w_old = None
            work = {}  # the compiled backend's buffers, reused from step to step
            for t in range(T):
                n = counts[b, t]
                x = self.predict(x_old, w_old, counts[b, t - 1] if t else None, t, n, ids[b], work)
                post = self.weigh(x, n, z[b, t], t, ids[b], work=work)
                mean[b, t], cov[b, t], ll[b, t], ess[b, t] = post["mean"], post["cov"], post["loglik"], post["ess"]
                x_old, w_old = x, post["w"]
        return FilterRun(mean=mean, cov=cov, nis=np.full((M, T), np.nan), loglik=ll,
                         params=params, info={"ess": ess, "particles": int(counts.sum()),
                                                                "on_indefinite": "inf"})
