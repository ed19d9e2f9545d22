r"""One-step costs ``L(s_t, z_t, theta_t)`` of the parameter MDPs, and the transform a learner sees.

A cost is anything that meets :class:`StepCost`: a ``name`` (what results and policy files record),
a ``compute_weight`` (the price of one unit of the parameter's compute, what an evaluation charges a
policy's extra computation at), ``needs_truth`` (whether it reads the true state, which only a simulation
has: the environment then hands it over, and refuses candidate features that would leak it) and
``cost(update, theta, nz) -> (M,)``, where ``update`` is what the environment's step made (``info["update"]``). A new cost is a class here, or a :class:`FunctionCost`
around a function; an environment takes any of them.

The costs of Section VI-D, as functions (:func:`nis_cost`, :func:`logmaxnis_cost`, :func:`stateinnov_cost`); the
NIS-type ones are read by both families:

* :class:`Cost`, for a Gaussian-assumed filter's update (:class:`~adaptfilt.mdp.FilterEnv`):
  ``"nis"`` ``(NIS - nz)^2``, ``"logmaxnis"`` ``log(1 + max(0, NIS - nz))``, ``"stateinnov"``
  ``||K z~||``, ``"sqerr"`` ``||x_filt - x||^2`` against the true state (beyond the paper: a cost only
  a simulation can pay; the environment hands it the truth, :attr:`Cost.needs_truth`), plus
  ``compute_weight * theta`` (the paper's ``n_iter / 50``);
* :class:`ParticleCost`, for a particle filter's update with ``N`` particles
  (:class:`~adaptfilt.particle_env.ParticleCountEnv`): the same NIS-type costs of the Gaussian fit of
  the predicted measurement, ``"stateinnov"`` as the update's move of the mean, ``"sqerr"``
  ``||x_filt - x||^2`` against the truth, plus ``price * N``.

:func:`transform_cost` is the cost a learner's networks see (``sign(L) log(1 + |L|)``).

>>> import numpy as np
>>> nis_cost(np.array([1.0, 4.0]), nz=1).tolist(), Cost("stateinnov", 1 / 50).name
([0.0, 9.0], 'stateinnov+n_iter/50')
>>> isinstance(FunctionCost("abs-nis", lambda u, nz: abs(u.nis - nz)), StepCost)
True
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal, Protocol, runtime_checkable

import numpy as np

__all__ = ["StepCost", "Cost", "ParticleCost", "FunctionCost", "nis_cost", "logmaxnis_cost", "stateinnov_cost",
           "gaussian_nll", "NIS_COSTS", "transform_cost"]


@runtime_checkable
class StepCost(Protocol):
    """What an environment asks of its cost (:class:`~adaptfilt.paramenv.ParamEnv`'s ``cost``)."""

    @property
    def name(self) -> str: ...

    @property
    def compute_weight(self) -> float: ...

    @property
    def needs_truth(self) -> bool: ...

    def __call__(self, update: Any, theta: np.ndarray, nz: int) -> np.ndarray: ...


def nis_cost(nis: np.ndarray, nz: int) -> np.ndarray:
    """``L_NIS = (NIS - nz)^2``: how far the normalised innovation squared is from its mean."""
    return (nis - nz) ** 2


def logmaxnis_cost(nis: np.ndarray, nz: int) -> np.ndarray:
    """``L_logmaxNIS = log(1 + max(0, NIS - nz))``: overconfidence only, compressed."""
    return np.log1p(np.maximum(0.0, nis - nz))


def stateinnov_cost(K: np.ndarray, innovation: np.ndarray) -> np.ndarray:
    """``L_stateInnov = ||K z~||``: the size of the correction the update applies to the mean, per run
    (run-last: ``K (nx, nz, M)``, ``innovation (nz, M)``)."""
    dx = np.einsum("ijM,jM->iM", K, innovation)
    return np.sqrt((dx * dx).sum(axis=0))


def gaussian_nll(e: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``e^T P^{-1} e + log det P`` per run (run-last: ``e (nx, M)``, ``P (nx, nx, M)``): twice the Gaussian
    negative log-likelihood of an error ``e`` under the covariance ``P``, less its constant ``nx log 2 pi``.
    ValueError naming the first run whose ``P`` is not positive definite.

    >>> gaussian_nll(np.array([[2.0]]), np.array([[[4.0]]])).round(4).tolist()   # 1 + log 4
    [2.3863]
    """
    Pm = np.moveaxis(np.asarray(P, dtype=float), -1, 0)  # (M, nx, nx)
    em = np.asarray(e, dtype=float).T[..., None]          # (M, nx, 1)
    sign, logdet = np.linalg.slogdet(Pm)
    bad = ~(sign > 0) | ~np.isfinite(logdet)
    if bad.any():
        raise ValueError(f"the negative log-likelihood needs a positive definite covariance: run {int(np.argmax(bad))} "
                         f"has P_filt = {Pm[int(np.argmax(bad))].tolist()}")
    nees = (em * np.linalg.solve(Pm, em)).sum(axis=(1, 2))
    return nees + logdet


#: The NIS-type estimation costs by kind: both cost families read them from here.
NIS_COSTS: dict[str, Callable[[np.ndarray, int], np.ndarray]] = {"nis": nis_cost, "logmaxnis": logmaxnis_cost}


def _check_weight(label: str, w: float) -> None:
    if not (np.isfinite(w) and w >= 0):
        raise ValueError(f"{label} must be finite and >= 0, got {w}")


def _check_kind(kind: str, kinds: tuple[str, ...]) -> None:
    if kind not in kinds:
        raise ValueError(f"unknown cost {kind!r}: choose {', '.join(repr(k) for k in kinds[:-1])} or {kinds[-1]!r}")


@dataclass(frozen=True)
class Cost:
    """One-step cost ``L(s, z, theta)`` of Section VI-D for a Gaussian-assumed filter's update.

    ``kind``: ``"nis"`` (``(NIS - nz)^2``), ``"logmaxnis"``
    (``log(1 + max(0, NIS - nz))``), ``"stateinnov"`` (``||K z~||``) or ``"sqerr"``
    (``||x_{t|t} - x_t||^2``, the squared error of the update's mean against the true state ``x_t``:
    beyond the paper, for the learned-gain study (``adaptfilt beyond --studies gain``), where the kappa
    policy is trained on the objective supervised KalmanNet is trained on); ``compute_weight`` adds
    ``weight * theta`` (the iteration count of the SIF).

    ``nll_weight`` (``"sqerr"`` only; beyond the paper, the learned-gain study's consistency arm) adds
    ``w`` times the Gaussian negative log-likelihood of the true state under the filter's claim
    ``N(x_{t|t}, P_{t|t})``, up to its constant: ``||e||^2 + w (e^T P^{-1} e + log det P)``, the NEES plus
    the log-determinant. For a given mean its expectation over the error is smallest when ``P_{t|t}``
    equals the error's covariance (``E[e^T P^{-1} e] + log det P`` with ``P = c C`` is
    ``nx / c + nx log c + const``, smallest at ``c = 1``), so unlike a penalty on ``(NEES - nx)^2``,
    which an inflated covariance lowers, it rewards a covariance that is right, neither too small nor too
    large. A covariance that is not positive definite is a ValueError naming the run.

    Only ``"sqerr"`` reads the truth (:attr:`needs_truth`): :class:`~adaptfilt.mdp.FilterEnv` then passes
    ``truth (nx, M)``, the true state of the step, run-last as the update; the other kinds are called
    exactly as before, without it. A policy trained on ``"sqerr"`` still sees only its information state.
    Its greedy baseline (the argmin of the one-step cost over the grid) reads the truth: an oracle, not
    a filter.

    >>> Cost("nis").name, Cost("stateinnov", 1 / 50).name, Cost("sqerr").needs_truth
    ('nis', 'stateinnov+n_iter/50', True)
    >>> Cost("sqerr", nll_weight=0.1).name
    'sqerr+0.1*nll'
    """

    kind: Literal["nis", "logmaxnis", "stateinnov", "sqerr"] = "nis"
    compute_weight: float = 0.0
    nll_weight: float = 0.0

    KINDS = ("nis", "logmaxnis", "stateinnov", "sqerr")

    def __post_init__(self):
        _check_kind(self.kind, self.KINDS)
        _check_weight("compute_weight", self.compute_weight)
        _check_weight("nll_weight", self.nll_weight)
        if self.nll_weight and self.kind != "sqerr":
            raise ValueError(f"nll_weight adds the true state's negative log-likelihood: it needs kind='sqerr', "
                             f"got {self.kind!r}")

    @property
    def name(self) -> str:
        if self.nll_weight:
            return f"{self.kind}+{self.nll_weight:g}*nll"
        if self.compute_weight == 0:
            return self.kind
        inv = 1.0 / self.compute_weight
        w = f"n_iter/{inv:g}" if abs(inv - round(inv)) < 1e-9 else f"{self.compute_weight:g}*n_iter"
        return f"{self.kind}+{w}"

    @property
    def needs_truth(self) -> bool:
        """Whether the cost reads the true state (``"sqerr"``): the environment then passes ``truth=``."""
        return self.kind == "sqerr"

    def estimation_cost(self, u, nz: int, truth: np.ndarray | None = None) -> np.ndarray:
        """The estimation part of the cost, per run, of an update ``u`` (run-last: ``nis (M,)``,
        ``K (nx, nz, M)``, ``innovation (nz, M)``, ``x_filt (nx, M)``); ``truth (nx, M)``: the true
        state, read by ``"sqerr"`` only (ValueError when it is missing or not finite)."""
        if self.kind in NIS_COSTS:
            return NIS_COSTS[self.kind](u.nis, nz)
        if self.kind == "sqerr":
            if truth is None:
                raise ValueError("the 'sqerr' cost needs the true state: call it with truth= (nx, M) "
                                 "(a FilterEnv does, from its trajectory's x)")
            truth = np.asarray(truth, dtype=float)
            if truth.shape != u.x_filt.shape:
                raise ValueError(f"the 'sqerr' cost: truth must be run-last (nx, M) = {u.x_filt.shape}, got {truth.shape}")
            if not np.all(np.isfinite(truth)):
                raise ValueError("the 'sqerr' cost needs the true states (simulate, or replay a trajectory with x); "
                                 "got non-finite ones")
            e = u.x_filt - truth
            c = (e * e).sum(axis=0)
            return c + self.nll_weight * gaussian_nll(e, u.P_filt) if self.nll_weight else c
        return stateinnov_cost(u.K, u.innovation)

    def __call__(self, u, theta: np.ndarray, nz: int, truth: np.ndarray | None = None) -> np.ndarray:
        """Cost per run of update ``u`` made with parameter(s) ``theta`` (``truth``: see :meth:`estimation_cost`)."""
        c = self.estimation_cost(u, nz, truth)
        return c + self.compute_weight * np.asarray(theta, dtype=float) if self.compute_weight else c


@dataclass(frozen=True)
class ParticleCost:
    r"""One-step cost of a particle filter's update with ``N`` particles, plus ``price * N``.

    From the ``N`` predicted particles, the predicted measurement is fitted by a Gaussian
    (:math:`\tilde z = \overline{z - h(x_j)}`, :math:`S = \mathrm{cov}(z - h(x_j)) + R`) so that the
    paper's costs read as for a Gaussian filter: ``"nis"`` ``(NIS - nz)^2``, ``"logmaxnis"``
    ``log(1 + max(0, NIS - nz))``, ``"stateinnov"`` the update's move of the mean
    ``||x_filt - x_pred||`` (the particle form of ``||K z~||``). ``"sqerr"`` is
    ``||x_filt - x||^2`` against the true state: a cost only a simulation can pay (training in
    simulation knows the truth; the policy still sees only the information state). The update ``u``
    is a :class:`~adaptfilt.particle_env.ParticleUpdate` (run-first: ``nis (M,)``, ``dx``, ``err (M, nx)``).

    >>> ParticleCost("logmaxnis", price=1e-4).name
    'logmaxnis+1e-04*N'
    """

    kind: Literal["nis", "logmaxnis", "stateinnov", "sqerr"] = "logmaxnis"
    price: float = 0.0

    KINDS = ("nis", "logmaxnis", "stateinnov", "sqerr")

    def __post_init__(self):
        _check_kind(self.kind, self.KINDS)
        _check_weight("price", self.price)

    @property
    def compute_weight(self) -> float:
        """The price of one particle: what :func:`~adaptfilt.evaluation.evaluate` charges ``extra_spent`` at."""
        return self.price

    @property
    def name(self) -> str:
        return self.kind if self.price == 0 else f"{self.kind}+{self.price:.0e}*N"

    @property
    def needs_truth(self) -> bool:
        """Whether the cost reads the true state (``"sqerr"``: the particle update carries the error itself)."""
        return self.kind == "sqerr"

    def estimation_cost(self, u, nz: int) -> np.ndarray:
        if self.kind in NIS_COSTS:
            return NIS_COSTS[self.kind](u.nis, nz)
        if self.kind == "stateinnov":
            return np.sqrt((u.dx * u.dx).sum(axis=1))
        if not np.all(np.isfinite(u.err)):
            raise ValueError("the 'sqerr' cost needs the true states (simulate, or replay a trajectory with x)")
        return (u.err * u.err).sum(axis=1)

    def __call__(self, u, theta: np.ndarray, nz: int, truth: np.ndarray | None = None) -> np.ndarray:
        """Cost per run of update ``u`` with ``theta`` particles; ``truth`` is not read: the particle update
        carries the estimate's error itself (``u.err``), which ``"sqerr"`` reads."""
        c = self.estimation_cost(u, nz)
        return c + self.price * np.asarray(theta, dtype=float) if self.price else c


@dataclass(frozen=True)
class FunctionCost:
    """A cost of one's own from a function ``fn(update, nz) -> (M,)`` of the step's update (what the
    environment's ``info["update"]`` holds), plus ``compute_weight * theta``. ``name`` is what results
    and policy files record, so give each function its own. ``needs_truth``: ``fn(update, nz, truth)``
    reads the true state too (a :class:`~adaptfilt.mdp.FilterEnv` passes it run-last, ``(nx, M)``)."""

    name: str
    fn: Callable[..., np.ndarray]
    compute_weight: float = 0.0
    needs_truth: bool = False

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"a FunctionCost needs a non-empty name, got {self.name!r}")
        if not callable(self.fn):
            raise TypeError(f"fn must be callable (update, nz) -> cost per run, got {type(self.fn).__name__}")
        _check_weight("compute_weight", self.compute_weight)

    def __call__(self, u, theta: np.ndarray, nz: int, truth: np.ndarray | None = None) -> np.ndarray:
        if self.needs_truth and truth is None:
            raise ValueError(f"the cost {self.name!r} needs the true state: call it with truth= (a FilterEnv does)")
        c = np.asarray(self.fn(u, nz, truth) if self.needs_truth else self.fn(u, nz), dtype=float)
        return c + self.compute_weight * np.asarray(theta, dtype=float) if self.compute_weight else c


def transform_cost(cost: np.ndarray, kind: str) -> np.ndarray:
    """The cost the networks learn from: ``sign(L) log(1 + |L|)`` or ``L``."""
    if kind == "log1p":
        return np.sign(cost) * np.log1p(np.abs(cost))
    if kind == "none":
        return cost
    raise ValueError(f"unknown cost_transform {kind!r}: choose 'log1p' or 'none'")
