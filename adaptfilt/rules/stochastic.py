r"""The stochastic integration rule (:class:`StochasticIntegrationRule`, parameter ``n_iter``): Genz and
Monahan's stochastic spherical-radial rules of degree 1, 3 or 5 as the stochastic integration filter
uses them, averaged over ``n_iter`` independent draws (random rotations :func:`haar_rotations`,
simplex points, the integration-error term, tolerance stopping, run subsets and tiles), and
:func:`stochastic_rule_points`, one draw's points and weights.
"""
from __future__ import annotations

from typing import Callable, Iterator, Literal

import numpy as np

from adaptfilt.linalg import chol, sym
from adaptfilt.rules._sif_kernels import gram_schmidt as _gram_schmidt_runs
import adaptfilt.rules._sif_kernels as _kernels
from adaptfilt.rules.base import (BatchFn, MomentRule, Moments, Residual, _active_runs, _check_tile, _PointSet, _sums_numpy,
                                  _take_runs, _weighted_sums)

__all__ = ["StochasticIntegrationRule", "haar_rotations", "stochastic_rule_points"]


def haar_rotations(n: int, M: int, rng: np.random.Generator) -> np.ndarray:
    """``M`` independent Haar-distributed orthogonal ``n x n`` matrices, ``(n, n, M)``.

    Gram-Schmidt on i.i.d. Gaussian columns, i.e. the Q of a QR factorisation
    with positive diagonal R, which is Haar distributed; vectorised over runs.
    """
    return _gram_schmidt(rng.standard_normal((n, n, M)))


def _gram_schmidt(G: np.ndarray, runs: np.ndarray | None = None) -> np.ndarray:
    """The Q factor (positive diagonal R) of each ``G[:, :, j]``, ``(n, n, M)``, for the runs ``runs`` (all
    when None): elementwise in the run axis, so a subset of runs gets bit for bit the columns the whole
    batch gets. Compiled where numba is installed, the same numbers (:mod:`adaptfilt.rules._sif_kernels`)."""
    return _gram_schmidt_runs(G, runs)


def _simplex(n: int) -> np.ndarray:
    """The ``n + 1`` unit vertices of a regular simplex centred at the origin, ``(n, n + 1)``
    (``v_i . v_j = -1/n``), built as in the authors' code."""
    V = np.zeros((n, n + 1))
    for i in range(n):
        V[i, i] = np.sqrt((n + 1) * (n - i) / (n * (n - i + 1)))
        V[i, i + 1 :] = -np.sqrt((n + 1) / ((n - i) * n * (n - i + 1)))
    return V


def _simplex_midpoints(V: np.ndarray) -> np.ndarray:
    """Normalised midpoints ``(v_i + v_j) / |v_i + v_j|`` of the simplex edges, ``i > j`` in
    row-major order (the authors' order), ``(n, n (n + 1) / 2)``."""
    i, j = np.tril_indices(V.shape[1], k=-1)
    Y = V[:, i] + V[:, j]
    return Y / np.linalg.norm(Y, axis=0)


_INTEGRATION_ERROR = {False: "none", None: "none", "none": "none", True: "diag", "diag": "diag", "full": "full"}


