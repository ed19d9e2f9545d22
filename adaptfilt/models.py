r"""State-space models: ``x_{k+1} = f(x_k, k) + w_k``, ``z_k = h(x_k, k) + v_k``.

Time convention (DESIGN.md): the prior ``N(m0, P0)`` is the predictive density
of the first state ``x_1``; arrays are indexed ``t = 0..T-1`` for the paper's
``k = 1..T``. The model functions receive the paper's index ``k = t + 1`` of
the state they are given: ``f(x, k)`` maps ``x_k`` to the mean of ``x_{k+1}``
and ``h(x, k)`` gives the mean of ``z_k``.

``f`` and ``h`` are batched: ``x`` has shape ``(..., nx)`` with any leading
axes, and they return ``(..., nx)`` / ``(..., nz)``.

A model may also declare **torch forms** of ``f``, ``h`` and ``residual``
(``f_torch``, ``h_torch``, ``residual_torch``): the same functions on float64
torch tensors, differentiable by autograd. The filters never use them; a
learned filter trained through the model (:mod:`adaptfilt.kalmannet`) does,
and falls back to the numpy functions (finite-difference Jacobians) without
them. The library's UNGM and CTM declare them (``tests/test_model_torch.py``
holds them equal to the numpy functions to 1e-12). This module does not
import torch: the forms of UNGM use only arithmetic, the CTM's import it
when called.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from adaptfilt.linalg import wrap_angle

__all__ = ["StateSpaceModel", "Trajectory", "ungm", "coordinated_turn", "linear_gaussian", "wrap_angle",
           "wrap_angle_torch"]

ModelFn = Callable[[np.ndarray, int], np.ndarray]


def _spd(name: str, A, n: int | None) -> np.ndarray:
    A = np.atleast_2d(np.asarray(A, dtype=float))
    if A.ndim != 2 or A.shape[0] != A.shape[1]:
        raise ValueError(f"{name} must be a square matrix, got shape {A.shape}")
    if n is not None and A.shape[0] != n:
        raise ValueError(f"{name} must be {n}x{n} to match the state/measurement dimension, got {A.shape}")
    if not np.isfinite(A).all():
        raise ValueError(f"{name} has non-finite entries")
    if not np.allclose(A, A.T, rtol=1e-10, atol=1e-12 * max(1.0, np.abs(A).max())):
        raise ValueError(f"{name} must be symmetric")
    if np.linalg.eigvalsh(A)[0] <= 0:
        raise ValueError(f"{name} must be positive definite (smallest eigenvalue {np.linalg.eigvalsh(A)[0]:.3g})")
    return A


@dataclass
class Trajectory:
    """Simulated states ``x (M, T, nx)`` and measurements ``z (M, T, nz)``."""

    x: np.ndarray
    z: np.ndarray

    @property
    def n_runs(self) -> int:
        return self.x.shape[0]

    @property
    def n_steps(self) -> int:
        return self.x.shape[1]

    def __getitem__(self, runs) -> "Trajectory":
        """A subset of runs, e.g. ``traj[:100]``."""
        return Trajectory(self.x[runs], self.z[runs])


@dataclass
class StateSpaceModel:
    """A nonlinear model with additive Gaussian noise (equation (1) of the paper).

    Parameters
    ----------
    f, h : callable ``(x, k) -> array``
        Batched transition and measurement functions, ``x (..., nx)``.
    Q, R : array
        Process and measurement noise covariances (``nx x nx``, ``nz x nz``).
    m0, P0 : array
        Mean and covariance of the first state ``x_1``.
    residual : callable ``(a, b) -> a - b``, optional
        Batched measurement difference, e.g. wrapping bearings to (-pi, pi].
    name : str
        Used in saved policies and results, which refuse files made for another model.
    n_steps : int, optional
        The horizon ``T`` of the experiments on this model.
    F, H : array, optional
        Set when ``f`` (``h``) is linear, ``f(x, k) = F x``: filters then
        predict (update) exactly, and the Kalman filter accepts the model.
    circular_z : tuple of int
        Measurement components that are angles (policies may see them as
        ``(sin, cos)``, see :mod:`adaptfilt.features`).
    time_features : callable ``k -> sequence of float``, optional
        The phase of a time-varying model (UNGM: ``cos 0.05k, sin 0.05k``),
        named by ``time_feature_names``; an optional policy feature.
    f_torch, h_torch, residual_torch : callable, optional
        Torch forms of ``f``, ``h`` and ``residual`` (module docstring):
        ``(x: Tensor (..., nx), k) -> Tensor``, equal to the numpy functions
        and differentiable. Checked against them by their user
        (:class:`~adaptfilt.kalmannet.KalmanNet`), not here (no torch import);
        ``residual_torch`` is not used where ``residual`` is None.

    Every argument is checked at construction: dimensions agree, covariances
    are symmetric positive definite, and ``f``/``h`` return the right shapes on
    a probe batch. Each failure is a ``ValueError`` naming the argument.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.StateSpaceModel(
    ...     f=lambda x, k: 0.9 * x, h=lambda x, k: np.sin(x),
    ...     Q=[[0.1]], R=[[0.01]], m0=[0.0], P0=[[1.0]], name="sine")
    >>> traj = model.simulate(n_runs=3, n_steps=5, rng=np.random.default_rng(0))
    >>> traj.x.shape, traj.z.shape
    ((3, 5, 1), (3, 5, 1))
    """

    f: ModelFn
    h: ModelFn
    Q: np.ndarray
    R: np.ndarray
    m0: np.ndarray
    P0: np.ndarray
    residual: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    name: str = "model"
    n_steps: int | None = None
    F: np.ndarray | None = None
    H: np.ndarray | None = None
    description: str = field(default="", repr=False)
    circular_z: tuple[int, ...] = ()
    time_features: Callable[[int], Sequence[float]] | None = field(default=None, repr=False)
    time_feature_names: tuple[str, ...] = ()
    f_torch: Callable | None = field(default=None, repr=False)
    h_torch: Callable | None = field(default=None, repr=False)
    residual_torch: Callable | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not callable(self.f) or not callable(self.h):
            raise ValueError("f and h must be callables f(x, k), h(x, k)")
        self.m0 = np.atleast_1d(np.asarray(self.m0, dtype=float))
        if self.m0.ndim != 1 or not np.isfinite(self.m0).all():
            raise ValueError(f"m0 must be a finite vector, got shape {self.m0.shape}")
        nx = self.m0.shape[0]
        self.P0 = _spd("P0", self.P0, nx)
        self.Q = _spd("Q", self.Q, nx)
        self.R = _spd("R", self.R, None)
        nz = self.R.shape[0]
        if self.F is not None:
            self.F = np.atleast_2d(np.asarray(self.F, dtype=float))
            if self.F.shape != (nx, nx):
                raise ValueError(f"F must be {nx}x{nx}, got {self.F.shape}")
        if self.H is not None:
            self.H = np.atleast_2d(np.asarray(self.H, dtype=float))
            if self.H.shape != (nz, nx):
                raise ValueError(f"H must be {nz}x{nx}, got {self.H.shape}")
        if self.n_steps is not None and int(self.n_steps) < 1:
            raise ValueError(f"n_steps must be positive, got {self.n_steps}")
        probe = self.m0 + np.zeros((3, 2, nx))
        for fname, fn, nout in (("f", self.f, nx), ("h", self.h, nz)):
            out = np.asarray(fn(probe, 1))
            if out.shape != (3, 2, nout):
                raise ValueError(
                    f"{fname}(x, k) must map a batch x of shape (..., {nx}) to (..., {nout}); "
                    f"on a probe of shape {probe.shape} it returned shape {out.shape}"
                )
        self.circular_z = tuple(int(i) for i in self.circular_z)
        if any(not 0 <= i < nz for i in self.circular_z):
            raise ValueError(f"circular_z {self.circular_z} must index measurement components 0..{nz - 1}")
        if self.time_features is not None:
            tf = np.asarray(self.time_features(1), dtype=float)
            if tf.ndim != 1 or tf.shape[0] != len(self.time_feature_names):
                raise ValueError(f"time_features(k) must return one value per name in time_feature_names "
                                 f"{self.time_feature_names}; it returned shape {tf.shape}")
        elif self.time_feature_names:
            raise ValueError("time_feature_names given without time_features")
        for fname in ("f_torch", "h_torch", "residual_torch"):
            if getattr(self, fname) is not None and not callable(getattr(self, fname)):
                raise ValueError(f"{fname} must be a callable (the torch form of {fname[:-6]}) or None")
        if self.residual is not None:
            zz = np.zeros((3, 2, nz))
            out = np.asarray(self.residual(zz, zz))
            if out.shape != (3, 2, nz):
                raise ValueError(f"residual(a, b) must return the shape of a ({zz.shape}), got {out.shape}")

    @property
    def nx(self) -> int:
        return self.m0.shape[0]

    @property
    def nz(self) -> int:
        return self.R.shape[0]

    def diff_z(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``a - b`` in measurement space (wrapped where the model says so)."""
        return a - b if self.residual is None else self.residual(a, b)

    def simulate(self, n_runs: int, n_steps: int | None = None, rng: np.random.Generator | int | None = None) -> Trajectory:
        """Simulate ``n_runs`` independent trajectories of ``n_steps`` steps.

        ``rng`` is a numpy Generator or a seed; the same seed gives the same
        trajectories. ``n_steps`` defaults to the model's horizon.
        """
        T = self.n_steps if n_steps is None else int(n_steps)
        if T is None or T < 1:
            raise ValueError("n_steps must be a positive integer (the model has no default horizon)")
        if int(n_runs) < 1:
            raise ValueError(f"n_runs must be a positive integer, got {n_runs}")
        rng = np.random.default_rng(rng)
        M, nx, nz = int(n_runs), self.nx, self.nz
        Lq, Lr, L0 = (np.linalg.cholesky(A) for A in (self.Q, self.R, self.P0))
        x = np.empty((M, T, nx))
        z = np.empty((M, T, nz))
        x[:, 0] = self.m0 + rng.standard_normal((M, nx)) @ L0.T
        for t in range(T):
            if t:
                x[:, t] = self.f(x[:, t - 1], t) + rng.standard_normal((M, nx)) @ Lq.T
            z[:, t] = self.h(x[:, t], t + 1) + rng.standard_normal((M, nz)) @ Lr.T
        return Trajectory(x=x, z=z)


