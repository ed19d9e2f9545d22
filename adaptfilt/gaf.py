r"""The Gaussian-assumed filter (Algorithm 1 of the paper) and its front doors.

A GAF is one recursion plus a moment rule (:mod:`adaptfilt.rules`):

.. math::

    \hat x_{k|k-1} = E[f(x_{k-1})],\quad
    P_{k|k-1} = \mathrm{Cov}[f(x_{k-1})] + Q \qquad\text{(predict)}

.. math::

    \hat z_{k|k-1} = E[h(x_k)],\quad P^{zz} = \mathrm{Cov}[h(x_k)] + R,\quad
    P^{xz} = \mathrm{Cov}[x_k, h(x_k)]

.. math::

    K = P^{xz} (P^{zz})^{-1},\quad \tilde z = z_k - \hat z_{k|k-1},\quad
    \hat x_{k|k} = \hat x_{k|k-1} + K \tilde z,\quad
    P_{k|k} = P_{k|k-1} - K P^{zz} K^T \qquad\text{(update)}

with ``NIS = z~^T (P^{zz})^{-1} z~`` and log-likelihood
``log N(z~; 0, P^{zz})``. The UKF is the GAF with the unscented rule
(parameter ``kappa``), the SIF the GAF with the stochastic integration rule
(parameter ``n_iter``). A stochastic rule asked for its integration-error term
reports the estimated variance ``V`` of its mean estimate
(``Moments.mean_var``), which is added to the predicted covariance:
``P_{k|k-1} = Cov[f] + Q + V_x`` and ``P^{zz} = Cov[h] + R + V_z``, as the
SIF's authors do.

Everything is batched over Monte-Carlo runs; a parameter is a scalar or one
value per run. Only the update-step parameter is adapted (Section V of the
paper): ``run(z, params=...)`` sets the update parameter, and the predict step
uses the filter's own parameter. When the model declares its dynamics linear
(``model.F``) the predict step is the exact Kalman predict.

Time convention: the prior is the predictive density of the first state, so
step ``t = 0`` is an update without a predict before it.

Numerics: covariances are symmetrised; a covariance that is not positive
definite (negative centre weights can do that) raises :class:`FilterError`
naming the quantity, the step and the runs, unless the filter was built with
``on_indefinite="clip"``, the documented opt-in repair that clips the offending
runs' eigenvalues and counts the repairs in ``FilterRun.n_repairs`` (:class:`~adaptfilt.filters.FilterRun`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from adaptfilt.filters import FilterRun
from adaptfilt.linalg import NotPositiveDefinite, chol, clip_to_pd, logdet_chol, mm, mv, solve_spd, sym, sym_fresh
from adaptfilt.models import StateSpaceModel
from adaptfilt.rules import MomentRule, Moments, StochasticIntegrationRule, UnscentedRule
from adaptfilt.rules import scalar_kernels

__all__ = ["FilterError", "Prediction", "Update", "GaussianAssumedFilter", "UKF", "SIF", "CKF"]

_PREDICT, _UPDATE = 0, 1
_LOG2PI = np.log(2.0 * np.pi)


class FilterError(RuntimeError):
    """Numerical failure inside a filter, naming the quantity, step and runs."""

    def __init__(self, quantity: str, step: int, runs, detail: str = ""):
        self.quantity, self.step, self.runs = quantity, int(step), np.asarray(runs)
        shown = ", ".join(str(int(r)) for r in self.runs[:10])
        more = "" if self.runs.size <= 10 else f" (+{self.runs.size - 10} more)"
        msg = f"{quantity} at step t={step} (k={step + 1}) in run(s) {shown}{more}"
        super().__init__(msg + (f": {detail}" if detail else ""))


def _plus_error(C: np.ndarray, mo: Moments) -> np.ndarray:
    """``C + V``: a predicted covariance plus the rule's integration-error term, when it reports one."""
    return C if mo.mean_var is None else C + mo.mean_var


def _last_first(a: np.ndarray) -> np.ndarray:
    """``np.moveaxis(a, 0, -1)`` (a view) without moveaxis's argument checks, which cost more than
    the move on a small batch; ``a.ndim >= 1``."""
    return a.transpose(tuple(range(1, a.ndim)) + (0,))


def _first_last(a: np.ndarray) -> np.ndarray:
    """``np.moveaxis(a, -1, 0)`` (a view), as :func:`_last_first`."""
    return a.transpose((a.ndim - 1,) + tuple(range(a.ndim - 1)))