class StochasticIntegrationRule(MomentRule):
    r"""Stochastic integration rule (Genz and Monahan) as in the stochastic integration filter.

    One *draw* is a randomised spherical-radial rule for ``N(0, I_n)`` mapped
    through ``x = m + L u`` (``P = L L^T``); each draw is unbiased for any
    integrand and exact for polynomials up to its degree. ``n_iter`` draws are
    averaged (the SIR recursion of Dunik, Straka and Simandl), so the error
    shrinks like ``1 / sqrt(n_iter)``. All draws use a Haar-random rotation
    ``Q`` (:func:`haar_rotations`); points come in pairs ``+-a`` with equal
    weights, so every draw integrates linear functions exactly (the
    integration error of the mean is then zero, too).

    ``order=3`` (default): ``rho^2 ~ chi2(n + 2)``; points ``m``,
    ``m +- rho L Q e_j`` (``2n + 1``); weights ``1 - n / rho^2`` (centre),
    ``1 / (2 rho^2)``. These are the *axis* points. All three public codes of
    the authors' group (the NEF toolbox's ``nefSIF``, the MATLAB
    ``stochasticCubatureRulePoints`` of ``sifTimeUpdate`` /
    ``sifMeasurementUpdatev2``, and Stone Soup's
    ``stochastic_cubature_rule_points``) use exactly these axis points for
    degree 3, so there is no separate "simplex" degree-3 variant to select:
    only degree 5 is built on a simplex. The centre weight is negative with
    probability ``P(chi2(n+2) < n)`` (0.32 for ``n = 4``).

    ``order=5``: ``r^2 ~ chi2(2n + 7)``, ``q ~ Beta(n + 2, 3/2)``,
    ``rho = r sin(asin(q)/2)``, ``delta = r cos(asin(q)/2)``; with ``v_i``
    the ``n + 1`` vertices of a regular simplex and ``y_ij`` the normalised
    midpoints of its edges, both rotated by ``Q``, the points
    ``m +- L {rho v_i, delta v_i, rho y_ij, delta y_ij}`` (``1 + 4(n+1) +
    2n(n+1)`` points, 61 for ``n = 4``) carry Genz and Monahan's weights,
    with ``c = 2 (n+1)^2 (n+2)``,

    .. math::

        w_{\rho v} = \frac{(n+2-\delta^2)(7-n)n^2}{c\,\rho^2(\rho^2-\delta^2)},\;
        w_{\delta v} = \frac{(n+2-\rho^2)(7-n)n^2}{c\,\delta^2(\delta^2-\rho^2)},\;
        w_{\rho y} = \frac{(n+2-\delta^2)\,4(n-1)^2}{c\,\rho^2(\rho^2-\delta^2)},\;
        w_{\delta y} = \frac{(n+2-\rho^2)\,4(n-1)^2}{c\,\delta^2(\delta^2-\rho^2)},

    and the centre ``1 - n (rho^2 + delta^2 - n - 2) / (rho^2 delta^2)``
    (constructed as in Stone Soup, whose draws it reproduces given the same
    ``r``, ``q``, ``Q``; see :func:`stochastic_rule_points`). Exact for
    polynomials of degree 5, so one draw gives the variance of a quadratic
    exactly. For ``n = 1`` the midpoints vanish (and carry weight zero): they
    are left out. The weights are heavy-tailed: as ``q -> 1``, ``rho -> delta``
    and the ``rho`` and ``delta`` weights grow without bound with opposite
    signs. Smooth integrands cancel that; a bearing's wrap cut or a target
    near the sensor does not, and on the CTM the degree-5 filter with few
    iterations loses definiteness and diverges far more often than degree 3
    (``benchmarks/bench_sif.py``), although one degree-5 draw is as accurate
    as ten degree-3 draws on its first update.

    ``order=1``: ``+-L X``, ``X ~ N(0, I)``, weights 1/2 (antithetic Monte
    Carlo; the mean of a linear function is exact, its covariance is not).

    Options of the authors' reference implementations
    -------------------------------------------------
    ``passes`` -- ``1`` (default): every draw updates the mean and the
    covariances together, and the covariance is taken about the average of
    the same draws (the NEF toolbox's ``nefSIF`` and the MATLAB
    ``sifTimeUpdate``). ``2``: first the mean ``I_z`` from draws of its own,
    then ``Pzz``, ``Pxz`` from fresh draws about that mean (``sum_i w_i (h_i -
    I_z)(h_i - I_z)^T``; MATLAB ``sifMeasurementUpdatev2`` and Stone Soup's
    ``StochasticIntegrationPredictor`` / ``Updater``). The second pass draws
    from ``rng.spawn(1)[0]``, so its draw ``i`` is also the same whatever the
    iteration counts.

    ``integration_error`` -- ``False`` (default) or ``"diag"`` / ``True`` or
    ``"full"``: report in ``Moments.mean_var`` the estimated variance of the
    averaged mean, ``V_N = s_N^2 / N`` (``s_N^2`` the sample covariance of the
    ``N`` per-draw means), by the references' recursion

    .. math::

        D_N = (S_N - I_{N-1}) / N,\quad I_N = I_{N-1} + D_N,\quad
        V_N = \frac{N-2}{N} V_{N-1} + D_N D_N^T ,

    which the filters add to the predicted covariance (``Pzz = IPz + R +
    Vz``, ``P_pred = IPx + Q + Vx``, as in Stone Soup and, for ``Pzz``, the
    MATLAB v2 update). ``"diag"`` keeps its diagonal (Stone Soup), ``"full"``
    the whole matrix (MATLAB v2, ``Dz*Dz'``); for a scalar measurement they
    agree. ``Pxz`` gets no such term (none of the references adds one).
    *Convention for* ``N = 1``: ``V_1 = 0``. The references start the recursion
    from ``I_0 = 0, V_0 = 0``, which gives ``V_1 = I_1 I_1^T``, the square of
    the estimate itself: it depends on the coordinate origin (a bearing's
    zero direction, a position's origin) and is not a variance; one draw
    carries no information about the spread, so nothing is added. From
    ``N = 2`` on the recursion is exactly the references'.

    ``tol``, ``n_min`` -- ``tol=None`` (default): a fixed number of draws,
    ``n_iter`` (the parameter a policy picks). With ``tol`` set, ``n_iter``
    is the *maximum* and each run iterates while ``N < n_min`` or
    (``N < n_iter`` and the estimated integration error exceeds ``tol``), the
    references' ``while N < Nmin || (N < Nmax && norm(V) > Eps)``: the
    error is the Frobenius norm of the element-wise variances of the mean
    (and, for the covariance pass or ``passes=1``, of ``Pzz`` and ``Pxz``), as
    Stone Soup computes it. Because ``V_1 = 0`` carries no information the
    tolerance is tested from ``N = 2`` on. ``n_min`` wins over ``n_iter``, as
    in the references. The iterations each run spent are in
    ``Moments.n_iter`` (both passes counted).

    Batched runs: per-run ``n_iter`` and per-run stopping. Every iteration
    draws its random numbers for all runs, so draw ``i`` of run ``j`` consumes
    the same random numbers whatever the iteration counts (common random
    numbers between policies), but evaluates the function only for the runs
    still iterating: a batch costs ``sum_j n_iter_j`` draws' points, not
    ``max_j n_iter_j * M``, and each run's moments are bit for bit those of
    the scalar call with its own count.

    Stone Soup's defaults (the authors' Python port) are
    ``StochasticIntegrationRule(10, order=5, passes=2,
    integration_error="diag", tol=5e-4, n_min=5)`` for the update and
    ``tol=5e-3`` for the predict step (:meth:`adaptfilt.gaf.SIF.reference`).
    The default here is the simplest of the references' forms, the NEF
    toolbox's: degree 3, one pass, no error term, a fixed count. The paper's
    experiments (:mod:`adaptfilt.experiments`, every SIF result in ``data/``)
    run the form that ``tests/test_sif_reference.py`` checks draw for draw
    against Stone Soup: degree 3, ``passes=2``, ``integration_error="diag"``,
    a fixed ``N_it`` chosen by the policy (with ``V_1 = 0``, above). The
    authors' own codes differ on all these choices (the NEF toolbox and the
    MATLAB time update use one pass and no error term; the order is an
    argument everywhere, 5 being Stone Soup's default).

    Example
    -------
    >>> import numpy as np
    >>> from adaptfilt.rules import StochasticIntegrationRule
    >>> m, P = np.zeros((2, 3)), np.repeat(np.eye(2)[:, :, None], 3, axis=2)
    >>> quad = lambda X: (X * X).sum(axis=0, keepdims=True)  # |x|^2: E = 2, Var = 4
    >>> mo = StochasticIntegrationRule(order=5).moments(quad, m, P, 1, rng=np.random.default_rng(0))
    >>> np.allclose(mo.mean, 2.0), np.allclose(mo.cov, 4.0)  # degree 5: exact in every draw
    (True, True)
    """

    param_name = "n_iter"
    stochastic = True
    ORDERS = (1, 3, 5)

    def __init__(
        self,
        default_n_iter: int = 10,
        *,
        order: Literal[1, 3, 5] = 3,
        passes: Literal[1, 2] = 1,
        integration_error: bool | Literal["none", "diag", "full"] = False,
        tol: float | None = None,
        n_min: int = 1,
    ):
        self._default = int(default_n_iter)
        if order not in self.ORDERS:
            raise ValueError(f"order must be one of {self.ORDERS}, got {order!r}")
        if passes not in (1, 2):
            raise ValueError(f"passes must be 1 or 2, got {passes!r}")
        if not isinstance(integration_error, (bool, str, type(None))) or integration_error not in _INTEGRATION_ERROR:
            raise ValueError(f"integration_error must be False, True, 'none', 'diag' or 'full', got {integration_error!r}")
        if tol is not None and not (np.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be a positive number or None, got {tol!r}")
        if int(n_min) != n_min or n_min < 1:
            raise ValueError(f"n_min must be a positive integer, got {n_min!r}")
        self.order, self.passes = int(order), int(passes)
        self.integration_error = _INTEGRATION_ERROR[integration_error]
        self.tol = None if tol is None else float(tol)
        self.n_min = int(n_min)
        self._basis5: dict[int, np.ndarray] = {}

    def __repr__(self) -> str:
        return (f"StochasticIntegrationRule(order={self.order}, passes={self.passes}, "
                f"integration_error={self.integration_error!r}, tol={self.tol}, n_min={self.n_min})")

    def default_param(self, n: int) -> float:
        return float(self._default)

    def check_param(self, param, n: int) -> np.ndarray:
        it = np.asarray(param, dtype=float)
        if not np.isfinite(it).all() or (it < 1).any() or (it != np.round(it)).any():
            raise ValueError(f"n_iter must be a positive integer (or one per run), got {param!r}")
        return it

    def points_per_draw(self, n: int) -> int:
        """Function evaluations of one draw, centre excluded."""
        if self.order == 1:
            return 2
        if self.order == 3:
            return 2 * n
        return 4 * (n + 1) + (2 * n * (n + 1) if n > 1 else 0)

    compute_unit = "iteration"

    def spent(self, param) -> np.ndarray:
        """Iterations: ``n_iter`` itself (at least ``n_min`` with ``tol``; at most ``n_iter``).

        One iteration of the two-pass rule is a draw for the mean and one for the
        covariances, so its function evaluations are twice the one-pass rule's
        (:meth:`n_points`); the paper's cost term ``N_it / 50`` counts iterations.
        """
        it = np.asarray(param, dtype=float)
        return np.maximum(it, self.n_min) if self.tol is not None else it

    def n_points(self, n: int, param) -> np.ndarray:
        """Function evaluations for ``param`` iterations (at most, with ``tol``); centre included."""
        it = np.asarray(param, dtype=float)
        if self.tol is not None:
            it = np.maximum(it, self.n_min)
        return 1 + self.passes * self.points_per_draw(n) * it

    # ------------------------------------------------------------ draws
    def _draw(self, n: int, M: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
        """The random variates of one draw for ``M`` runs (run axis last). For orders 3 and 5 the
        first is the Gaussian matrix whose Gram-Schmidt factor is the rotation (:func:`haar_rotations`);
        :meth:`_point_set` orthogonalises it, for the runs that use the draw only."""
        if self.order == 1:
            return (rng.standard_normal((n, M)),)
        if self.order == 3:  # numpy's numbers, drawn by compiled code where numba is there
            G, chi2 = _kernels.rule3_draws(rng, n, M)
            return G[0], chi2[0]
        G = rng.standard_normal((n, n, M))
        return G, rng.chisquare(2 * n + 7, size=M), rng.beta(n + 2, 1.5, size=M)

    def _basis(self, n: int) -> np.ndarray:
        """Simplex vertices and (``n > 1``) edge midpoints, ``(n, n + 1 + n(n+1)/2)``."""
        if n not in self._basis5:
            V = _simplex(n)
            self._basis5[n] = np.concatenate([V, _simplex_midpoints(V)], axis=1) if n > 1 else V
        return self._basis5[n]

    @staticmethod
    def _degree5_weights(n: int, rho: np.ndarray, delta: np.ndarray):
        """Genz-Monahan degree-5 weights of the four point groups and the centre, as in the references."""
        r2, d2 = rho**2, delta**2
        c1up, c1do = n + 2 - d2, r2 * (r2 - d2)
        c2up, c2do = n + 2 - r2, d2 * (d2 - r2)
        cdo = 2 * (n + 1) ** 2 * (n + 2)
        c3, c4 = (7 - n) * n**2, 4 * (n - 1) ** 2
        coef = (c1up * c3 / cdo / c1do, c2up * c3 / cdo / c2do, c1up * c4 / cdo / c1do, c2up * c4 / cdo / c2do)
        w0 = 1 - n * (r2 + d2 - n - 2) / (r2 * d2)
        return coef, w0

    def _point_set(self, n: int, raw: tuple[np.ndarray, ...], sel: np.ndarray | None = None) -> _PointSet:
        """The point set of one draw for the runs ``sel`` of its random variates (all when None)."""
        take = (lambda a: a) if sel is None else (lambda a: _take_runs(a, sel))  # noqa: E731
        if self.order == 1:
            return _PointSet(scale=1.0, rotation=take(raw[0])[:, None, :], weight=0.5)
        # the rotation gathers its runs itself (one pass over G, no copy of the subset first)
        Q = _gram_schmidt(raw[0], sel)
        if self.order == 3:
            rho2 = take(raw[1])
            return _PointSet(scale=np.sqrt(rho2), rotation=Q, weight=0.5 / rho2)
        r2, q = take(raw[1]), take(raw[2])
        r, a = np.sqrt(r2), np.arcsin(q) / 2
        rho, delta = r * np.sin(a), r * np.cos(a)
        coef, _ = self._degree5_weights(n, rho, delta)
        v, y = slice(0, n + 1), slice(n + 1, None)
        groups = [(v, rho, coef[0]), (v, delta, coef[1])] + ([(y, rho, coef[2]), (y, delta, coef[3])] if n > 1 else [])
        return _PointSet(scale=1.0, rotation=Q, weight=1.0, basis=self._basis(n), groups=groups)

    def _point_sets(self, n: int, M: int, n_iter: np.ndarray, rng: np.random.Generator, tile: int = 1,
                    runs: Callable[[], np.ndarray | None] | None = None) -> Iterator[tuple[_PointSet, np.ndarray | None]]:
        """The draws of one pass: ``max(n_iter)`` of them (at least ``n_min`` with ``tol``); the
        recursion may stop early. Every draw's random numbers are drawn for all ``M`` runs (so that
        draw ``i`` of a run is the same whatever the other runs do), but its points are made only
        for the runs ``runs()`` names when the draw is due (None: all); the others are done.
        With ``tile = G`` each draw is made for ``M / G`` runs and repeated ``G`` times.
        Yields ``(point set, runs)``: the set is made for those runs, in that order (None: all ``M``)."""
        cap = int(n_iter.max()) if self.tol is None else max(int(n_iter.max()), self.n_min)
        M0 = M // tile
        copies = np.tile(np.arange(M0), tile) if tile > 1 else None  # run g * M0 + j is copy g of run j
        last_idx, last_sel = None, copies
        for _ in range(cap):
            raw = self._draw(n, M0, rng)
            idx = None if runs is None else runs()
            if idx is not last_idx:  # the runs' columns of the draws: recomputed only when the runs change
                last_idx, last_sel = idx, (copies if idx is None else idx % M0 if tile > 1 else idx)
            yield self._point_set(n, raw, last_sel), idx

    # -------------------------------------------------------- recursion
    def _recursion(self, make_sets, evaluate, n_iter: np.ndarray, M: int, what: str, cross: bool, c=None,
                   at: tuple[int, ...] | None = None) -> dict | dict[int, dict]:
        """One SIR recursion over draws, per run, until its fixed count or the stopping rule ends it.

        ``make_sets(runs)``: the pass's draws (:meth:`_point_sets`), each made for the runs
        ``runs()`` names when it is due: the runs still iterating (None: all of them), so a
        run that is done costs no function evaluations, only its share of the random numbers.
        ``evaluate(ps, runs, cross)``: the weighted sums of the set ``ps`` made for ``runs``.
        ``what``: ``"joint"`` (mean and covariances from the same draws),
        ``"mean"`` (first pass) or ``"cov"`` (second pass, about ``g0 + c``).
        Returns the averaged sums, the per-run counts and the Welford state.
        ``at`` (fixed count, scalar ``n_iter = max(at)`` only): return instead
        ``{k: state after draw k}`` for every ``k`` in ``at``, the states the
        recursion with ``n_iter = k`` ends in (the first ``k`` draws are the same).

        The state (sums, counts, Welford terms) is kept for the active runs only, in arrays of
        their columns: gathered when the active set changes (a few times a call: the runs stop
        at a few distinct counts), written back then and at the end. Each run's numbers are
        those of whole-batch arrays (the same operations on the same operands, element by
        element; the runs that are done would only add zeros or keep their values).
        """
        tol = self.tol
        per_run = n_iter.ndim > 0 or tol is not None
        want_mean, want_cov = what != "cov", what != "mean"
        cross = cross and want_cov
        want_var = want_mean and self.integration_error != "none"
        track = want_var or tol is not None
        full_var = self.integration_error == "full"
        if at is not None and (per_run or int(n_iter) != max(at)):
            raise ValueError("_recursion(at=...) needs a fixed count with scalar n_iter = max(at)")
        tracked = ("mean",) * want_mean + (("cov",) + ("cross",) * cross if want_cov and tol is not None else ())
        tested = [k for k in (("mean", "cov", "cross") if what == "joint" else ("mean",) if what == "mean" else ("cov", "cross"))
                  if k in tracked]
        # the state of the runs in ``cols`` (None: all M): state["sums"] (ED, EDD, EXD), state[name] = (I, V)
        # of each tracked quantity, state["Vfull"]; N, the counts and the centre c of those runs
        cols = None
        state: dict[str, list] = {}
        whole: dict[str, list] = {}  # the whole-batch arrays while cols is a subset
        N = np.zeros(M) if per_run else 0.0
        its, ck = n_iter, c
        active = np.ones(M, dtype=bool) if per_run else None
        snaps: dict[int, dict] = {}

        def regroup(new):
            """Write the subset's state back into the whole-batch arrays and gather the runs ``new``."""
            nonlocal cols, N, its, ck
            if cols is None:
                whole.update({k: list(v) for k, v in state.items()}, N=[N])
            else:
                for k, v in state.items():
                    for a, part in zip(whole[k], v):
                        if a is not None:
                            a[..., cols] = part
                whole["N"][0][cols] = N
            cols = new
            if new is None:
                state.update({k: list(v) for k, v in whole.items() if k != "N"})
                N, its, ck = whole["N"][0], n_iter, c
            else:
                state.update({k: [None if a is None else _take_runs(a, new) for a in v] for k, v in whole.items() if k != "N"})
                N, ck = whole["N"][0][new], None if c is None else _take_runs(c, new)
                its = n_iter if n_iter.ndim == 0 else n_iter[new]

        sets = make_sets((lambda: cols) if per_run else None)
        for ps, idx in sets:
            e, ee, ex = evaluate(ps, idx, cross)
            if not state:
                state["sums"] = [np.zeros_like(e), np.zeros_like(ee), np.zeros_like(ex) if cross else None]
            sums = state["sums"]
            sums[0] += e
            sums[1] += ee
            if cross:
                sums[2] += ex
            N = N + 1.0
            if track:
                X = {"mean": e}
                if "cov" in tracked:
                    X["cov"] = ee if c is None else ee - e[:, None] * ck[None] - ck[:, None] * e[None] + ck[:, None] * ck[None]
                    if cross:
                        X["cross"] = ex
                for name in tracked:
                    I, V = state.get(name) or (np.zeros_like(X[name]), np.zeros_like(X[name]))
                    Dv = (X[name] - I) / N
                    if per_run:
                        later = N >= 2  # V_1 = 0: one draw says nothing about the spread
                        I, V = I + Dv, np.where(later, (N - 2) / N * V + Dv * Dv, V)
                    else:
                        later = N >= 2
                        I, V = I + Dv, ((N - 2) / N * V + Dv * Dv if later else V)
                    state[name] = [I, V]
                    if name == "mean" and full_var:
                        Vfull = state["Vfull"][0] if "Vfull" in state else np.zeros((e.shape[0],) * 2 + e.shape[1:])
                        outer = Dv[:, None] * Dv[None]
                        state["Vfull"] = [np.where(np.broadcast_to(later, Vfull.shape[-1:]), (N - 2) / N * Vfull + outer, Vfull)]
            if at is not None and N in at:
                snaps[int(N)] = self._averaged(state["sums"], N, cross, state["mean"][1] if want_var else None,
                                               state["Vfull"][0] if "Vfull" in state else None)
            if not per_run:
                continue
            if tol is None:
                still = N < its
            else:
                big = np.zeros(N.shape, dtype=bool)
                for name in tested:
                    V = state[name][1]
                    big |= np.sqrt((V * V).reshape(-1, V.shape[-1]).sum(axis=0)) > tol
                still = (N < self.n_min) | ((N < its) & ((N < 2) | big))
            if not still.all():  # some runs are done: the active set changes
                if cols is None:
                    active = still
                else:
                    active[cols] = still
                if not active.any():
                    break
                regroup(_active_runs(active))
        if cols is not None:
            regroup(None)
        if at is not None:
            return snaps
        return self._averaged(state["sums"], N, cross, state["mean"][1] if want_var else None,
                              state["Vfull"][0] if "Vfull" in state else None)

    def _fused_applies(self, m: np.ndarray, L: np.ndarray, g0: np.ndarray) -> bool:
        """Whether :meth:`_recursion_fused` computes this call: degree 3, a fixed count (per call or per
        run), ``n >= 2``, ``M >= 2``, float64 throughout, the compiled kernels there."""
        n, M = m.shape
        return (self.order == 3 and self.tol is None and n >= 2 and M >= 2 and m.dtype == np.float64
                and L.dtype == np.float64 and L.shape == (n, n, M) and g0.dtype == np.float64 and g0.ndim == 2
                and _kernels.fused_available())

    def _recursion_fused(self, rng, g, residual, m, g0, L, n_iter: np.ndarray, M: int, tile: int, what: str,
                         cross: bool, at: tuple[int, ...] | None = None) -> dict | dict[int, dict]:
        """:meth:`_recursion` over :meth:`_point_sets` for the degree-3 rule with a fixed count (scalar or per
        run), bit for bit, in two compiled calls per draw around the function ``g`` (and ``residual``):
        the point set (:func:`~adaptfilt.rules._sif_kernels.rule3_points`) and the sums with the Welford
        state (:func:`~adaptfilt.rules._sif_kernels.rule3_accumulate`). The draws are the same (``_draw``
        for all ``M / tile`` runs, ``max(n_iter)`` of them); the state is kept for the whole batch and
        updated at the columns of the runs still iterating, each element by the operations
        :meth:`_recursion` applies to it. Without ``tol`` every run still iterating has made the same
        number of draws, so the active set after draw ``k`` is the runs with ``n_iter > k``. The variates
        of several draws are made in one call (:func:`~adaptfilt.rules._sif_kernels.rule3_draws`): ``g``
        and ``residual`` do not draw from ``rng``."""
        n = m.shape[0]
        ng = g0.shape[0]
        per_run = n_iter.ndim > 0
        want_mean = what != "cov"
        cross = cross and what != "mean"
        track = want_mean and self.integration_error != "none"
        full = track and self.integration_error == "full"
        cap = int(n_iter.max())
        M0 = M // tile
        sums = (np.zeros((ng, M)), np.zeros((ng, ng, M)), np.zeros((n if cross else 0, ng, M)))
        welford = (np.zeros((ng, M)), np.zeros((ng, M)), np.zeros((ng, ng, M)) if full else None) if track else None
        every = np.arange(M)
        sel = np.tile(np.arange(M0), tile) if tile > 1 else every  # the draws' columns of the runs
        runs, n_runs, ms, Ls, g0s = every, M, m, L, g0
        stops = set(np.unique(n_iter).tolist()) if per_run else set()
        work: dict = {}
        snaps: dict[int, dict] = {}
        # the draws' variates a block at a time (nothing else draws from rng in between: the same stream)
        block = max(1, min(cap, (1 << 21) // (n * n * M0)))  # at most 16 MB of normals a block
        for k in range(1, cap + 1):
            if (k - 1) % block == 0:
                Gs, chi2s = _kernels.rule3_draws(rng, n, M0, min(block, cap - k + 1), scratch=True)
            G, chi2 = Gs[(k - 1) % block], chi2s[(k - 1) % block]
            X, A, weight = _kernels.rule3_points(G, chi2, sel, ms, Ls, work)
            Gx = g(X)
            D = Gx - g0s[:, None, :] if residual is None else residual(Gx, g0s[:, None, :])
            given = None
            if not (isinstance(D, np.ndarray) and D.dtype == np.float64 and D.shape == (ng,) + X.shape[1:]):
                # not the kernels' case: numpy's sums (as _pair_sums_made takes them then)
                given = _sums_numpy(np.ascontiguousarray(D), np.concatenate([A, -A], axis=1) if cross else None, weight)
                given = tuple(None if a is None else np.ascontiguousarray(a, dtype=np.float64) for a in given)
            else:
                D = np.ascontiguousarray(D)
            _kernels.rule3_accumulate(D, A, weight, cross, runs, n_runs, sums, float(k), welford, work, given)
            if at is not None and k in at:
                snaps[k] = self._averaged(sums, float(k), cross, None if not track else welford[1].copy(),
                                          None if not full else welford[2].copy())
            if float(k) in stops and k < cap:  # some runs are done: gather those still iterating
                idx = _active_runs(n_iter > k)
                runs, n_runs = idx, 1 if idx.size == 2 and idx[0] == idx[1] else idx.size
                sel = idx % M0 if tile > 1 else idx
                ms, Ls, g0s = (_take_runs(a, idx) for a in (m, L, g0))
                work = {}
        if at is not None:
            return snaps
        N = np.array(n_iter, dtype=float) if per_run else float(cap)
        return self._averaged(sums, N, cross, None if not track else welford[1], None if not full else welford[2])

    @staticmethod
    def _averaged(sums: list, N, cross: bool, V, Vfull) -> dict:
        """The recursion's result after ``N`` draws: the sums averaged (new arrays; ``sums`` is left as it is)."""
        ED, EDD, EXD = sums
        return {"ED": ED / N, "EDD": EDD / N, "EXD": EXD / N if cross else None, "N": N, "V": V, "Vfull": Vfull}

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
        """Moments of ``g(x)`` for ``x ~ N(m, P)``, ``m (n, M)``, ``P (n, n, M)``; ``param`` is ``n_iter``.

        ``rng`` (required) supplies the draws. ``tile = G`` declares the call
        a tiling of ``G`` copies of ``M / G`` runs (run ``g * M/G + j`` is
        copy ``g`` of run ``j``, as ``np.concatenate([a] * G, axis=-1)`` lays
        them out): draws are made for ``M / G`` runs and repeated, so run
        ``j`` sees the same draws in every copy, exactly those an untiled
        call with the same ``rng`` gives it. ``tile = 1`` changes nothing.
        """
        n, M = m.shape
        n_iter = self.check_param(param, n)
        if rng is None:
            raise ValueError("the stochastic integration rule needs a numpy Generator (rng)")
        tile = _check_tile(tile, M)
        return self._run(g, m, P, n_iter, residual, rng, L, cross, tile)

    @property
    def supports_prefixes(self) -> bool:
        """Whether :meth:`moments_prefixes` applies: a fixed count (``tol`` is None)."""
        return self.tol is None

    def moments_prefixes(
        self,
        g: BatchFn,
        m: np.ndarray,
        P: np.ndarray,
        n_iters,
        residual: Residual | None = None,
        rng: np.random.Generator | None = None,
        L: np.ndarray | None = None,
        cross: bool = True,
        tile: int = 1,
    ) -> list[Moments]:
        r"""The moments for several iteration counts from one set of draws: one :class:`Moments` per ``n_iters``.

        With a fixed count, the rule at ``n_iter = k`` averages the first ``k``
        draws its ``rng`` gives (draw ``i`` is the same whatever the count; the
        second pass draws from ``rng.spawn(1)[0]``), so every count is a
        prefix of the largest one. This makes ``max(n_iters)`` draws once and
        keeps the running sums, the Welford state of the integration-error
        term and the counts at each requested ``k``:

        .. math::

            \bar D^{(k)} = \frac1k \sum_{i \le k} S_i,\qquad
            \mathrm{Moments}^{(k)} = \text{moments}(g, m, P, k, \text{rng}),

        equal to ``moments(g, m, P, k, rng=Generator(same seed))`` up to
        summation order, for every order, pass count and
        ``integration_error`` form, at the cost of ``max(n_iters)`` draws on
        ``M`` runs instead of ``max(n_iters)`` draws on ``M * len(n_iters)``
        runs (the tiled call, ``moments(..., tile=G)``). ``n_iters`` is a
        sequence of positive integers (repeats allowed, any order). ValueError
        when ``tol`` is set: tolerance stopping depends on the draws, and the
        counts are then no longer prefixes of one another. ``tile``: as in
        :meth:`moments` (the ``M`` runs are ``tile`` copies that see the same draws).

        Example
        -------
        >>> import numpy as np
        >>> from adaptfilt.rules import StochasticIntegrationRule
        >>> rule, m, P = StochasticIntegrationRule(), np.zeros((2, 3)), np.repeat(np.eye(2)[:, :, None], 3, axis=2)
        >>> sin = lambda X: np.sin(X[:1])
        >>> few, many = rule.moments_prefixes(sin, m + 1, P, [2, 5], rng=np.random.default_rng(1))
        >>> two = rule.moments(sin, m + 1, P, 2, rng=np.random.default_rng(1))
        >>> bool(np.allclose(few.cov, two.cov, rtol=1e-12)), many.n_iter.tolist()
        (True, [5, 5, 5])
        """
        if not self.supports_prefixes:
            raise ValueError("moments_prefixes needs a fixed count (tol=None): with tol, counts are not prefixes")
        n, M = m.shape
        counts = np.asarray(n_iters, dtype=float)
        if counts.ndim != 1 or counts.size == 0:
            raise ValueError(f"n_iters must be a non-empty sequence of iteration counts, got {n_iters!r}")
        counts = self.check_param(counts, n).astype(int)
        if rng is None:
            raise ValueError("the stochastic integration rule needs a numpy Generator (rng)")
        return self._run(g, m, P, np.array(float(counts.max())), residual, rng, L, cross, _check_tile(tile, M),
                         at=tuple(counts.tolist()))

    def _run(self, g, m, P, n_iter, residual, rng, L, cross, tile, at=None) -> Moments | list[Moments]:
        """The passes of :meth:`moments`; with ``at`` (see :meth:`_recursion`), one Moments per count in ``at``."""
        n, M = m.shape
        if L is None:
            L = chol(sym(P), "P")
        g0 = g(m[:, None, :])[:, 0, :]
        work: dict = {}
        taken: list = [None, None]  # the runs last evaluated and their m, g0, L: the subset changes rarely

        def evaluate(ps: _PointSet, runs: np.ndarray | None, cr: bool):
            if runs is None:
                return _weighted_sums(g, m, g0, L, ps, residual, cr, work)
            if taken[0] is not runs:
                taken[:] = runs, tuple(_take_runs(a, runs) for a in (m, g0, L))
            return _weighted_sums(g, *taken[1], ps, residual, cr, work)

        if self._fused_applies(m, L, g0):  # the same numbers from two compiled calls per draw
            def recursion(r, what, cr, c=None, at=None):
                return self._recursion_fused(r, g, residual, m, g0, L, n_iter, M, tile, what, cr, at)
        else:
            def recursion(r, what, cr, c=None, at=None):
                draws = lambda runs: self._point_sets(n, M, n_iter, r, tile, runs)  # noqa: E731  (see _recursion)
                return self._recursion(draws, evaluate, n_iter, M, what, cr, c=c, at=at)
        if self.passes == 1:
            joint = recursion(rng, "joint", cross, at=at)
            if at is None:
                return self._finish(g0, joint, None, n_iter, M)
            return [self._finish(g0, joint[k], None, n_iter, M) for k in at]
        try:
            rng2 = rng.spawn(1)[0]
        except (AttributeError, TypeError, ValueError) as err:
            raise ValueError("passes=2 needs a numpy Generator with a SeedSequence (np.random.default_rng(seed))") from err
        mean_pass = recursion(rng, "mean", False, at=at)
        if at is None:
            cov_pass = recursion(rng2, "cov", cross, c=mean_pass["ED"])
            return self._finish(g0, mean_pass, cov_pass, n_iter, M)
        # without tol the covariance pass's sums do not depend on the centre c, so one
        # recursion serves every count (c only enters the tolerance test)
        cov_pass = recursion(rng2, "cov", cross, at=at)
        return [self._finish(g0, mean_pass[k], cov_pass[k], n_iter, M) for k in at]

    def _finish(self, g0: np.ndarray, mean_pass: dict, cov_pass: dict | None, n_iter, M: int) -> Moments:
        """Moments from the recursion's results (``cov_pass`` None: one pass, ``mean_pass`` is the joint one)."""
        ED = mean_pass["ED"]
        if cov_pass is None:
            r = mean_pass
            cov = self._cov_from_sums(r["EDD"], ED, n_iter)
            spent = r["N"]
        else:
            r = cov_pass
            E2 = r["ED"]
            # sum_i w_i (D_i - c)(D_i - c)^T averaged over the draws, c = ED
            cov = r["EDD"] - E2[:, None] * ED[None] - ED[:, None] * E2[None] + ED[:, None] * ED[None]
            spent = mean_pass["N"] + r["N"]
        mean_var = None
        if self.integration_error == "diag":
            mean_var = mean_pass["V"][:, None, :] * np.eye(ED.shape[0])[:, :, None]
        elif self.integration_error == "full":
            mean_var = mean_pass["Vfull"] if mean_pass["Vfull"] is not None else np.zeros((ED.shape[0],) * 2 + (M,))
        return Moments(mean=g0 + ED, cov=sym(cov), cross=r["EXD"], mean_var=mean_var,
                       n_iter=np.broadcast_to(spent, (M,)).astype(int))


def stochastic_rule_points(n: int, order: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One draw of the stochastic integration rule for ``N(0, I_n)``: points ``(n, S)``, weights ``(S,)``.

    The points and weights of Stone Soup's ``stochastic_cubature_rule_points``
    (and the authors' MATLAB ``stochasticCubatureRulePoints``), in their
    order, but drawn from ``rng`` as :class:`StochasticIntegrationRule` draws
    them (``Q`` by :func:`haar_rotations`, then ``chi2``, then ``Beta``):
    given the same radii and rotation the two agree. Order 1: ``[X, -X]``;
    order 3: centre, ``+rho Q e_j``, ``-rho Q e_j``; order 5: centre,
    ``-+rho v``, ``-+delta v``, ``-+rho y``, ``-+delta y`` (``y`` left out for
    ``n = 1``, where it is 0/0 in the references and has weight zero).
    """
    rule = StochasticIntegrationRule(order=order)
    raw = rule._draw(n, 1, rng)
    if order == 1:
        X = raw[0]
        return np.concatenate([X, -X], axis=1), np.array([0.5, 0.5])
    Q = _gram_schmidt(raw[0])[:, :, 0]
    if order == 3:
        rho2 = raw[1][0]
        A = Q * np.sqrt(rho2)
        return np.concatenate([np.zeros((n, 1)), A, -A], axis=1), np.concatenate([[1 - n / rho2], np.full(2 * n, 0.5 / rho2)])
    ps = rule._point_set(n, raw)
    _, w0 = rule._degree5_weights(n, ps.groups[0][1], ps.groups[1][1])
    pts, wts = [np.zeros((n, 1))], [w0]
    for cols, radius, w in ps.groups:
        A = (Q @ ps.basis[:, cols]) * radius[0]
        pts += [-A, A]
        wts += [np.full(2 * A.shape[1], w[0])]
    return np.concatenate(pts, axis=1), np.concatenate(wts)