def ungm(Q: float = 1.0, R: float = 0.1, P0: float = 5.0, n_steps: int = 500, forcing: float = 8.0) -> StateSpaceModel:
    r"""Univariate nonstationary growth model (Section VI-A).

    .. math::
        x_{k+1} = 0.5 x_k + \frac{25 x_k}{1 + x_k^2} + 8 \cos(0.05 k) + w_k,\qquad
        z_k = x_k^2 / 20 + v_k,

    ``w ~ N(0, 1)``, ``v ~ N(0, 0.1)``, ``x_1 ~ N(0, 5)``, ``k = 1..500``.
    The measurement is even in ``x``: the posterior is bimodal. ``forcing``: the amplitude of the
    forcing term (the paper's 8; another value makes a truth whose dynamics differ from the model's,
    for the learned-gain study's trained-on-the-truth regime).
    """
    c = float(forcing)

    def f(x, k):
        return 0.5 * x + 25.0 * x / (1.0 + x * x) + c * np.cos(0.05 * k)

    def h(x, k):
        return x * x / 20.0

    def f_torch(x, k):  # the same operations on a tensor (the forcing a float): bit for bit f's values
        return 0.5 * x + 25.0 * x / (1.0 + x * x) + float(c * np.cos(0.05 * k))

    def phase(k):
        return (np.cos(0.05 * k), np.sin(0.05 * k))

    return StateSpaceModel(
        f=f, h=h, Q=[[Q]], R=[[R]], m0=[0.0], P0=[[P0]], name="ungm", n_steps=n_steps,
        description="univariate nonstationary growth model (paper Sec. VI-A)"
        + ("" if c == 8.0 else f", forcing {c:g} cos(0.05k)"),
        time_features=phase, time_feature_names=("cos 0.05k", "sin 0.05k"),
        f_torch=f_torch, h_torch=h,  # h's arithmetic works on tensors as written
    )


