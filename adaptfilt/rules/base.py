r"""The moment rules' common part: :class:`Moments` (what a rule returns), :class:`MomentRule` (the
fully symmetric rule: a centre and pairs of points ``m +- L a_k``, the centred weighted sums) and the
helpers that evaluate a point set on a subset of runs or in tiles. The equations are in
:mod:`adaptfilt.rules`.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from adaptfilt.linalg import chol, mm, sym, sym_fresh
import adaptfilt.rules.scalar_kernels as _scalar
import adaptfilt.rules._sif_kernels as _kernels

__all__ = ["Moments", "MomentRule"]

#: ``g`` maps points ``(n, S, M)`` to values ``(ng, S, M)`` (run axis last).
BatchFn = Callable[[np.ndarray], np.ndarray]
Residual = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class Moments:
    """Moments of ``g(x)``, run axis last: ``mean (ng, M)``, ``cov (ng, ng, M)``, ``cross (n, ng, M)``.

    Stochastic rules also report ``n_iter (M,)``, the iterations (draws) each
    run spent, and, when asked for the integration-error term, ``mean_var
    (ng, ng, M)``: the estimated variance of the stochastic estimate ``mean``,
    which a filter adds to the predicted covariance. ``None`` otherwise.
    """

    mean: np.ndarray
    cov: np.ndarray
    cross: np.ndarray | None
    mean_var: np.ndarray | None = None
    n_iter: np.ndarray | None = None


@dataclass
class _PointSet:
    """The points ``m +- A[:, k]``, ``A = L @ rotation * scale``, with weight ``weight``.

    ``rotation (n, K, M)`` (None: identity), ``scale`` and ``weight`` a
    scalar or ``(M,)``. ``runs``: the set was made for these runs only (indices into the run axis,
    ``M`` of them; None: for all runs); the sums are then computed for them alone.
    With ``groups``, the directions are instead ``L @ rotation @ basis[:, cols]
    * radius`` with weight ``w`` for each ``(cols, radius, w)`` of ``groups``
    (``basis (n, B)``, ``radius``, ``w`` ``(M,)``): each basis column is rotated
    once, however many groups use it.
    """

    scale: np.ndarray | float
    rotation: np.ndarray | None
    weight: np.ndarray | float
    basis: np.ndarray | None = None
    groups: list | None = None
    runs: np.ndarray | None = None


def _weighted_sums(g: BatchFn, m, g0, L, ps: _PointSet, residual: Residual | None, cross: bool, work: dict | None = None):
    """``sum_i w_i D_i``, ``sum_i w_i D_i D_i^T`` and ``sum_i w_i (X_i - m) D_i^T`` of one point set
    ``work`` keeps buffers between calls. With ``ps.runs``
    the sums are those of the runs ``ps.runs``, in that order."""
    if ps.runs is not None:
        m, g0, L = (_take_runs(a, ps.runs) for a in (m, g0, L))
    if ps.groups is None:
        made = _kernels.points(m, L, ps.rotation, ps.scale, work)  # compiled, numpy's bits; None: numpy's form
        if made is not None:
            return _pair_sums_made(g, g0, *made, ps.weight, residual, cross, work)
    A = L if ps.rotation is None else mm(L, ps.rotation)
    if ps.groups is None:
        return _pair_sums(g, m, g0, A * ps.scale, ps.weight, residual, cross)
    # rotate the basis once (BLAS: basis^T @ (L Q)[i] per row i), then one group at a time: small
    # temporaries, reused, cost far less first-touch paging than one large array of all points
    n, M = m.shape
    B = np.empty((n, ps.basis.shape[1], M))
    for i in range(n):
        np.matmul(ps.basis.T, A[i], out=B[i])
    sums = None
    for cols, radius, w in ps.groups:
        part = _pair_sums_lean(g, m, g0, B[:, cols] * radius, w, residual, cross, {} if work is None else work)
        sums = part if sums is None else [a if b is None else a + b for a, b in zip(sums, part)]
    return tuple(sums)


def _pair_sums_lean(g, m, g0, A, w, residual, cross, work: dict):
    """:func:`_pair_sums` with fewer temporaries (``X`` in a reused buffer, no ``dX``;
    ``Cov[x, g]`` from ``w (D+ - D-)``); ``w`` a scalar or ``(M,)``."""
    K = A.shape[1]
    X = work.get(K)
    if X is None or X.shape[2] != A.shape[2]:  # one buffer per group size, for the latest run count
        X = work[K] = np.empty((A.shape[0], 2 * K, A.shape[2]))
    np.add(m[:, None, :], A, out=X[:, :K])
    np.subtract(m[:, None, :], A, out=X[:, K:])
    G = g(X)
    D = _deviations(G, g0) if residual is None else np.ascontiguousarray(residual(G, g0[:, None, :]))
    Dp, Dm = D[:, :K], D[:, K:]
    wDp, wDm = Dp * w, Dm * w
    ED = (wDp + wDm).sum(axis=1)
    EDD = np.einsum("isM,jsM->ijM", wDp, Dp) + np.einsum("isM,jsM->ijM", wDm, Dm)
    EXD = np.einsum("isM,jsM->ijM", A, wDp - wDm) if cross else None
    return ED, EDD, EXD


def _pair_sums(g, m, g0, A, weight, residual, cross):
    """The sums over the points ``m +- A[:, k]`` with weights ``weight[k]`` (scalar, ``(M,)`` or ``(K, M)``)."""
    K = A.shape[1]
    mc = m[:, None, :]
    shape = A.shape[:1] + (2 * K,) + A.shape[2:]
    if not cross and m.dtype == A.dtype and mc.shape[2:] == A.shape[2:]:
        # the points without dX (n, 2K, M): m - a is m + (-a), bit for bit
        X = np.empty(shape, dtype=A.dtype)
        np.add(mc, A, out=X[:, :K])
        np.subtract(mc, A, out=X[:, K:])
    else:  # dX = [A, -A], kept for Cov[x, g]
        dX = np.empty(shape, dtype=A.dtype)
        dX[:, :K] = A
        np.negative(A, out=dX[:, K:])
        X = mc + dX
    G = g(X)
    # A model function returns (..., ng) with ng fastest; moved to run-last its runs are strided, which
    # makes the einsums below ~6x slower, and G - g0 keeps G's layout: the difference is written into a
    # C-ordered array instead (the same subtractions; no second pass to copy it)
    D = _deviations(G, g0) if residual is None else np.ascontiguousarray(residual(G, g0[:, None, :]))
    return _sums_numpy(D, dX if cross else None, weight)


def _deviations(G: np.ndarray, g0: np.ndarray) -> np.ndarray:
    """``G - g0[:, None, :]`` in C order whatever ``G``'s layout (``np.ascontiguousarray`` of it, bit
    for bit, in one pass)."""
    if G.ndim == 3 and G.dtype == g0.dtype == np.float64 and G.shape[::2] == g0.shape:
        out = np.empty(G.shape)  # the common case, without broadcast_shapes' Python (a tenth of a scalar step)
    else:
        out = np.empty(np.broadcast_shapes(G.shape, g0[:, None, :].shape), dtype=np.result_type(G, g0))
    return np.subtract(G, g0[:, None, :], out=out)


def _sums_numpy(D, dX, weight):
    """The sums of :func:`_pair_sums` from the contiguous deviations ``D (ng, 2K, M)`` and the
    directions ``dX = [A, -A]`` (None: no cross sums)."""
    w = weight
    if getattr(w, "ndim", 0) == 2:  # one weight per direction and run: the same for +a_k and -a_k
        w = np.concatenate([w, w], axis=0)
    wD = D * w
    ED = wD.sum(axis=1)
    EDD = np.einsum("isM,jsM->ijM", wD, D)
    EXD = np.einsum("isM,jsM->ijM", dX, wD) if dX is not None else None
    return ED, EDD, EXD


def _pair_sums_made(g, g0, X, A, weight, residual, cross, work: dict | None = None):
    """:func:`_pair_sums` from the points ``X = [m + A, m - A]`` the compiled kernel made, its sums
    compiled too where they apply (:mod:`adaptfilt.rules._sif_kernels`: numpy's bits). ``X`` and ``A``
    may be buffers of ``work`` (reused by the next point set): what is returned is fresh."""
    G = g(X)
    D = G - g0[:, None, :] if residual is None else residual(G, g0[:, None, :])
    sums = _kernels.weighted_sums(D, A, weight, cross, work)
    if sums is None:
        sums = _sums_numpy(np.ascontiguousarray(D), np.concatenate([A, -A], axis=1) if cross else None, weight)
    return sums


def _active_runs(active: np.ndarray) -> np.ndarray:
    """The indices of the active runs; a single run is named twice (its sums are then computed
    on two identical columns, as in a full batch: numpy drops a length-1 run axis and would
    sum the points in another order, changing the last bits)."""
    idx = np.flatnonzero(active)
    return np.repeat(idx, 2) if idx.size == 1 else idx


def _take_runs(a: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """``a[..., runs]``, C-contiguous: numpy's reductions and einsum sum in the same order
    as on the whole batch only on the same layout, and the subset must match it bit for bit."""
    return np.ascontiguousarray(a[..., runs])


def _scatter(a: np.ndarray, runs: np.ndarray, M: int) -> np.ndarray:
    """``a (..., len(runs))`` placed at ``runs`` of a zero ``(..., M)`` array."""
    out = np.zeros(a.shape[:-1] + (M,))
    out[..., runs] = a
    return out


def _check_tile(tile, M: int) -> int:
    if type(tile) is int and tile == 1:  # the common case, without numpy's checks
        return 1
    t = int(tile) if np.ndim(tile) == 0 and float(tile) == int(tile) else -1
    if t < 1:
        raise ValueError(f"tile must be a positive integer, got {tile!r}")
    if M % t:
        raise ValueError(f"tile = {t} must divide the number of runs M = {M}")
    return t


class MomentRule(ABC):
    """A rule for the Gaussian moments of a function, with one scalar parameter.

    Deterministic subclasses say how their point sets are drawn
    (:meth:`_point_sets`); the moment arithmetic is shared. ``param`` may be a
    scalar or one value per run ``(M,)``.
    """

    #: name of the parameter, as in the paper ("kappa", "n_iter")
    param_name: str = "param"
    #: whether the rule draws random numbers (then ``moments`` needs ``rng``)
    stochastic: bool = False
    #: whether the rule offers ``moments_prefixes`` (the moments for several parameter values from one
    #: set of draws; see :meth:`StochasticIntegrationRule.moments_prefixes`)
    supports_prefixes: bool = False

    @abstractmethod
    def default_param(self, n: int) -> float:
        """The parameter a practitioner would use for state dimension ``n``."""

    @abstractmethod
    def check_param(self, param, n: int) -> np.ndarray:
        """Validated parameter as an array (scalar or ``(M,)``); ValueError if invalid."""

    def _point_sets(self, n: int, M: int, param: np.ndarray, rng: np.random.Generator | None) -> Iterator[_PointSet]:
        raise NotImplementedError

    def _cov_from_sums(self, EDD: np.ndarray, ED: np.ndarray, param: np.ndarray) -> np.ndarray:
        """``Cov[g]`` from the averaged centred sums (about the mean: ``EDD - ED ED^T``)."""
        return EDD - ED[:, None, :] * ED[None, :, :]

    def n_points(self, n: int, param) -> np.ndarray:
        """Number of function evaluations the rule spends (centre included)."""
        return 1 + 2 * n * np.ones_like(np.asarray(param, dtype=float))

    #: whether a scalar state's moments may come from the compiled kernels of one point set and the
    #: standard covariance (:mod:`adaptfilt.rules.scalar_kernels`): the rule's point set is one such set
    #: and :meth:`_cov_from_sums` the standard form
    _scalar_kernel: bool = False

    #: what :meth:`spent` counts: one moment computation of a deterministic rule is one ``"update"``
    compute_unit: str = "update"

    def spent(self, param) -> np.ndarray:
        """The compute one moment computation with ``param`` costs, in :attr:`compute_unit`.

        A deterministic rule costs one point set (one update) whatever its
        parameter: kappa moves the points, it does not add any. The stochastic
        integration rule counts iterations (its parameter), the unit of the
        paper's computational cost term ``c N_it``. This is what an evaluation
        charges a policy for what it computed to decide (candidates, features).
        """
        return np.ones_like(np.asarray(param, dtype=float))

    def moments(
        self,
        g: BatchFn,
        m: np.ndarray,
        P: np.ndarray,
        param,
        residual: Residual | None = None,
        rng: np.random.Generator | None = None,
        L: np.ndarray | None = None,
        cross: bool = True,
        tile: int = 1,
    ) -> Moments:
        """Moments of ``g(x)`` for ``x ~ N(m, P)``, ``m (n, M)``, ``P (n, n, M)``.

        ``L`` may pass a Cholesky factor of ``P`` that the caller already has.
        ``tile`` only matters for stochastic rules (see
        :meth:`StochasticIntegrationRule.moments`). Raises
        :class:`~adaptfilt.linalg.NotPositiveDefinite` when ``P`` is not
        positive definite.
        """
        n, M = m.shape
        param = self.check_param(param, n)
        _check_tile(tile, M)
        if L is None:
            L = chol(sym(P), "P")
        g0 = g(m[:, None, :])[:, 0, :]
        if n == 1 and residual is None and self._scalar_kernel:  # a scalar state: one compiled pass, numpy's bits
            ps = next(iter(self._point_sets(n, M, param, rng)))
            made = _scalar.moments(g, m, g0, L, ps.scale, ps.weight, cross)
            if made is not None:
                return Moments(mean=made[0], cov=made[1], cross=made[2])
        sums = None
        count = 0.0
        for ps in self._point_sets(n, M, param, rng):
            part = _weighted_sums(g, m, g0, L, ps, residual, cross)
            if sums is None and g0.dtype == part[0].dtype == part[1].dtype == np.float64 and (
                    part[2] is None or part[2].dtype == np.float64):
                # the first set's sums are fresh arrays: adding 0.0 in place is adding them to zeros
                # (it turns -0 into +0), without the zeros
                sums = [a if a is None else np.add(a, 0.0, out=a) for a in part]
            else:
                if sums is None:
                    sums = [np.zeros_like(g0), np.zeros((g0.shape[0], g0.shape[0], M)),
                            np.zeros((n, g0.shape[0], M)) if cross else None]
                for acc, a in zip(sums, part):
                    if acc is not None:
                        acc += a
            count = count + 1.0
        if sums is None:  # no point set: the zero sums over a zero count, as ever
            sums = [np.zeros_like(g0), np.zeros((g0.shape[0], g0.shape[0], M)),
                    np.zeros((n, g0.shape[0], M)) if cross else None]
        ED, EDD, EXD = sums
        if count != 1.0:  # x / 1 = x: one set (the unscented rule) needs no averaging
            ED /= count
            EDD /= count
            if cross:
                EXD /= count
        cov = self._cov_from_sums(EDD, ED, param)
        return Moments(mean=g0 + ED, cov=sym_fresh(cov), cross=EXD)


