r"""The filter as a declared interface: :class:`FilterRun`, :class:`Filter` and its check, :func:`check_filter`.

Every filter of the library meets :class:`Filter`: the Gaussian-assumed filters (:mod:`adaptfilt.gaf`:
``GaussianAssumedFilter``, ``UKF``, ``SIF``, ``CKF``), the exact references (:mod:`adaptfilt.exact`:
``KalmanFilter``, ``PointMassFilter``, ``BootstrapParticleFilter``), the particle filter with a count per
run and step (:class:`~adaptfilt.particles.ParticleCountFilter`, at a given count) and the learned gain
(:class:`~adaptfilt.kalmannet.KalmanNet`). :func:`~adaptfilt.evaluation.evaluate` runs any of them on an
evaluation's paired runs beside the policies (``filters={name: filter}``), so a new reference filter or
a new learned filter is a class that meets it (and passes :func:`check_filter`), not a copy of the
evaluation.

=======================  =======================================================================
member                   meaning
=======================  =======================================================================
``model``                the :class:`~adaptfilt.models.StateSpaceModel` it filters with (``nx``, ``nz``)
``run(z) -> FilterRun``  filter ``z (M, T, nz)``: the same ``z`` and the filter's own seed give the same
                         numbers, bit for bit (what paired evaluations rest on); ``z`` is not written
``repr(filter)``         what results record: the class and its settings, not an address
``param_name``           optional: the parameter ``run(z).params`` holds (``"kappa"``, ``"n_iter"``,
                         ``"n_particles"``); absent or None: none that an environment chooses
=======================  =======================================================================

**What a filter without a covariance returns** (declared here once): ``cov`` all NaN
(:func:`has_covariance` is False), and then ``nis`` all NaN too (no innovation covariance). Plain
KalmanNet is one: its ANEES and NEES-based divergence are *n/a* wherever it is evaluated. A filter
with a covariance has a finite, symmetric, positive semi-definite one; a filter that has no NIS (a
particle or point-mass filter: no Gaussian predicted measurement) returns ``nis`` all NaN, and
``loglik`` all NaN where it has no likelihood. ``params`` is NaN where the filter has no
``param_name``.

>>> import numpy as np, adaptfilt as af
>>> model = af.models.linear_gaussian(F=[[0.9]], H=[[1.0]], Q=[[0.1]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
>>> check_filter(af.KalmanFilter(model))
>>> isinstance(af.UKF(model), Filter), has_covariance(af.KalmanFilter(model).run(np.zeros((2, 3, 1))))
(True, True)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["FilterRun", "Filter", "FilterCheckError", "check_filter", "has_covariance", "has_nis"]


@dataclass
class FilterRun:
    """A filter run over ``M`` runs and ``T`` steps (public layout).

    ``mean (M, T, nx)`` and ``cov (M, T, nx, nx)`` are the filtering moments (``cov`` all NaN: the filter
    has none, module docstring), ``nis``/``loglik`` ``(M, T)`` the per-step normalised innovation squared
    and measurement log-likelihood, ``params (M, T)`` the update-step parameter used (read-only when it is
    one value for all runs and steps; NaN for a filter without one). ``x_pred``/``P_pred`` are kept when
    the run was asked to (``keep_pred``). With a stochastic rule, ``info["n_iter_spent"]`` and
    ``info["n_iter_spent_predict"]`` ``(M, T)`` hold the iterations each run spent in each update and
    predict step (0 where nothing was drawn: the first step's predict, exact linear steps).
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


@runtime_checkable
class Filter(Protocol):
    """A filter of the library (see the module docstring): ``model``, ``run(z) -> FilterRun``, a ``repr``."""

    model: Any

    def run(self, z: np.ndarray) -> FilterRun: ...


def has_covariance(run: FilterRun) -> bool:
    """Whether ``run`` holds a covariance: False when ``cov`` is all NaN (the declared "none")."""
    cov = run.cov
    return cov is not None and not (np.isnan(cov.flat[0]) and np.isnan(cov).all())


def has_nis(run: FilterRun) -> bool:
    """Whether ``run`` holds a NIS: False when ``nis`` is all NaN (no innovation covariance)."""
    return not np.isnan(run.nis).all()


class FilterCheckError(ValueError):
    """A filter breaks the :class:`Filter` contract; the message names the filter and the broken rule."""


def check_filter(filt: Any, model: Any = None, n_runs: int = 4, n_steps: int = 6, seed: int = 0,
                 **run_kwargs: Any) -> None:
    """Check that ``filt`` meets the :class:`Filter` contract; :class:`FilterCheckError` naming the first
    rule it breaks (as :func:`~adaptfilt.paramenv.check_env` does for an environment).

    It simulates ``n_runs`` runs of ``n_steps`` steps of ``model`` (default ``filt.model``; seeded by
    ``seed``), runs the filter on them twice (``run_kwargs`` go to ``run``: a
    :class:`~adaptfilt.particles.ParticleCountFilter` takes its count, ``n_particles=100``), and checks:
    the members exist, ``model`` has the simulated model's ``nx`` and ``nz``, ``repr`` is the filter's
    settings (not ``<... object at 0x...>``), ``run`` returns a :class:`FilterRun` of the public shapes
    and leaves ``z`` as it was, ``mean`` is finite, ``cov`` is finite, symmetric and positive
    semi-definite or all NaN (no covariance), ``nis`` is finite and non-negative or all NaN (all NaN
    without a covariance), ``loglik`` is finite or all NaN, ``params`` is finite where the filter
    declares ``param_name``, and the second run gives the same numbers bit for bit.
    """
    name = type(filt).__name__

    def fail(what: str) -> FilterCheckError:
        return FilterCheckError(f"{name}: {what}")

    has = {"model": hasattr(filt, "model"), "run": callable(getattr(filt, "run", None))}
    lacks = [m for m, ok in has.items() if not ok]
    if lacks:
        raise fail(f"missing member(s) of the Filter interface: {', '.join(lacks)}")
    model = filt.model if model is None else model
    for dim in ("nx", "nz"):
        if getattr(filt.model, dim, None) != getattr(model, dim):
            raise fail(f"its model has {dim} = {getattr(filt.model, dim, None)!r}, the model it is checked on "
                       f"{getattr(model, dim)!r}")
    text = repr(filt)
    if not isinstance(text, str) or not text or " object at 0x" in text:
        raise fail(f"repr is {text!r}: define __repr__ as the filter's class and settings (results record it)")
    z = model.simulate(n_runs, n_steps, rng=np.random.default_rng(seed)).z
    z_seen = z.copy()
    first = filt.run(z, **run_kwargs)
    if not np.array_equal(z, z_seen):
        raise fail("run(z) changed z: a filter must not write its input")
    _check_run(first, filt, model, n_runs, n_steps, fail)
    again = filt.run(z.copy(), **run_kwargs)
    for k in ("mean", "cov", "nis", "loglik", "params"):
        if not np.array_equal(getattr(first, k), getattr(again, k), equal_nan=True):
            raise fail(f"run(z) twice gave different {k}: the same z and seed must give the same numbers, bit "
                       "for bit (draw from the filter's own seed, not from a generator that moves on)")


def _check_run(run: Any, filt: Any, model: Any, M: int, T: int, fail) -> None:
    if not isinstance(run, FilterRun):
        raise fail(f"run(z) must return a FilterRun, got {type(run).__name__}")
    nx = model.nx
    shapes = {"mean": (M, T, nx), "cov": (M, T, nx, nx), "nis": (M, T), "loglik": (M, T), "params": (M, T)}
    for k, shape in shapes.items():
        if np.shape(getattr(run, k)) != shape:
            raise fail(f"run(z).{k} must have shape {shape}, got {np.shape(getattr(run, k))}")
    if not np.isfinite(run.mean).all():
        raise fail("run(z).mean is not finite on runs of its own model")
    cov = np.asarray(run.cov, dtype=float)
    if has_covariance(run):
        if not np.isfinite(cov).all():
            raise fail("run(z).cov must be finite, or all NaN for a filter without a covariance")
        if not np.allclose(cov, np.swapaxes(cov, -1, -2), rtol=1e-9, atol=0.0):
            raise fail("run(z).cov is not symmetric")
        low = np.linalg.eigvalsh(cov).min(axis=-1)
        scale = np.abs(cov).max(axis=(-2, -1))
        if (low < -1e-9 * np.maximum(scale, 1e-300)).any():
            raise fail(f"run(z).cov is not positive semi-definite (an eigenvalue {low.min():.3g})")
    elif has_nis(run):
        raise fail("run(z).cov is all NaN (no covariance) but nis is not: without a covariance there is no "
                   "innovation covariance, and nis must be all NaN")
    if has_nis(run) and not (np.isfinite(run.nis).all() and (run.nis >= 0).all()):
        raise fail("run(z).nis must be finite and non-negative, or all NaN")
    if not (np.isfinite(run.loglik).all() or np.isnan(run.loglik).all()):
        raise fail("run(z).loglik must be finite, or all NaN")
    if getattr(filt, "param_name", None) is not None and not np.isfinite(run.params).all():
        raise fail(f"it declares param_name = {filt.param_name!r}, but run(z).params is not finite")