def ct_matrices(omega: float, dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition matrix ``F`` and noise covariance ``Q`` of the coordinated turn
    with known turn rate, state ``[px, vx, py, vy]`` (Section VI-B)."""
    s, c = np.sin(omega * dt), np.cos(omega * dt)
    F = np.array(
        [
            [1.0, s / omega, 0.0, -(1.0 - c) / omega],
            [0.0, c, 0.0, -s],
            [0.0, (1.0 - c) / omega, 1.0, s / omega],
            [0.0, s, 0.0, c],
        ]
    )
    Q = q * np.kron(np.eye(2), np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]]))
    return F, Q


def coordinated_turn(
    omega: float = 0.5, dt: float = 1.0, q: float = 1.0, R: float = 0.04, n_steps: int = 150
) -> StateSpaceModel:
    r"""Coordinated turn with a bearing-only sensor at the origin (Section VI-B).

    State ``[px, vx, py, vy]``, linear dynamics ``x_{k+1} = F x_k + w_k`` with
    known turn rate ``omega``, bearing ``z_k = atan2(py, px) + v_k``,
    ``R = 0.04``, ``x_1 ~ N([80, 0, 0, 20], diag(1e3, 1e2, 1e3, 1e2))``,
    ``k = 1..150``. Measurement differences are wrapped to ``(-pi, pi]``.
    Range is not observable from one static bearing sensor: filters on this
    model are expected to be inconsistent.
    """
    F, Q = ct_matrices(omega, dt, q)

    def f(x, k):
        return x @ F.T

    def h(x, k):
        return np.arctan2(x[..., 2:3], x[..., 0:1])

    def residual(a, b):
        return wrap_angle(a - b)

    F_t = {}  # F as a tensor, made at the first call (this module does not import torch)

    def f_torch(x, k):
        import torch

        if "F" not in F_t:
            F_t["F"] = torch.from_numpy(F.T.copy())
        return x @ F_t["F"]

    def h_torch(x, k):
        import torch

        return torch.atan2(x[..., 2:3], x[..., 0:1])

    def residual_torch(a, b):
        return wrap_angle_torch(a - b)

    return StateSpaceModel(
        f=f, h=h, Q=Q, R=[[R]], m0=[80.0, 0.0, 0.0, 20.0], P0=np.diag([1e3, 1e2, 1e3, 1e2]),
        residual=residual, name="ctm", n_steps=n_steps, F=F,
        description="coordinated turn, bearing-only (paper Sec. VI-B)", circular_z=(0,),
        f_torch=f_torch, h_torch=h_torch, residual_torch=residual_torch,
    )


def wrap_angle_torch(a):
    """:func:`~adaptfilt.linalg.wrap_angle` for a torch tensor: ``(-pi, pi]``, angles inside unchanged
    (exactly); the wrap of the others is a constant offset of ``2 pi k``, so the derivative is 1."""
    import torch

    outside = (a > np.pi) | (a <= -np.pi)
    w = torch.remainder(a + np.pi, 2.0 * np.pi) - np.pi
    w = torch.where(w == -np.pi, np.pi, w)  # remainder maps +pi to -pi; the convention is (-pi, pi]
    return torch.where(outside, w, a)


def linear_gaussian(F, H, Q, R, m0, P0, name: str = "linear", n_steps: int | None = None) -> StateSpaceModel:
    """A linear-Gaussian model ``x_{k+1} = F x_k + w_k``, ``z_k = H x_k + v_k``.

    On it every Gaussian-assumed filter must equal the Kalman filter.
    """
    F = np.atleast_2d(np.asarray(F, dtype=float))
    H = np.atleast_2d(np.asarray(H, dtype=float))
    return StateSpaceModel(
        f=lambda x, k: x @ F.T, h=lambda x, k: x @ H.T, Q=Q, R=R, m0=m0, P0=P0,
        name=name, n_steps=n_steps, F=F, H=H,
    )