def _public(a: np.ndarray) -> np.ndarray:
    """Run-last ``(n, ..., M)`` -> public ``(M, n, ...)`` view (no copy)."""
    return np.moveaxis(a, -1, 0)


def _internal(a: np.ndarray) -> np.ndarray:
    """Public ``(M, n, ...)`` -> run-last ``(n, ..., M)`` view (no copy)."""
    return np.moveaxis(np.asarray(a, dtype=float), 0, -1)


@dataclass
class Prediction:
    """Predict step output, public layout: ``x_pred (M, nx)``, ``P_pred (M, nx, nx)``."""

    x_pred: np.ndarray
    P_pred: np.ndarray


@dataclass
class Update:
    """Every quantity of one update step of Algorithm 1, public layout ``(M, ...)``."""

    x_pred: np.ndarray
    P_pred: np.ndarray
    z_pred: np.ndarray
    Pzz: np.ndarray
    Pxz: np.ndarray
    K: np.ndarray
    innovation: np.ndarray
    nis: np.ndarray
    loglik: np.ndarray
    x_filt: np.ndarray
    P_filt: np.ndarray
    #: iterations a stochastic rule spent per run ``(M,)``; 0 for deterministic rules and exact linear updates
    n_iter_spent: np.ndarray | None = None


@dataclass
class _UpdateRL:
    """The same quantities, run axis last (internal)."""

    z_pred: np.ndarray
    Pzz: np.ndarray
    Pxz: np.ndarray
    K: np.ndarray
    innovation: np.ndarray
    nis: np.ndarray
    loglik: np.ndarray
    x_filt: np.ndarray
    P_filt: np.ndarray
    n_iter_spent: np.ndarray | None = None
    #: the Cholesky factor of ``P_filt`` when it needed no repair (the next predict's factor, so that
    #: :meth:`GaussianAssumedFilter.predict_rl` need not factor it again), else None. Not annotated, so
    #: not a field: a copy built from the fields (the MDP's chosen candidates) leaves it None
    L_filt = None


