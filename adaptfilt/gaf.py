r"""The Gaussian-assumed filter (Algorithm 1 of the paper) and its front doors.

A GAF is one recursion plus a moment rule (:mod:`adaptfilt.rules`):

.. math::

    \hat x_{k|k-1} = E[f(x_{k-1})],\quad
    P_{k|k-1} = \mathrm{Cov}[f(x_{k-1})] + Q \qquad\text{(predict)}

    \hat z_{k|k-1} = E[h(x_k)],\quad P^{zz} = \mathrm{Cov}[h(x_k)] + R,\quad
    P^{xz} = \mathrm{Cov}[x_k, h(x_k)]

    K = P^{xz} (P^{zz})^{-1},\quad \tilde z = z_k - \hat z_{k|k-1},\quad
    \hat x_{k|k} = \hat x_{k|k-1} + K \tilde z,\quad
    P_{k|k} = P_{k|k-1} - K P^{zz} K^T \qquad\text{(update)}

with ``NIS = z~^T (P^{zz})^{-1} z~`` and log-likelihood
``log N(z~; 0, P^{zz})``. The UKF is the GAF with the unscented rule
(parameter ``kappa``), the SIF the GAF with the stochastic integration rule
(parameter ``n_iter``).

Everything is batched over Monte-Carlo runs; a parameter is a scalar or one
value per run. Only the update-step parameter is adapted (Section IV of the
paper): ``run(z, params=...)`` sets the update parameter, and the predict step
uses the filter's own parameter. When the model declares its dynamics linear
(``model.F``) the predict step is the exact Kalman predict.

Time convention: the prior is the predictive density of the first state, so
step ``t = 0`` is an update without a predict before it.

Numerics: covariances are symmetrised; a covariance that is not positive
definite (negative centre weights can do that) raises :class:`FilterError`
naming the quantity, the step and the runs, unless the filter was built with
``on_indefinite="clip"``, the documented opt-in repair that clips the offending
runs' eigenvalues and counts the repairs in ``FilterRun.n_repairs``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Literal

import numpy as np

from adaptfilt.linalg import NotPositiveDefinite, chol, clip_to_pd, logdet_chol, mm, mv, solve_spd, sym
from adaptfilt.models import StateSpaceModel
from adaptfilt.rules import MomentRule, StochasticIntegrationRule, UnscentedRule

__all__ = ["FilterError", "Prediction", "Update", "FilterRun", "GaussianAssumedFilter", "UKF", "SIF", "CKF"]

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


@dataclass
class FilterRun:
    """A filter run over ``M`` runs and ``T`` steps (public layout).

    ``mean (M, T, nx)`` and ``cov (M, T, nx, nx)`` are the filtering moments,
    ``nis``/``loglik`` ``(M, T)`` the per-step normalised innovation squared and
    measurement log-likelihood, ``params (M, T)`` the update-step parameter used.
    ``x_pred``/``P_pred`` are kept when the run was asked to (``keep_pred``).
    """

    mean: np.ndarray
    cov: np.ndarray
    nis: np.ndarray
    loglik: np.ndarray
    params: np.ndarray
    x_pred: np.ndarray | None = None
    P_pred: np.ndarray | None = None
    n_repairs: int = 0
    info: dict = field(default_factory=dict)

    @property
    def n_runs(self) -> int:
        return self.mean.shape[0]

    @property
    def n_steps(self) -> int:
        return self.mean.shape[1]


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

    def __init__(
        self,
        model: StateSpaceModel,
        rule: MomentRule,
        param: float | None = None,
        seed: int = 0,
        on_indefinite: Literal["raise", "clip"] = "raise",
    ):
        if not isinstance(model, StateSpaceModel):
            raise TypeError(f"model must be a StateSpaceModel, got {type(model).__name__}")
        if on_indefinite not in ("raise", "clip"):
            raise ValueError(f"on_indefinite must be 'raise' or 'clip', got {on_indefinite!r}")
        self.model = model
        self.rule = rule
        self.param = float(rule.default_param(model.nx) if param is None else param)
        rule.check_param(self.param, model.nx)
        self.seed = int(seed)
        self.on_indefinite = on_indefinite
        self.n_repairs = 0
        nx = model.nx
        self._Q = model.Q[:, :, None]
        self._R = model.R[:, :, None]
        self._m0 = model.m0[:, None]
        self._P0 = model.P0[:, :, None]
        self._nx = nx

    # ---------------------------------------------------------------- helpers
    def __repr__(self) -> str:
        return f"{type(self).__name__}(model={self.model.name!r}, {self.rule.param_name}={self.param:g})"

    def rng(self, stage: int, t: int, stream: int | None = None) -> np.random.Generator | None:
        """The random numbers of a stochastic rule at ``(stage, t)`` (stage 0 =
        predict, 1 = update); ``stream`` separates e.g. training episodes."""
        if not self.rule.stochastic:
            return None
        return np.random.default_rng([self.seed, stage, t] + ([] if stream is None else [int(stream)]))

    def _wrap(self, fn: Callable, k: int) -> Callable[[np.ndarray], np.ndarray]:
        # model functions take (..., n); the filter holds (n, ..., M)
        return lambda X: np.moveaxis(np.asarray(fn(np.moveaxis(X, 0, -1), k)), -1, 0)

    def _residual_rl(self):
        r = self.model.residual
        if r is None:
            return None
        return lambda a, b: np.moveaxis(r(np.moveaxis(a, 0, -1), np.moveaxis(b, 0, -1)), -1, 0)

    def _chol(self, P: np.ndarray, quantity: str, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Cholesky factor, or FilterError / documented repair."""
        try:
            return chol(P, quantity), P
        except NotPositiveDefinite as e:
            if self.on_indefinite == "raise":
                raise FilterError(f"{quantity} is not positive definite", t, e.runs) from None
            self.n_repairs += int(e.runs.size)
            P = clip_to_pd(P, e.runs)
            return chol(P, quantity), P

    def initial(self, n_runs: int) -> tuple[np.ndarray, np.ndarray]:
        """Prior mean and covariance broadcast over runs, run axis last."""
        return (np.repeat(self._m0, n_runs, axis=1), np.repeat(self._P0, n_runs, axis=2))

    # ------------------------------------------------------------- run-last core
    def predict_rl(
        self, m: np.ndarray, P: np.ndarray, t: int, rng: np.random.Generator | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predict from step ``t`` to ``t + 1``; ``m (nx, M)``, ``P (nx, nx, M)``."""
        model = self.model
        if model.F is not None:
            F = model.F[:, :, None]
            m_pred = mv(F, m)
            P_pred = mm(mm(F, P), F.swapaxes(0, 1)) + self._Q
        else:
            L, P = self._chol(sym(P), "P_filt", t)
            mo = self.rule.moments(self._wrap(model.f, t + 1), m, P, self.param, rng=self.rng(_PREDICT, t) if rng is None else rng, L=L, cross=False)
            m_pred, P_pred = mo.mean, mo.cov + self._Q
        if not np.isfinite(m_pred).all():
            raise FilterError("non-finite predicted mean x_pred", t + 1, np.flatnonzero(~np.isfinite(m_pred).all(0)))
        return m_pred, sym(P_pred)

    def update_rl(
        self,
        m: np.ndarray,
        P: np.ndarray,
        z: np.ndarray,
        t: int,
        param=None,
        rng: np.random.Generator | None = None,
    ) -> _UpdateRL:
        """Update at step ``t`` with ``z (nz, M)``; ``param`` scalar or ``(M,)``."""
        model = self.model
        param = self.param if param is None else param
        L, P = self._chol(sym(P), "P_pred", t)
        if model.H is not None:
            H = model.H[:, :, None]
            z_pred = mv(H, m)
            Pxz = mm(P, H.swapaxes(0, 1))
            S = mm(H, Pxz)
        else:
            if rng is None:
                rng = self.rng(_UPDATE, t)
            mo = self.rule.moments(self._wrap(model.h, t + 1), m, P, param, residual=self._residual_rl(), rng=rng, L=L)
            z_pred, S, Pxz = mo.mean, mo.cov, mo.cross
        Pzz = sym(S + self._R)
        Lz, Pzz = self._chol(Pzz, "Pzz", t)
        innov = z - z_pred if model.residual is None else self._residual_rl()(z, z_pred)
        K = solve_spd(Lz, Pxz.swapaxes(0, 1)).swapaxes(0, 1)  # (nx, nz, M)
        y = solve_spd(Lz, innov[:, None, :])[:, 0, :]
        nis = (innov * y).sum(axis=0)
        loglik = -0.5 * (nis + logdet_chol(Lz) + model.nz * _LOG2PI)
        x_filt = m + mv(K, innov)
        P_filt = sym(P - mm(mm(K, Pzz), K.swapaxes(0, 1)))
        if not np.isfinite(x_filt).all():
            raise FilterError("non-finite filtering mean x_filt", t, np.flatnonzero(~np.isfinite(x_filt).all(0)))
        return _UpdateRL(z_pred, Pzz, Pxz, K, innov, nis, loglik, x_filt, P_filt)

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
            loglik=u.loglik, x_filt=_public(u.x_filt), P_filt=_public(u.P_filt),
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
        if not np.isfinite(z).all():
            bad = np.argwhere(~np.isfinite(z).all(axis=2))[0]
            raise ValueError(f"z has non-finite values (first at run {bad[0]}, step {bad[1]})")
        return z

    def _param_schedule(self, params, M: int, T: int) -> np.ndarray:
        if params is None:
            return np.full((M, T), self.param)
        p = np.asarray(params, dtype=float)
        if p.ndim == 0:
            p = np.full((M, T), float(p))
        elif p.shape == (M,):
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
            from adaptfilt.mdp import run_policy

            return run_policy(self, z, policy, keep_pred=keep_pred, progress=progress)
        M, T, nx = z.shape[0], z.shape[1], self.model.nx
        sched = self._param_schedule(params, M, T)
        const = bool((sched == sched[0, 0]).all())  # one scalar parameter: no per-run weights
        mean = np.empty((T, nx, M))
        cov = np.empty((T, nx, nx, M))
        nis = np.empty((T, M))
        ll = np.empty((T, M))
        xp = np.empty((T, nx, M)) if keep_pred else None
        Pp = np.empty((T, nx, nx, M)) if keep_pred else None
        self.n_repairs = 0
        m, P = self.initial(M)
        zt = np.ascontiguousarray(np.moveaxis(z, 0, -1))  # (T, nz, M)
        steps = range(T)
        if progress:
            from tqdm.auto import tqdm

            steps = tqdm(steps, desc=repr(self), leave=False)
        for t in steps:
            if t:
                m, P = self.predict_rl(m, P, t - 1)
            if keep_pred:
                xp[t], Pp[t] = m, P
            u = self.update_rl(m, P, zt[t], t, sched[0, t] if const else sched[:, t])
            m, P = u.x_filt, u.P_filt
            mean[t], cov[t], nis[t], ll[t] = m, P, u.nis, u.loglik
        return FilterRun(
            mean=mean.transpose(2, 0, 1), cov=cov.transpose(3, 0, 1, 2), nis=nis.T, loglik=ll.T, params=sched,
            x_pred=None if xp is None else xp.transpose(2, 0, 1),
            P_pred=None if Pp is None else Pp.transpose(3, 0, 1, 2),
            n_repairs=self.n_repairs,
        )


class UKF(GaussianAssumedFilter):
    """Unscented Kalman filter: the GAF with Julier's unscented rule.

    ``kappa`` (default ``max(0, 3 - nx)``) is used in the predict step and is
    the default update parameter; ``run(z, params=kappa_t)`` adapts the update.
    ``n + kappa > 0`` is required (a ``ValueError`` otherwise).

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.ungm()
    >>> traj = model.simulate(n_runs=200, rng=np.random.default_rng(0))
    >>> run = af.UKF(model).run(traj.z)
    >>> rmse = af.metrics.rmse(traj.x, run.mean)   # (500,)
    """

    def __init__(self, model: StateSpaceModel, kappa: float | None = None, *, on_indefinite: Literal["raise", "clip"] = "raise"):
        super().__init__(model, UnscentedRule(), param=kappa, on_indefinite=on_indefinite)

    @property
    def kappa(self) -> float:
        return self.param


class CKF(GaussianAssumedFilter):
    """Cubature Kalman filter: the unscented rule at ``kappa = 0`` (Arasaratnam and Haykin)."""

    def __init__(self, model: StateSpaceModel, *, on_indefinite: Literal["raise", "clip"] = "raise"):
        super().__init__(model, UnscentedRule(default_kappa=0.0), param=0.0, on_indefinite=on_indefinite)


class SIF(GaussianAssumedFilter):
    """Stochastic integration filter: the GAF with the stochastic integration rule.

    ``n_iter`` independent draws of Genz-Monahan's degree-3 stochastic rule are
    averaged per moment computation (default 10); ``seed`` makes runs
    reproducible. ``run(z, params=n_iter_t)`` adapts the update's iteration count.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.coordinated_turn()
    >>> traj = model.simulate(n_runs=100, rng=np.random.default_rng(0))
    >>> run = af.SIF(model, n_iter=10, seed=0).run(traj.z)
    >>> run.mean.shape
    (100, 150, 4)
    """

    def __init__(
        self, model: StateSpaceModel, n_iter: int = 10, seed: int = 0, *, on_indefinite: Literal["raise", "clip"] = "raise"
    ):
        super().__init__(model, StochasticIntegrationRule(default_n_iter=n_iter), param=n_iter, seed=seed, on_indefinite=on_indefinite)

    @property
    def n_iter(self) -> int:
        return int(self.param)