class GaussianAssumedFilter:
    """Algorithm 1 with a pluggable moment rule, batched over runs.

    Parameters
    ----------
    model : StateSpaceModel
    rule : MomentRule
    param : float, optional
        The rule's parameter for the predict step and the default update
        parameter; ``None`` takes ``rule.default_param(nx)``.
    seed : int
        Seeds stochastic rules. The random numbers of step ``t`` come from
        ``Generator([seed, stage, t])``, so they do not depend on what earlier
        steps drew: filters that differ only in their parameters share them.
    on_indefinite : "raise" or "clip"
        What to do when a covariance loses positive definiteness.
    predict_rule : MomentRule, optional
        A rule for the predict step only (e.g. another stopping tolerance);
        default ``rule``. It takes the same parameter.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.ungm()
    >>> traj = model.simulate(n_runs=100, n_steps=50, rng=np.random.default_rng(0))
    >>> ukf = af.GaussianAssumedFilter(model, af.rules.UnscentedRule(), param=2.0)
    >>> run = ukf.run(traj.z)
    >>> run.mean.shape, run.cov.shape, run.nis.shape
    ((100, 50, 1), (100, 50, 1, 1), (100, 50))
    """

    #: ``run(z, policy=...)`` delegates to the MDP's episode loop, which registers itself here
    #: (:func:`adaptfilt.mdp.run_policy`): the filter does not import the MDP built on it.
    policy_runner = None

    def __init__(
        self,
        model: StateSpaceModel,
        rule: MomentRule,
        param: float | None = None,
        seed: int = 0,
        on_indefinite: Literal["raise", "clip"] = "raise",
        predict_rule: MomentRule | None = None,
    ):
        if not isinstance(model, StateSpaceModel):
            raise TypeError(f"model must be a StateSpaceModel, got {type(model).__name__}")
        if on_indefinite not in ("raise", "clip"):
            raise ValueError(f"on_indefinite must be 'raise' or 'clip', got {on_indefinite!r}")
        self.model = model
        self.rule = rule
        self.predict_rule = rule if predict_rule is None else predict_rule
        if self.predict_rule.stochastic != rule.stochastic:
            raise ValueError("rule and predict_rule must both be stochastic or both deterministic")
        self.param = float(rule.default_param(model.nx) if param is None else param)
        rule.check_param(self.param, model.nx)
        self.seed = int(seed)
        self.on_indefinite = on_indefinite
        self.n_repairs = 0
        #: when a list, every repair appends the indices of the runs it repaired (the MDP reads it per step)
        self.repair_log: list | None = None
        #: let :meth:`update_candidates_rl` use the rule's one-set-of-draws path where it has one
        #: (False: always the tiled call; for cross-checks and benchmarks, the results agree to round-off)
        self.candidate_prefixes = True
        nx = model.nx
        self._Q = model.Q[:, :, None]
        self._R = model.R[:, :, None]
        self._m0 = model.m0[:, None]
        self._P0 = model.P0[:, :, None]
        self._nx = nx

    # ---------------------------------------------------------------- helpers
    def __repr__(self) -> str:
        return f"{type(self).__name__}(model={self.model.name!r}, {self.rule.param_name}={self.param:g})"

    @property
    def param_name(self) -> str:
        """The rule's parameter, what ``run(z).params`` holds (:class:`~adaptfilt.filters.Filter`)."""
        return self.rule.param_name

    def rng(self, stage: int, t: int, stream: int | None = None) -> np.random.Generator | None:
        """The random numbers of a stochastic rule at ``(stage, t)`` (stage 0 =
        predict, 1 = update); ``stream`` separates e.g. training episodes."""
        if not self.rule.stochastic:
            return None
        return np.random.default_rng([self.seed, stage, t] + ([] if stream is None else [int(stream)]))

    def _wrap(self, fn: Callable, k: int) -> Callable[[np.ndarray], np.ndarray]:
        # model functions take (..., n); the filter holds (n, ..., M)
        def g(X: np.ndarray) -> np.ndarray:
            if X.ndim == 3:  # (n, S, M), what the rules pass
                return np.asarray(fn(X.transpose(1, 2, 0), k)).transpose(2, 0, 1)
            return _first_last(np.asarray(fn(_last_first(X), k)))

        return g

    def _residual_rl(self):
        r = self.model.residual
        if r is None:
            return None
        return lambda a, b: _first_last(r(_last_first(a), _last_first(b)))

    def factor(self, P: np.ndarray, quantity: str, t: int) -> tuple[np.ndarray, np.ndarray]:
        """``(L, P)``: the Cholesky factor of ``P`` (run-last ``(n, n, M)``, named ``quantity`` in errors) as
        this filter's step ``t`` takes it: ``FilterError`` naming the step and runs where it is not positive
        definite, or (``on_indefinite="clip"``) the documented repair of those runs, counted in ``n_repairs``
        and logged in ``repair_log``, with the repaired ``P``."""
        try:
            return chol(P, quantity), P
        except NotPositiveDefinite as e:
            if self.on_indefinite == "raise":
                raise FilterError(f"{quantity} is not positive definite", t, e.runs) from None
            self.n_repairs += int(e.runs.size)
            if self.repair_log is not None:
                self.repair_log.append(e.runs)
            P = clip_to_pd(P, e.runs)
            return chol(P, quantity), P

    def initial(self, n_runs: int) -> tuple[np.ndarray, np.ndarray]:
        """Prior mean and covariance broadcast over runs, run axis last."""
        return (np.repeat(self._m0, n_runs, axis=1), np.repeat(self._P0, n_runs, axis=2))

    # ------------------------------------------------------------- run-last core
    def predict_rl(
        self, m: np.ndarray, P: np.ndarray, t: int, rng: np.random.Generator | None = None, param=None,
        info: dict | None = None, tile: int = 1, L: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predict from step ``t`` to ``t + 1``; ``m (nx, M)``, ``P (nx, nx, M)``;
        ``param`` (default: the filter's) scalar or ``(M,)``.

        ``info``, if given, receives ``"n_iter"`` (the iterations a stochastic
        rule spent per run, or None). ``tile``: as in :meth:`update_rl` (the
        ``M`` runs are ``tile`` copies of ``M / tile`` runs that see the same draws).
        ``L``: the Cholesky factor of ``P`` when the caller has it (an update's
        ``L_filt``); ``P`` must then be symmetric, as an update's ``P_filt`` is.
        """
        model = self.model
        n_iter = None
        if model.F is not None:
            F = model.F[:, :, None]
            m_pred = mv(F, m)
            P_pred = mm(mm(F, P), F.swapaxes(0, 1)) + self._Q
        else:
            if L is None:
                L, P = self.factor(sym(P), "P_filt", t)
            mo = self.predict_rule.moments(self._wrap(model.f, t + 1), m, P, self.param if param is None else param,
                                           rng=self.rng(_PREDICT, t) if rng is None else rng, L=L, cross=False,
                                           tile=tile)
            m_pred, P_pred, n_iter = mo.mean, _plus_error(mo.cov + self._Q, mo), mo.n_iter
        if info is not None:
            info["n_iter"] = n_iter
        if not np.isfinite(m_pred).all():
            raise FilterError("non-finite predicted mean x_pred", t + 1, np.flatnonzero(~np.isfinite(m_pred).all(0)))
        return m_pred, sym_fresh(P_pred)

    def update_rl(
        self,
        m: np.ndarray,
        P: np.ndarray,
        z: np.ndarray | Callable[[np.ndarray, np.ndarray], np.ndarray],
        t: int,
        param=None,
        rng: np.random.Generator | None = None,
        tile: int = 1,
    ) -> _UpdateRL:
        """Update at step ``t`` with ``z (nz, M)``; ``param`` scalar or ``(M,)``.

        ``z`` may also be a function ``(z_pred, L_zz) -> z (nz, M)`` of the predicted
        measurement and the Cholesky factor of ``Pzz``: a measurement drawn from
        the filter's own predictive (what a look-ahead samples, :mod:`adaptfilt.lookahead`).

        ``tile = G``: the ``M`` runs are ``G`` copies of ``M / G`` runs laid out
        as ``np.concatenate([a] * G, axis=-1)`` (e.g. the MDP evaluating every
        candidate parameter at once); a stochastic rule then gives run ``j``
        the same draws in every copy, the draws an untiled call of the ``M / G``
        runs with the same ``rng`` gets. ``tile = 1``: independent draws per run.
        """
        L, P = self.factor(sym(P), "P_pred", t)
        return self._update_factored(m, P, L, z, t, self.param if param is None else param, rng, tile)

    def _update_factored(self, m, P, L, z, t: int, param, rng, tile: int) -> _UpdateRL:
        """:meth:`update_rl` from ``P`` symmetric, repaired if need be, and its Cholesky factor ``L``."""
        model = self.model
        n_iter = np.zeros(m.shape[1], dtype=int)
        if model.H is not None:
            H = model.H[:, :, None]
            z_pred = mv(H, m)
            Pxz = mm(P, H.swapaxes(0, 1))
            S = mm(H, Pxz)
        else:
            if rng is None:
                rng = self.rng(_UPDATE, t)
            mo = self.rule.moments(self._wrap(model.h, t + 1), m, P, param, residual=self._residual_rl(), rng=rng, L=L, tile=tile)
            z_pred, S, Pxz = mo.mean, _plus_error(mo.cov, mo), mo.cross
            if mo.n_iter is not None:
                n_iter = mo.n_iter
        return self._finish_update(m, P, z, t, z_pred, S, Pxz, n_iter)

    def candidates_spent(self, grid) -> float:
        """What :meth:`update_candidates_rl` spends, in the rule's ``compute_unit`` (:meth:`MomentRule.spent`):
        one update per grid value for the UKF; for the SIF ``max(grid)`` iterations when the candidates
        share one set of draws (prefix averages), else ``sum(grid)``."""
        cost = self.rule.spent(np.asarray(grid, dtype=float))
        shared = self.model.H is None and self.candidate_prefixes and self.rule.supports_prefixes
        return float(cost.max() if shared else cost.sum())

    def update_candidates_rl(
        self,
        m: np.ndarray,
        P: np.ndarray,
        z: np.ndarray | Callable[[np.ndarray, np.ndarray], np.ndarray],
        t: int,
        grid,
        rng: np.random.Generator | None = None,
        tile: int = 1,
    ) -> _UpdateRL:
        """The update of every run under every parameter of ``grid``, ``G * M`` runs, tile-major.

        Run ``g * M + j`` of the result is the update run ``j`` (of ``m (nx, M)``,
        ``P``, ``z (nz, M)``) makes with ``grid[g]``, with the same random numbers
        for every ``g``: exactly ``update_rl(tile(m), tile(P), tile(z), t,
        np.repeat(grid, M), rng, tile=G)`` with ``tile(a) = np.concatenate([a] * G,
        axis=-1)``, and, for each ``g``, ``update_rl(m, P, z, t, grid[g], rng)``
        with a Generator seeded alike.

        When the rule computes several parameters from one set of draws
        (``rule.supports_prefixes``: the stochastic integration rule with a
        fixed count, where ``n_iter = k`` averages the first ``k`` draws), the
        moments come from ``max(grid)`` draws on ``M`` runs
        (:meth:`~adaptfilt.rules.StochasticIntegrationRule.moments_prefixes`)
        instead of on ``G * M`` runs; the results agree to round-off
        (summation order). Otherwise, and for a linear measurement, it is the
        tiled call above (also when ``candidate_prefixes`` is False). A ``P`` that is not positive definite is repaired
        (and counted) once per run here, where the tiled call counts it once
        per copy; callers that repair ``P`` first (the MDP) see no difference.

        ``tile = K``: the ``M`` runs are themselves ``K`` copies of ``M / K`` runs
        (as in :meth:`update_rl`) that see the same draws, so that run ``j`` gets
        the draws of run ``j mod M / K`` under every parameter (a look-ahead
        comparing its branches with common random numbers). ``z`` may be a
        function, as in :meth:`update_rl`; it receives the moments of all
        ``G * M`` runs and returns their ``(nz, G * M)`` measurements.

        Example
        -------
        >>> import numpy as np, adaptfilt as af
        >>> model = af.models.coordinated_turn()
        >>> sif = af.SIF(model, seed=0)
        >>> m, P = sif.initial(4)
        >>> z = model.simulate(4, 1, rng=0).z[:, 0].T
        >>> u = sif.update_candidates_rl(m, P, z, 0, [1, 5, 10], rng=sif.rng(1, 0))
        >>> u.x_filt.shape, u.n_iter_spent.tolist()
        ((4, 12), [1, 1, 1, 1, 5, 5, 5, 5, 10, 10, 10, 10])
        """
        grid = np.asarray(grid, dtype=float)
        if grid.ndim != 1 or grid.size == 0:
            raise ValueError(f"grid must be a non-empty 1-D sequence of parameters, got shape {grid.shape}")
        G, M = grid.size, m.shape[1]
        copies = lambda a: np.concatenate([a] * G, axis=-1)  # noqa: E731
        model, rule = self.model, self.rule
        zt = z if callable(z) else copies(z)
        if model.H is not None or not (self.candidate_prefixes and rule.supports_prefixes):
            return self.update_rl(copies(m), copies(P), zt, t, np.repeat(grid, M), rng=rng, tile=G * tile)
        L, P = self.factor(sym(P), "P_pred", t)
        if rng is None:
            rng = self.rng(_UPDATE, t)
        mos = rule.moments_prefixes(self._wrap(model.h, t + 1), m, P, grid, residual=self._residual_rl(), rng=rng, L=L,
                                    tile=tile)
        cat = lambda arrays: np.concatenate(arrays, axis=-1)  # noqa: E731
        return self._finish_update(
            copies(m), copies(P), zt, t, cat([mo.mean for mo in mos]), cat([_plus_error(mo.cov, mo) for mo in mos]),
            cat([mo.cross for mo in mos]), cat([mo.n_iter for mo in mos]),
        )

    def _finish_update(self, m, P, z, t: int, z_pred, S, Pxz, n_iter) -> _UpdateRL:
        """The update from the measurement moments: ``S = Cov[h] (+ V_z)`` without ``R``; ``P`` already repaired."""
        model = self.model
        if self._nx == 1 and model.nz == 1 and model.residual is None and not callable(z):
            # a scalar state and measurement: the arithmetic below in one compiled pass, numpy's bits
            # (None: not compiled, or a step that raises or repairs below)
            done = scalar_kernels.update(m, P, z, z_pred, S, Pxz, self._R, model.nz * _LOG2PI)
            if done is not None:
                Pzz, _, K, innov, nis, loglik, x_filt, P_filt, L_filt = done
                u = _UpdateRL(z_pred, Pzz, Pxz, K, innov, nis, loglik, x_filt, P_filt, n_iter)
                u.L_filt = L_filt
                return u
        Pzz = sym_fresh(S + self._R)
        Lz, Pzz = self.factor(Pzz, "Pzz", t)
        if callable(z):
            z = z(z_pred, Lz)
        innov = z - z_pred if model.residual is None else self._residual_rl()(z, z_pred)
        if Lz.shape[0] == 1:  # solve_spd's 1x1 division, with L_zz^2 squared once for K and y
            Lz2 = Lz[0, 0] ** 2
            K = Pxz / Lz2  # (nx, nz, M)
            # the sum over one component, 0 + v (v / l^2), is v (v / l^2): it is never -0
            nis = innov[0] * (innov[0] / Lz2)
        else:
            K = solve_spd(Lz, Pxz.swapaxes(0, 1)).swapaxes(0, 1)  # (nx, nz, M)
            y = solve_spd(Lz, innov[:, None, :])[:, 0, :]
            nis = (innov * y).sum(axis=0)
        loglik = -0.5 * (nis + logdet_chol(Lz) + model.nz * _LOG2PI)
        x_filt = m + mv(K, innov)
        P_filt = sym_fresh(P - mm(mm(K, Pzz), K.swapaxes(0, 1)))
        if not np.isfinite(x_filt).all():
            raise FilterError("non-finite filtering mean x_filt", t, np.flatnonzero(~np.isfinite(x_filt).all(0)))
        # What the filter returns is a covariance: an indefinite P_filt (a negative centre weight, a
        # stochastic rule's bad draw) is an error naming the step, or repaired here and counted, so that
        # no stored covariance gives a negative NEES.
        L_filt, P_checked = self.factor(P_filt, "P_filt", t)
        u = _UpdateRL(z_pred, Pzz, Pxz, K, innov, nis, loglik, x_filt, P_checked, n_iter)
        if P_checked is P_filt:  # not repaired: L_filt is the factor of sym(P_filt) = P_filt
            u.L_filt = L_filt
        return u

    # ------------------------------------------------------------ public steps
    def predict(self, x_filt: np.ndarray, P_filt: np.ndarray, t: int) -> Prediction:
        """Predict step from ``t`` to ``t + 1``; ``x_filt (M, nx)``, ``P_filt (M, nx, nx)``."""
        m, P = self.predict_rl(_internal(x_filt), _internal(P_filt), t)
        return Prediction(_public(m), _public(P))

    def update(self, x_pred: np.ndarray, P_pred: np.ndarray, z: np.ndarray, t: int, param=None) -> Update:
        """Update step at ``t`` with ``z (M, nz)``; returns every quantity of Algorithm 1."""
        m, P = _internal(x_pred), _internal(P_pred)
        u = self.update_rl(m, P, _internal(z), t, param)
        return Update(
            x_pred=_public(m), P_pred=_public(P), z_pred=_public(u.z_pred), Pzz=_public(u.Pzz),
            Pxz=_public(u.Pxz), K=_public(u.K), innovation=_public(u.innovation), nis=u.nis,
            loglik=u.loglik, x_filt=_public(u.x_filt), P_filt=_public(u.P_filt), n_iter_spent=u.n_iter_spent,
        )

    # --------------------------------------------------------------------- run
    def check_z(self, z) -> np.ndarray:
        """Measurements as ``(M, T, nz)``; ValueError naming what is wrong."""
        z = np.asarray(z, dtype=float)
        nz = self.model.nz
        if z.ndim == 2 and nz == 1:
            z = z[:, :, None]
        if z.ndim != 3 or z.shape[2] != nz:
            raise ValueError(f"z must have shape (M, T, nz={nz}) (or (M, T) when nz = 1), got {z.shape}")
        # a finite sum has only finite terms (one pass, not two); an infinite one may be an overflow
        if not np.isfinite(z.sum()) and not np.isfinite(z).all():
            bad = np.argwhere(~np.isfinite(z).all(axis=2))[0]
            raise ValueError(f"z has non-finite values (first at run {bad[0]}, step {bad[1]})")
        return z

    def _param_schedule(self, params, M: int, T: int) -> np.ndarray:
        """The update parameter per run and step ``(M, T)``; one value is a read-only broadcast view
        (no ``M x T`` array to fill and check)."""
        if params is None:
            return np.broadcast_to(np.float64(self.param), (M, T))
        p = np.asarray(params, dtype=float)
        if p.ndim == 0:
            p = np.broadcast_to(np.float64(p), (M, T))
            self.rule.check_param(p[:1, :1], self.model.nx)  # one entry stands for all (the same message)
            return p
        if p.shape == (M,):
            p = np.repeat(p[:, None], T, axis=1)
        elif p.shape != (M, T):
            raise ValueError(f"params must be a scalar, (M,) = ({M},) or (M, T) = ({M}, {T}); got {p.shape}")
        self.rule.check_param(p, self.model.nx)
        return p

    def run(self, z, params=None, policy=None, keep_pred: bool = False, progress: bool = False) -> FilterRun:
        """Filter measurements ``z (M, T, nz)``.

        ``params`` (update-step parameter): scalar, one per run ``(M,)`` or one
        per run and step ``(M, T)``. ``policy``: a policy of
        :mod:`adaptfilt.policies` that picks the update parameter at every step
        from the information state (then ``params`` must be None).
        """
        z = self.check_z(z)
        if policy is not None:
            if params is not None:
                raise ValueError("give either params or policy, not both")
            if GaussianAssumedFilter.policy_runner is None:  # pragma: no cover - adaptfilt/__init__ imports mdp
                raise RuntimeError("import adaptfilt.mdp to run a filter with a policy")
            return GaussianAssumedFilter.policy_runner(self, z, policy, keep_pred=keep_pred, progress=progress)
        M, T, nx = z.shape[0], z.shape[1], self.model.nx
        sched = self._param_schedule(params, M, T)
        # one scalar parameter: no per-run weights
        const = sched.strides == (0, 0) or bool((sched == sched[0, 0]).all())
        mean = np.empty((T, nx, M))
        cov = np.empty((T, nx, nx, M))
        nis = np.empty((T, M))
        ll = np.empty((T, M))
        xp = np.empty((T, nx, M)) if keep_pred else None
        Pp = np.empty((T, nx, nx, M)) if keep_pred else None
        spent = np.zeros((2, T, M), dtype=int) if self.rule.stochastic else None  # predict, update
        pinfo: dict = {}
        self.n_repairs = 0
        m, P = self.initial(M)
        zt = np.ascontiguousarray(np.moveaxis(z, 0, -1))  # (T, nz, M)
        steps = range(T)
        if progress:
            from tqdm.auto import tqdm

            steps = tqdm(steps, desc=repr(self), leave=False)
        u = None
        for t in steps:
            if t:
                m, P = self.predict_rl(m, P, t - 1, info=pinfo, L=u.L_filt)
                if spent is not None and pinfo["n_iter"] is not None:
                    spent[0, t] = pinfo["n_iter"]
            if keep_pred:
                xp[t], Pp[t] = m, P
            param = sched[0, t] if const else sched[:, t]
            if t:  # predict_rl's P_pred is symmetric: sym(P_pred) = P_pred, bit for bit
                L, P = self.factor(P, "P_pred", t)
                u = self._update_factored(m, P, L, zt[t], t, param, None, 1)
            else:
                u = self.update_rl(m, P, zt[t], t, param)
            if spent is not None:
                spent[1, t] = u.n_iter_spent
            m, P = u.x_filt, u.P_filt
            mean[t], cov[t], nis[t], ll[t] = m, P, u.nis, u.loglik
        info = {} if spent is None else {"n_iter_spent": spent[1].T.copy(), "n_iter_spent_predict": spent[0].T.copy()}
        return FilterRun(
            mean=mean.transpose(2, 0, 1), cov=cov.transpose(3, 0, 1, 2), nis=nis.T, loglik=ll.T, params=sched,
            x_pred=None if xp is None else xp.transpose(2, 0, 1),
            P_pred=None if Pp is None else Pp.transpose(3, 0, 1, 2),
            n_repairs=self.n_repairs, info=info,
        )


class UKF(GaussianAssumedFilter):
    """Unscented Kalman filter: the GAF with Julier's unscented rule.

    ``kappa`` (default ``max(0, 3 - nx)``) is used in the predict step and is
    the default update parameter; ``run(z, params=kappa_t)`` adapts the update.
    ``n + kappa > 0`` is required (a ``ValueError`` otherwise).

    ``form`` chooses how covariances are taken (see
    :class:`~adaptfilt.rules.UnscentedRule`): ``"standard"`` (default, about
    the mean), ``"modified"`` (Julier and Uhlmann's form, about the
    transformed centre point ``g(m)``, positive semidefinite for any
    ``kappa``) or ``"auto"`` (modified only where ``kappa < 0``, i.e. where
    the centre weight is negative; identical to standard elsewhere).

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.ungm()
    >>> traj = model.simulate(n_runs=200, rng=np.random.default_rng(0))
    >>> run = af.UKF(model).run(traj.z)
    >>> rmse = af.metrics.rmse(traj.x, run.mean)   # (500,)
    >>> run = af.UKF(af.models.coordinated_turn(), kappa=-2.0, form="auto").run(
    ...     af.models.coordinated_turn().simulate(50, rng=0).z)
    >>> run.n_repairs  # the modified form keeps every covariance positive definite
    0
    """

    def __init__(
        self,
        model: StateSpaceModel,
        kappa: float | None = None,
        *,
        form: Literal["standard", "modified", "auto"] = "standard",
        on_indefinite: Literal["raise", "clip"] = "raise",
    ):
        super().__init__(model, UnscentedRule(form=form), param=kappa, on_indefinite=on_indefinite)

    def __repr__(self) -> str:
        r = super().__repr__()
        return r if self.rule.form == "standard" else r[:-1] + f", form={self.rule.form!r})"

    @property
    def kappa(self) -> float:
        return self.param


class CKF(GaussianAssumedFilter):
    """Cubature Kalman filter: the unscented rule at ``kappa = 0`` (Arasaratnam and Haykin)."""

    def __init__(self, model: StateSpaceModel, *, on_indefinite: Literal["raise", "clip"] = "raise"):
        super().__init__(model, UnscentedRule(default_kappa=0.0), param=0.0, on_indefinite=on_indefinite)


class SIF(GaussianAssumedFilter):
    """Stochastic integration filter: the GAF with the stochastic integration rule.

    ``n_iter`` draws of Genz and Monahan's stochastic rule are averaged per
    moment computation (default 10); ``seed`` makes runs reproducible.
    ``run(z, params=n_iter_t)`` adapts the update's iteration count.

    The keyword options select the variants of the authors' reference codes
    (:class:`~adaptfilt.rules.StochasticIntegrationRule` documents each):
    ``order`` (1, 3 or 5), ``passes`` (1: mean and covariances from the same
    draws; 2: the mean first, then the covariances about it from fresh draws),
    ``integration_error`` (add the estimated variance of the averaged mean to
    ``P_pred`` and ``Pzz``), and ``tol`` / ``n_min`` (stop each run once the
    estimated integration error is below ``tol``; ``n_iter`` is then the
    maximum; ``tol_predict`` for the predict step, default ``tol``).
    The defaults are the degree-3, one-pass, fixed-count rule without the
    error term (the NEF toolbox's form). The paper's experiments and ``data/``
    use ``passes=2, integration_error="diag"``, the degree-3 form tested draw
    for draw against Stone Soup; :meth:`SIF.reference` builds the authors'
    Stone Soup SIF with its defaults (degree 5, tolerance stopping). With a
    stochastic rule, ``FilterRun.info["n_iter_spent"]`` reports the iterations
    each run spent at each step.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.coordinated_turn()
    >>> traj = model.simulate(n_runs=100, rng=np.random.default_rng(0))
    >>> run = af.SIF(model, n_iter=10, seed=0).run(traj.z)
    >>> run.mean.shape
    (100, 150, 4)
    >>> run = af.SIF(model, n_iter=2, seed=0, integration_error=True, on_indefinite="clip").run(traj.z)
    >>> ref = af.SIF.reference(model, seed=0).run(traj.z)   # degree 5, 5..10 iterations
    >>> bool(((ref.info["n_iter_spent"] >= 10) & (ref.info["n_iter_spent"] <= 20)).all())  # two passes
    True
    """

    def __init__(
        self,
        model: StateSpaceModel,
        n_iter: int = 10,
        seed: int = 0,
        *,
        order: int = 3,
        passes: int = 1,
        integration_error: bool | str = False,
        tol: float | None = None,
        tol_predict: float | None = None,
        n_min: int = 1,
        on_indefinite: Literal["raise", "clip"] = "raise",
    ):
        opts = dict(order=order, passes=passes, integration_error=integration_error, n_min=n_min)
        rule = StochasticIntegrationRule(default_n_iter=n_iter, tol=tol, **opts)
        predict_rule = None
        if tol_predict is not None and tol_predict != tol:
            predict_rule = StochasticIntegrationRule(default_n_iter=n_iter, tol=tol_predict, **opts)
        super().__init__(model, rule, param=n_iter, seed=seed, on_indefinite=on_indefinite, predict_rule=predict_rule)

    @classmethod
    def reference(
        cls, model: StateSpaceModel, seed: int = 0, n_iter: int = 10, *, on_indefinite: Literal["raise", "clip"] = "raise"
    ) -> "SIF":
        """The SIF with Stone Soup's defaults (the authors' Python port): degree 5, two passes,
        the diagonal integration-error term, ``n_min = 5``, at most ``n_iter = 10``
        iterations, tolerance ``5e-4`` in the update and ``5e-3`` in the predict step."""
        return cls(model, n_iter=n_iter, seed=seed, order=5, passes=2, integration_error="diag",
                   tol=5e-4, tol_predict=5e-3, n_min=5, on_indefinite=on_indefinite)

    def __repr__(self) -> str:
        r, rule = super().__repr__(), self.rule
        opts = []
        if rule.order != 3:
            opts.append(f"order={rule.order}")
        if rule.passes != 1:
            opts.append(f"passes={rule.passes}")
        if rule.integration_error != "none":
            opts.append(f"integration_error={rule.integration_error!r}")
        if rule.tol is not None:
            opts += [f"tol={rule.tol:g}", f"n_min={rule.n_min}"]
        if self.predict_rule is not rule:
            opts.append(f"tol_predict={self.predict_rule.tol:g}")
        return r if not opts else r[:-1] + ", " + ", ".join(opts) + ")"

    @property
    def n_iter(self) -> int:
        return int(self.param)
