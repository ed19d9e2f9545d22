r"""KalmanNet: a filter whose Kalman gain is computed by a recurrent network (issue 38).

Written from the paper (Revach, Shlezinger, Ni, López Escoriza, van Sloun, Eldar, "KalmanNet:
Neural network aided Kalman filtering for partially known dynamics", IEEE Trans. Signal Processing
70, 2022, architecture 2); no code of the authors' (unlicensed) repository is used or loaded.

The filter keeps the model's prediction and learns the gain:

.. math::
    \hat x_{t|t-1} = f(\hat x_{t-1|t-1}),\qquad \hat z_{t|t-1} = h(\hat x_{t|t-1}),\qquad
    \Delta z_t = z_t - \hat z_{t|t-1},

.. math::
    K_t = \mathrm{GainNet}(F_1, F_2, F_3, F_4;\ \text{GRU states}),\qquad
    \hat x_{t|t} = \hat x_{t|t-1} + K_t\, \Delta z_t,

with the four input features of the paper

* F1, observation difference   :math:`z_t - z_{t-1}`,
* F2, innovation               :math:`z_t - \hat z_{t|t-1}`,
* F3, forward evolution difference :math:`\hat x_{t-1|t-1} - \hat x_{t-2|t-2}`,
* F4, forward update difference    :math:`\hat x_{t-1|t-1} - \hat x_{t-1|t-2}`.

**Architecture 2** (:class:`GainNet`; ``m = nx``, ``n = nz``, multipliers ``in_mult = 5``,
``out_mult = 40`` as in the paper's experiments): F4 -> FC5 (``m -> 5m``) -> Q-GRU (hidden ``m^2``);
[Q-GRU out, FC6(F3) (``m -> 5m``)] -> Sigma-GRU (hidden ``m^2``); [FC1(Sigma out) (``m^2 -> n^2``),
FC7([F1, F2]) (``2n -> 10n``)] -> S-GRU (hidden ``n^2``); FC2: [Sigma out, S out] -> hidden
``(m^2 + n^2) out_mult`` -> ``m n`` = the gain; the backward flow FC3([S out, K]) -> ``m^2``, FC4([Sigma
out, FC3]) -> ``m^2`` becomes the Sigma-GRU's next state. Every FC layer but FC2's output has a ReLU.
The GRU states start from the priors ``vec(I_m)``, ``0``, ``vec(I_n)`` (KalmanNet is not told Q or R).
For ``m = n = 1`` the network has 472 parameters.

Choices where the paper is silent, or where this module departs from it (all options are recorded
in saved files):

* **Time convention** of the library: the prior ``N(m0, P0)`` is the prediction of the first state,
  so at ``t = 0`` ``x_{0|-1} = m0`` with no ``f``; the missing past is ``z_{-1} = h(m0)`` and
  ``x_{-1|-1} = x_{-2|-2} = x_{-1|-2} = m0`` (F3 = F4 = 0 at the first step).
* **Input normalisation** ``feature_norm``: ``"l2"`` (default, the public code's: each feature vector
  divided by its Euclidean norm per sample; in one dimension only its sign is left),
  ``"none"`` (raw features) or ``"scale"`` (each component divided by a fixed scale: F1 and F2 by the
  standard deviation of ``z_t - z_{t-1}``, F3 and F4 by that of ``x_t - x_{t-1}``, both from a pilot
  simulation of the model seeded by the training seed, never from the training labels).
* **Gradients through f and h** (``model_grad``): the library's models are numpy. With
  ``"jacobian"`` (default) ``f`` and ``h`` are applied per step in numpy and back-propagated with
  their Jacobian (exact for a model that declares ``F``/``H``, which then runs in torch; forward
  differences otherwise, ``nx`` extra evaluations per step, only while training), so
  back-propagation through time follows the state path ``x_{t|t} -> f -> x_{t+1|t}`` as in the paper.
  ``"detach"`` cuts that path (gradients flow through the network's own inputs and states only); it
  is cheaper, and cannot train the unsupervised loss, whose only path to the weights is through
  ``f`` and ``h``. Measurement differences use the model's ``residual`` (bearings wrapped); the
  wrap is a constant offset of ``2 pi``, so its derivative is that of the plain difference.
* Everything runs in float64 (the library's precision; the public code's float32 NaNs are a
  reported issue).

**Bayesian variant** (``n_samples = J > 1``, ``dropout = p > 0``; Dahan, Revach, Duník, Shlezinger,
"Bayesian KalmanNet", arXiv 2309.03058 / ICASSP 2024): Monte-Carlo dropout on the hidden layer of
the gain head FC2, kept on when filtering. Each run is filtered by ``J`` copies of the filter, each
with its own dropout mask (drawn once per sequence: one sample of the weights, as a Bayesian
network's), its own estimate and GRU states; the estimate is the copies' mean and its covariance
their sample covariance (``1/(J-1)``),

.. math::
    \hat x_{t|t} = \tfrac1J \sum_j \hat x^{(j)}_{t|t},\qquad
    P_{t|t} = \tfrac{1}{J-1} \sum_j (\hat x^{(j)}_{t|t} - \hat x_{t|t})(\hat x^{(j)}_{t|t} - \hat x_{t|t})^T .

The copies start from ``J`` draws of the prior ``N(m0, P0)``, centred on ``m0`` (without them the
first covariance would be the gains' spread alone, ``Var(K) (z - h(m0))^2``). Training adds to the
MSE of the mean the calibration term ``lambda mean_t |diag(P_{t|t}) - e_t^2|`` (``e`` the error of
the mean; ``calibration = lambda``), as we read the paper; the fixed dropout rate stands for its
Bayesian weight posterior. Between steps the copies' spread grows by ``(K^{(j)} - K) Delta z_t``:
it is proportional to the current innovation, so the NEES has a heavy tail where an innovation is
near zero (on the linear test model the time-averaged ANEES of a CI-trained filter is about 30-60,
ideal 1: overconfident).

**Training** (:func:`train_kalmannet`): trajectories from the model's simulator (seeded), Adam,
minibatches of whole trajectories, back-propagation through the whole sequence or truncated to
windows (``tbptt``: the estimate and GRU states carry over, detached), optional gradient-norm
clipping (``clip``), the model with the best validation loss kept (validated once per epoch). Losses:
``"supervised"`` (the paper: MSE of ``x_{t|t}`` against the true state) or ``"unsupervised"``
(Revach et al., "Unsupervised learned Kalman filtering", arXiv 2110.09005, EUSIPCO 2022: the squared error of the
predicted measurement, ``|z_t - h(x_{t|t-1})|^2``, no true state used). A non-finite loss or
gradient stops training with :class:`TrainingDiverged` naming the epoch and step.

Files (:meth:`KalmanNet.save`, :func:`load_kalmannet`): one ``.npz`` without pickles
(:func:`adaptfilt.files.write_npz`, as a policy's) holding the weights and a JSON record of the model's name and
dimensions, the options, the seed, the training summary and the package version; loading it for
another model is a ``ValueError`` naming both.

Example
-------
>>> import numpy as np, adaptfilt as af
>>> from adaptfilt.kalmannet import train_kalmannet
>>> model = af.models.linear_gaussian(F=[[0.9]], H=[[1.0]], Q=[[1.0]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
>>> knet = train_kalmannet(model, n_train=20, n_val=10, n_steps=10, epochs=2, seed=0, progress=False)
>>> traj = model.simulate(n_runs=5, n_steps=10, rng=1)
>>> run = knet.run(traj.z)                      # an adaptfilt FilterRun: the metrics work unchanged
>>> af.metrics.rmse(traj.x, run.mean).shape
(10,)
"""
from __future__ import annotations

import copy
import math
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence

import numpy as np
import torch
from torch import nn

from adaptfilt._version import __version__
from adaptfilt.files import read_npz, write_npz
from adaptfilt.filters import FilterRun
from adaptfilt.models import StateSpaceModel, Trajectory
from adaptfilt.nets import arrays_to_state, one_torch_thread, state_to_arrays

__all__ = ["GainNet", "KalmanNet", "train_kalmannet", "load_kalmannet", "TrainingDiverged", "KALMANNET_FORMAT"]

KALMANNET_FORMAT = "adaptfilt-kalmannet/1"
FEATURE_NORMS = ("l2", "none", "scale")
MODEL_GRADS = ("jacobian", "detach")
LOSSES = ("supervised", "unsupervised")
_DT = torch.float64


class TrainingDiverged(FloatingPointError):
    """Training produced a non-finite loss or gradient (named by epoch and optimiser step)."""


# ------------------------------------------------------------------ the network
class GainNet(nn.Module):
    """KalmanNet's architecture 2: three GRUs (Q, Sigma, S) and the fully connected layers FC1-FC7.

    ``step`` maps the four (normalised) features and the GRU states of one step (batch ``B``) to the
    gain ``K (B, m, n)`` and the next GRU states; ``mask`` is the Bayesian variant's dropout mask.
    """

    def __init__(self, nx: int, nz: int, in_mult: int = 5, out_mult: int = 40, dropout: float = 0.0):
        super().__init__()
        m, n = int(nx), int(nz)
        self.nx, self.nz, self.dropout = m, n, float(dropout)
        relu = nn.ReLU
        self.fc5 = nn.Sequential(nn.Linear(m, in_mult * m), relu())            # F4 -> Q-GRU
        self.gru_Q = nn.GRUCell(in_mult * m, m * m)
        self.fc6 = nn.Sequential(nn.Linear(m, in_mult * m), relu())            # F3 -> Sigma-GRU
        self.gru_Sigma = nn.GRUCell(m * m + in_mult * m, m * m)
        self.fc1 = nn.Sequential(nn.Linear(m * m, n * n), relu())              # Sigma -> S-GRU
        self.fc7 = nn.Sequential(nn.Linear(2 * n, 2 * in_mult * n), relu())    # [F1, F2] -> S-GRU
        self.gru_S = nn.GRUCell(n * n + 2 * in_mult * n, n * n)
        hidden = (m * m + n * n) * out_mult
        self.fc2_hidden = nn.Linear(m * m + n * n, hidden)                     # FC2: the gain head
        self.fc2_out = nn.Linear(hidden, m * n)
        self.fc3 = nn.Sequential(nn.Linear(n * n + m * n, m * m), relu())      # backward flow
        self.fc4 = nn.Sequential(nn.Linear(2 * m * m, m * m), relu())

    def initial_states(self, B: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """GRU states from the priors ``vec(I_m)``, ``0``, ``vec(I_n)``."""
        m, n = self.nx, self.nz
        h_Q = torch.eye(m, dtype=_DT).reshape(1, -1).expand(B, -1).contiguous()
        h_Sigma = torch.zeros(B, m * m, dtype=_DT)
        h_S = torch.eye(n, dtype=_DT).reshape(1, -1).expand(B, -1).contiguous()
        return h_Q, h_Sigma, h_S

    def dropout_mask(self, B: int) -> torch.Tensor | None:
        """A Monte-Carlo dropout mask of FC2's hidden layer per run (scaled by ``1/(1-p)``), or None."""
        if self.dropout == 0.0:
            return None
        keep = 1.0 - self.dropout
        return torch.bernoulli(torch.full((B, self.fc2_hidden.out_features), keep, dtype=_DT)) / keep

    def step(self, F1: torch.Tensor, F2: torch.Tensor, F3: torch.Tensor, F4: torch.Tensor, h_Q: torch.Tensor,
             h_Sigma: torch.Tensor, h_S: torch.Tensor, mask: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        h_Q = self.gru_Q(self.fc5(F4), h_Q)
        Sigma = self.gru_Sigma(torch.cat([h_Q, self.fc6(F3)], -1), h_Sigma)
        h_S = self.gru_S(torch.cat([self.fc1(Sigma), self.fc7(torch.cat([F1, F2], -1))], -1), h_S)
        a = torch.relu(self.fc2_hidden(torch.cat([Sigma, h_S], -1)))
        if mask is not None:
            a = a * mask
        K = self.fc2_out(a)
        b = self.fc3(torch.cat([h_S, K], -1))
        h_Sigma = self.fc4(torch.cat([Sigma, b], -1))  # the backward flow overwrites the Sigma-GRU state
        return K.reshape(-1, self.nx, self.nz), h_Q, h_Sigma, h_S


# ------------------------------------------------------------- model functions in torch
class _NumpyFn(torch.autograd.Function):
    """``y = fn(x, k)`` of a numpy model function, differentiated by forward differences."""

    @staticmethod
    def forward(ctx, x, fn, k):
        xn = x.detach().numpy()
        y = np.asarray(fn(xn, k), dtype=float)
        if ctx.needs_input_grad[0]:
            d = xn.shape[-1]
            eps = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(xn))  # (B, d)
            J = np.empty(y.shape + (d,))
            for j in range(d):
                xj = xn.copy()
                xj[:, j] += eps[:, j]
                J[..., j] = (np.asarray(fn(xj, k), dtype=float) - y) / eps[:, j:j + 1]
            ctx.save_for_backward(torch.from_numpy(J))
        return torch.from_numpy(y)

    @staticmethod
    def backward(ctx, gy):
        (J,) = ctx.saved_tensors
        return (gy.unsqueeze(-2) @ J).squeeze(-2), None, None


def _pilot_scales(model: StateSpaceModel, seed: int, n_steps: int) -> np.ndarray:
    """``feature_norm="scale"``: per-component scales of [F1, F2, F3, F4] from a pilot simulation."""
    traj = model.simulate(200, max(2, n_steps), rng=np.random.default_rng([int(seed), 7]))
    dz = model.diff_z(traj.z[:, 1:], traj.z[:, :-1]).reshape(-1, model.nz).std(0)
    dx = np.diff(traj.x, axis=1).reshape(-1, model.nx).std(0)
    s = np.concatenate([dz, dz, dx, dx])
    return np.where(s > 0, s, 1.0)


@dataclass
class _Carry:
    """What one step passes to the next (kept across truncated back-propagation windows)."""

    x_filt: torch.Tensor       # x_{t-1|t-1}
    x_filt_prev: torch.Tensor  # x_{t-2|t-2}
    x_pred: torch.Tensor       # x_{t-1|t-2}
    h: tuple
    mask: torch.Tensor | None = None  # the Bayesian variant's dropout mask, fixed over a sequence

    def detach(self) -> "_Carry":
        return _Carry(self.x_filt.detach(), self.x_filt_prev.detach(), self.x_pred.detach(),
                      tuple(h.detach() for h in self.h), self.mask)


# --------------------------------------------------------------------- the filter
class KalmanNet:
    """KalmanNet (architecture 2) over a library model, batched over runs (module docstring).

    Parameters
    ----------
    model : StateSpaceModel
        Gives ``f``, ``h``, ``residual``, ``m0`` and the dimensions (``Q``, ``R``, ``P0`` are not used
        by the filter; ``feature_norm="scale"`` simulates the model once for its scales).
    feature_norm : "l2", "none" or "scale"
        Input normalisation (module docstring); ``"l2"`` is the public code's.
    in_mult, out_mult : int
        Width multipliers of the input FC layers and of FC2's hidden layer (paper: 5 and 40).
    dropout, n_samples : float, int
        The Bayesian variant: Monte-Carlo dropout rate on FC2's hidden layer and the number ``J`` of
        samples per step (``n_samples > 1`` needs ``dropout > 0``); it returns covariances.
    model_grad : "jacobian" or "detach"
        How training back-propagates through ``f`` and ``h`` (module docstring).
    seed : int
        Initialises the weights (and draws the dropout masks when filtering, unless ``run`` gets one).
    """

    def __init__(self, model: StateSpaceModel, *, feature_norm: Literal["l2", "none", "scale"] = "l2",
                 in_mult: int = 5, out_mult: int = 40, dropout: float = 0.0, n_samples: int = 1,
                 model_grad: Literal["jacobian", "detach"] = "jacobian", seed: int = 0,
                 scales: np.ndarray | None = None):
        if not isinstance(model, StateSpaceModel):
            raise TypeError(f"model must be an adaptfilt StateSpaceModel, got {type(model).__name__}")
        if feature_norm not in FEATURE_NORMS:
            raise ValueError(f"feature_norm must be one of {FEATURE_NORMS}, got {feature_norm!r}")
        if model_grad not in MODEL_GRADS:
            raise ValueError(f"model_grad must be one of {MODEL_GRADS}, got {model_grad!r}")
        if int(in_mult) < 1 or int(out_mult) < 1:
            raise ValueError(f"in_mult and out_mult must be positive integers, got {in_mult}, {out_mult}")
        if not 0.0 <= float(dropout) < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        if int(n_samples) < 1 or (int(n_samples) > 1) != (float(dropout) > 0.0):
            raise ValueError(f"the Bayesian variant needs both n_samples > 1 and dropout > 0, the plain KalmanNet "
                             f"n_samples = 1 and dropout = 0 (got n_samples={n_samples}, dropout={dropout})")
        self.model = model
        self.options = dict(feature_norm=feature_norm, in_mult=int(in_mult), out_mult=int(out_mult),
                            dropout=float(dropout), n_samples=int(n_samples), model_grad=model_grad)
        self.seed = int(seed)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            self.net = GainNet(model.nx, model.nz, int(in_mult), int(out_mult), float(dropout)).to(_DT)
        if feature_norm == "scale":
            s = _pilot_scales(model, self.seed, model.n_steps or 100) if scales is None else np.asarray(scales, float)
            if s.shape != (2 * model.nz + 2 * model.nx,) or not (np.isfinite(s).all() and (s > 0).all()):
                raise ValueError(f"scales must be {2 * model.nz + 2 * model.nx} positive finite numbers, got {s}")
            self.scales = s
        else:
            self.scales = None
        self.history: dict = {}
        # exact torch versions of linear f and h (no finite differences)
        self._F = None if model.F is None else torch.from_numpy(np.ascontiguousarray(model.F.T))
        self._H = None if model.H is None else torch.from_numpy(np.ascontiguousarray(model.H.T))
        self._m0 = torch.from_numpy(model.m0.copy())

    @property
    def bayesian(self) -> bool:
        return self.options["n_samples"] > 1

    def __repr__(self) -> str:
        o = self.options
        extra = f", dropout={o['dropout']:g}, J={o['n_samples']}" if self.bayesian else ""
        return f"KalmanNet(model={self.model.name!r}, feature_norm={o['feature_norm']!r}{extra})"

    # -------------------------------------------------------------- checks
    def check_z(self, z) -> np.ndarray:
        """Measurements as ``(M, T, nz)``; ValueError naming what is wrong."""
        z = np.asarray(z, dtype=float)
        nz = self.model.nz
        if z.ndim == 2 and nz == 1:
            z = z[:, :, None]
        if z.ndim != 3 or z.shape[2] != nz or z.shape[0] < 1 or z.shape[1] < 1:
            raise ValueError(f"z must have shape (M, T, nz={nz}) (or (M, T) when nz = 1) for model "
                             f"{self.model.name!r}, got {z.shape}")
        if not np.isfinite(z).all():
            bad = np.argwhere(~np.isfinite(z).all(axis=2))[0]
            raise ValueError(f"z has non-finite values (first at run {bad[0]}, step {bad[1]})")
        return z

    # -------------------------------------------------------------- the recursion
    def _f(self, x: torch.Tensor, k: int) -> torch.Tensor:
        if self.options["model_grad"] == "detach":
            x = x.detach()
        if self._F is not None:
            return x @ self._F
        return _NumpyFn.apply(x, self.model.f, k)

    def _h(self, x: torch.Tensor, k: int) -> torch.Tensor:
        if self._H is not None:
            return x @ self._H
        return _NumpyFn.apply(x, self.model.h, k)

    def _dz(self, z: torch.Tensor, z_pred: torch.Tensor) -> torch.Tensor:
        """``z - z_pred`` through the model's residual; the wrap is added as a constant."""
        d = z - z_pred
        if self.model.residual is None:
            return d
        dn = d.detach().numpy()
        return d + torch.from_numpy(self.model.residual(z.detach().numpy(), z_pred.detach().numpy()) - dn)

    def _norm(self, F: torch.Tensor, which: slice) -> torch.Tensor:
        mode = self.options["feature_norm"]
        if mode == "l2":
            return nn.functional.normalize(F, p=2.0, dim=-1, eps=1e-12)
        if mode == "scale":
            return F / torch.from_numpy(self.scales[which])
        return F

    def _start(self, B: int) -> _Carry:
        """The carry before the first step for ``B`` runs (``J B`` filter copies in the Bayesian variant)."""
        J = self.options["n_samples"]
        x0 = self._m0.expand(J * B, -1)
        if J > 1:
            # the J copies start from J draws of the prior N(m0, P0), centred so that their mean is m0:
            # without them every copy starts at m0 and the first covariance is only the gains' spread
            d = torch.randn(J, B, self.model.nx, dtype=_DT) @ torch.from_numpy(np.linalg.cholesky(self.model.P0).T)
            x0 = x0 + (d - d.mean(0)).reshape(J * B, -1)
        return _Carry(x0, x0, x0, self.net.initial_states(J * B), self.net.dropout_mask(J * B))

    def _window(self, z: np.ndarray, z_prev: np.ndarray, t0: int, carry: _Carry):
        """Steps ``t0 .. t0 + len(z) - 1`` from ``carry``: per-step tensors and the final carry.

        ``z``, ``z_prev`` ``(B, L, nz)`` numpy (``z_prev`` the measurement of the step before). The
        Bayesian variant runs ``J`` copies of the filter per run (sample ``j`` of run ``b`` at
        ``j B + b``), each with its own dropout mask, estimate and GRU states; the outputs are their
        mean and sample covariance.
        """
        nx, nz = self.model.nx, self.model.nz
        J = self.options["n_samples"]
        if J > 1:
            z, z_prev = np.tile(z, (J, 1, 1)), np.tile(z_prev, (J, 1, 1))
        B, L = z.shape[:2]
        F1_all = torch.from_numpy(np.ascontiguousarray(self.model.diff_z(z, z_prev)))
        zt_all = torch.from_numpy(np.ascontiguousarray(z))
        s_z1, s_z2 = slice(0, nz), slice(nz, 2 * nz)
        s_x3, s_x4 = slice(2 * nz, 2 * nz + nx), slice(2 * nz + nx, 2 * nz + 2 * nx)
        means, preds, innovs, covs, gains = [], [], [], [], []
        c = carry
        for i in range(L):
            t = t0 + i
            x_pred = c.x_pred if t == 0 else self._f(c.x_filt, t)  # f(x_k, k), k = t; x_{0|-1} = m0
            z_pred = self._h(x_pred, t + 1)
            innov = self._dz(zt_all[:, i], z_pred)
            F1 = self._norm(F1_all[:, i], s_z1)
            F2 = self._norm(innov, s_z2)
            F3 = self._norm(c.x_filt - c.x_filt_prev, s_x3)
            F4 = self._norm(c.x_filt - c.x_pred, s_x4)
            K, h_Q, h_Sigma, h_S = self.net.step(F1, F2, F3, F4, *c.h, mask=c.mask)
            x_filt = x_pred + (K @ innov.unsqueeze(-1)).squeeze(-1)
            means.append(x_filt)
            preds.append(x_pred)
            innovs.append(innov)
            gains.append(K)
            c = _Carry(x_filt, c.x_filt, x_pred, (h_Q, h_Sigma, h_S), c.mask)
        out = dict(mean=torch.stack(means, 1), x_pred=torch.stack(preds, 1), innov=torch.stack(innovs, 1),
                   K=torch.stack(gains, 1), cov=None)
        if J > 1:  # (J B, L, ...) -> the mean over the J copies and their sample covariance
            x_j = out["mean"].reshape(J, B // J, L, nx)
            out["mean"] = x_j.mean(0)
            e = x_j - out["mean"]
            out["cov"] = torch.einsum("jbti,jbtk->btik", e, e) / (J - 1)
            out["x_pred"] = out["x_pred"].reshape(J, B // J, L, nx).mean(0)
            out["K"] = out["K"].reshape(J, B // J, L, nx, nz).mean(0)
        return out, c

    def _z_prev(self, z: np.ndarray) -> np.ndarray:
        """``z_{t-1}`` per step; before the first, the predicted measurement of the prior ``h(m0)``."""
        z0 = np.asarray(self.model.h(np.broadcast_to(self.model.m0, (z.shape[0], self.model.nx)).copy(), 1), float)
        return np.concatenate([z0[:, None, :], z[:, :-1]], axis=1)

    def run(self, z, *, keep_gain: bool = False, seed: int | None = None, chunk: int = 4096) -> FilterRun:
        """Filter measurements ``z (M, T, nz)``; a :class:`~adaptfilt.filters.FilterRun`.

        ``mean`` and ``x_pred`` are the estimates; ``cov`` is the sample covariance of the
        Bayesian variant, else NaN (no covariance: :func:`adaptfilt.metrics.nees` raises on it);
        ``nis``, ``loglik`` and ``params`` are NaN (read-only broadcasts). ``info["K"] (M, T, nx,
        nz)`` holds the gains when ``keep_gain``. ``seed`` draws the dropout masks of the
        Bayesian variant (default: the filter's seed), in the order of the runs and chunks, so a
        run's masks depend on its place in ``z``. Runs are filtered in chunks of ``chunk``. A run
        whose estimate overflows (a learned gain can make the recursion unstable, e.g. on UNGM)
        keeps its non-finite values, with numpy's overflow warning: count it with
        :func:`adaptfilt.metrics.divergent` (``mean=``) or ``~np.isfinite(run.mean)``.
        """
        z = self.check_z(z)
        M, T, _ = z.shape
        nx, nz = self.model.nx, self.model.nz
        J = self.options["n_samples"]
        mean, x_pred = np.empty((M, T, nx)), np.empty((M, T, nx))
        cov = np.empty((M, T, nx, nx)) if J > 1 else np.broadcast_to(np.float64(np.nan), (M, T, nx, nx))
        K = np.empty((M, T, nx, nz)) if keep_gain else None
        z_prev = self._z_prev(z)
        was_training = self.net.training
        self.net.eval()
        try:
            with one_torch_thread(), torch.no_grad(), torch.random.fork_rng(devices=[]):
                torch.manual_seed(self.seed if seed is None else int(seed))
                for a in range(0, M, int(chunk)):
                    b = min(M, a + int(chunk))
                    out, _ = self._window(z[a:b], z_prev[a:b], 0, self._start(b - a))
                    mean[a:b], x_pred[a:b] = out["mean"].numpy(), out["x_pred"].numpy()
                    if J > 1:
                        cov[a:b] = out["cov"].numpy()
                    if keep_gain:
                        K[a:b] = out["K"].numpy()
        finally:
            self.net.train(was_training)
        nan = np.broadcast_to(np.float64(np.nan), (M, T))
        info = {"filter": repr(self)}
        if keep_gain:
            info["K"] = K
        return FilterRun(mean=mean, cov=cov, nis=nan, loglik=nan, params=nan, x_pred=x_pred, info=info)

    def snapshot(self, epoch: int) -> "KalmanNet":
        """The filter as a training of ``epoch`` epochs returned it (``train_kalmannet(snapshots=...)``):
        a copy with those weights and that history. ValueError naming the epochs kept otherwise."""
        kept = getattr(self, "_snapshots", {})
        if int(epoch) not in kept:
            raise ValueError(f"no snapshot at epoch {epoch}; kept: {sorted(kept) or 'none (train with snapshots=...)'}")
        state, hist = kept[int(epoch)]
        other = copy.copy(self)
        other.net = copy.deepcopy(self.net)
        other.net.load_state_dict(state)
        other.net.eval()
        other.history, other._snapshots = copy.deepcopy(hist), {}
        return other

    # -------------------------------------------------------------- files
    def n_parameters(self) -> int:
        return sum(p.numel() for p in self.net.parameters())

    def metadata(self) -> dict:
        return {"format": KALMANNET_FORMAT, "model": self.model.name, "nx": self.model.nx, "nz": self.model.nz,
                "options": dict(self.options), "seed": self.seed, "version": __version__,
                "scales": None if self.scales is None else [float(s) for s in self.scales],
                "n_parameters": self.n_parameters(), "history": self.history}

    def save(self, path: str | os.PathLike) -> Path:
        """Write the weights and :meth:`metadata` to one ``.npz`` (no pickles, byte-reproducible)."""
        return write_npz(path, state_to_arrays("net", self.net), self.metadata())

    @classmethod
    def load(cls, path: str | os.PathLike, model: StateSpaceModel) -> "KalmanNet":
        return load_kalmannet(path, model)


def load_kalmannet(path: str | os.PathLike, model: StateSpaceModel) -> KalmanNet:
    """A :class:`KalmanNet` saved by :meth:`KalmanNet.save`, for ``model``.

    ``ValueError`` if the file is not a KalmanNet file or was made for another model (its name or
    dimensions differ: the message names both).
    """
    if not isinstance(model, StateSpaceModel):
        raise TypeError(f"model must be an adaptfilt StateSpaceModel, got {type(model).__name__}")
    arrays, meta = read_npz(path, what="adaptfilt KalmanNet file")
    if meta.get("format") != KALMANNET_FORMAT:
        raise ValueError(f"{path}: not an adaptfilt KalmanNet file (format {meta.get('format')!r}, "
                         f"expected {KALMANNET_FORMAT!r})")
    have = (meta.get("model"), meta.get("nx"), meta.get("nz"))
    want = (model.name, model.nx, model.nz)
    if have != want:
        raise ValueError(f"{path}: KalmanNet file made for model {have[0]!r} (nx={have[1]}, nz={have[2]}), "
                         f"not for model {want[0]!r} (nx={want[1]}, nz={want[2]})")
    missing = [k for k in ("options", "seed") if k not in meta]
    if missing or not isinstance(meta.get("options"), dict):
        raise ValueError(f"{path}: not an adaptfilt KalmanNet file (missing or malformed {', '.join(missing) or 'options'})")
    scales = meta.get("scales")
    knet = KalmanNet(model, seed=meta["seed"], scales=None if scales is None else np.asarray(scales), **meta["options"])
    try:
        knet.net.load_state_dict(arrays_to_state("net", arrays))
    except RuntimeError as e:
        raise ValueError(f"{path}: its weights do not fit a KalmanNet with options {meta['options']}: {e}") from None
    knet.history = meta.get("history", {})
    return knet


# --------------------------------------------------------------------- training
def _check_traj(traj: Trajectory, model: StateSpaceModel, what: str) -> Trajectory:
    if not isinstance(traj, Trajectory):
        raise TypeError(f"{what} must be an adaptfilt Trajectory, got {type(traj).__name__}")
    x, z = np.asarray(traj.x, float), np.asarray(traj.z, float)
    if x.ndim != 3 or z.ndim != 3 or x.shape[:2] != z.shape[:2] or x.shape[2] != model.nx or z.shape[2] != model.nz:
        raise ValueError(f"{what}: states {x.shape} and measurements {z.shape} must be (M, T, nx={model.nx}) and "
                         f"(M, T, nz={model.nz}) for model {model.name!r}")
    if not (np.isfinite(x).all() and np.isfinite(z).all()):
        raise ValueError(f"{what} has non-finite states or measurements")
    return Trajectory(x, z)


def _loss(knet: KalmanNet, out: dict, x: torch.Tensor | None, kind: str, calibration: float) -> torch.Tensor:
    if kind == "unsupervised":
        return (out["innov"] ** 2).mean()  # |z_t - h(x_{t|t-1})|^2: no true state
    e = out["mean"] - x
    loss = (e ** 2).mean()
    if out["cov"] is not None and calibration > 0.0:
        loss = loss + calibration * (torch.diagonal(out["cov"], dim1=-2, dim2=-1) - e ** 2).abs().mean()
    return loss


def _evaluate(knet: KalmanNet, traj: Trajectory, kind: str, calibration: float) -> float:
    """Validation loss, the training loss on the validation set with the filter's own dropout masks."""
    was_training = knet.net.training
    knet.net.eval()
    try:
        # the same dropout masks at every validation: epochs are compared on the same copies
        with torch.no_grad(), torch.random.fork_rng(devices=[]):
            torch.manual_seed(knet.seed)
            out, _ = knet._window(traj.z, knet._z_prev(traj.z), 0, knet._start(traj.n_runs))
            return float(_loss(knet, out, torch.from_numpy(traj.x), kind, calibration))
    finally:
        knet.net.train(was_training)


def train_kalmannet(model: StateSpaceModel, *, n_train: int = 100, n_val: int = 50, n_steps: int | None = None,
                    epochs: int = 30, batch_size: int = 20, lr: float = 1e-3, weight_decay: float = 1e-4,
                    loss: Literal["supervised", "unsupervised"] = "supervised", tbptt: int | None = None,
                    clip: float | None = None, seed: int = 0, data_seed: int | None = None,
                    train: Trajectory | None = None, val: Trajectory | None = None, progress: bool = True,
                    calibration: float = 1.0, init: KalmanNet | None = None,
                    on_diverged: Literal["raise", "restore", "stop"] = "raise", max_restores: int = 5,
                    max_cpu_s: float | None = None, snapshots: Sequence[int] = (),
                    **options) -> KalmanNet:
    """Train a :class:`KalmanNet` on simulated trajectories of ``model`` (module docstring).

    Parameters
    ----------
    n_train, n_val, n_steps : int
        Trajectories simulated for training and validation (``n_steps`` defaults to the model's
        horizon); with ``train``/``val`` given (Trajectories) those are used instead.
    epochs, batch_size, lr, weight_decay
        Passes over the training set, trajectories per optimiser step, Adam's settings.
    loss : "supervised" or "unsupervised"
        MSE against the true states (the paper), or the squared error of the predicted measurement
        (unsupervised KalmanNet); validation uses the same criterion.
    tbptt : int, optional
        Truncated back-propagation through time: one optimiser step per window of ``tbptt`` steps,
        the estimate and GRU states carried over (detached). Default: whole sequences.
    clip : float, optional
        Clip the gradient's global norm to ``clip`` (not in the paper; against exploding gradients).
    seed : int
        Weights, minibatch order and dropout masks; ``data_seed`` (default ``seed``) the trajectories:
        simulated from ``Generator([data_seed, 0])`` (training) and ``[data_seed, 1]`` (validation).
    progress : bool
        A tqdm bar over epochs.
    calibration : float
        Weight of the covariance calibration term of the Bayesian variant (supervised only).
    init : KalmanNet, optional
        Continue from these weights (options then come from it).
    **options
        :class:`KalmanNet`'s options (``feature_norm``, ``in_mult``, ``out_mult``, ``dropout``,
        ``n_samples``, ``model_grad``).

    max_cpu_s : float, optional
        A training budget in process CPU seconds (everything since the call: simulation,
        validation): training stops after the optimiser step that spends it, validates once more
        and keeps the best model (``history["stopped_by_budget"]``). For budget-matched studies.
    snapshots : sequence of int
        Epochs after which to keep the model as a training of that many epochs would have returned it
        (the best on validation so far, its history cut there): ``knet.snapshot(e)``. Training is
        deterministic per seed and an epoch does not depend on the epochs after it, so a snapshot at
        ``e`` is the filter of ``epochs=e`` (weights bit for bit; the CPU seconds are those spent up to
        it). One training then serves a budget curve (the learned-gain study). ValueError for an epoch
        outside ``1..epochs``.
    on_diverged : "raise", "restore" or "stop"
        What a non-finite training loss, gradient or validation loss does: ``"raise"`` (default)
        :class:`TrainingDiverged` naming the epoch and optimiser step; ``"restore"`` (a documented
        fallback, never silent) warns, goes back to the best weights so far, halves the learning
        rate with a fresh Adam state, skips the rest of that minibatch and records the event in
        ``history["restores"]``; more than ``max_restores`` such events raise. ``"stop"``: as
        ``"restore"``, but the event after ``max_restores`` ends the training with the best weights so
        far instead of raising, recorded in ``history["stopped_by_divergence"]`` (epoch, step, what)
        with a warning; the snapshots of later epochs are that filter (a training of that many epochs
        would have stopped there too). For studies that must report a diverged training, not lose it.

    Returns the filter with the best validation loss; ``knet.history`` holds the per-epoch training
    and validation losses, the best epoch and the training CPU seconds. Raises
    :class:`TrainingDiverged` on a non-finite loss or gradient, naming epoch and step.
    """
    if not isinstance(model, StateSpaceModel):
        raise TypeError(f"model must be an adaptfilt StateSpaceModel, got {type(model).__name__}")
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    for name, v in (("n_train", n_train), ("n_val", n_val), ("epochs", epochs), ("batch_size", batch_size)):
        if int(v) < 1:
            raise ValueError(f"{name} must be a positive integer, got {v}")
    if tbptt is not None and int(tbptt) < 1:
        raise ValueError(f"tbptt must be a positive window length or None, got {tbptt}")
    if clip is not None and not float(clip) > 0:
        raise ValueError(f"clip must be a positive gradient norm or None, got {clip}")
    if max_cpu_s is not None and not float(max_cpu_s) > 0:
        raise ValueError(f"max_cpu_s must be a positive number of CPU seconds or None, got {max_cpu_s}")
    snaps = sorted({int(e) for e in snapshots})
    if any(e < 1 or e > int(epochs) for e in snaps) or any(int(e) != e for e in snapshots):
        raise ValueError(f"snapshots must be epochs in 1..epochs={int(epochs)}, got {list(snapshots)}")
    if on_diverged not in ("raise", "restore", "stop"):
        raise ValueError(f"on_diverged must be 'raise', 'restore' or 'stop', got {on_diverged!r}")
    if not (math.isfinite(lr) and lr > 0):
        raise ValueError(f"lr must be positive, got {lr}")
    cpu0 = time.process_time()
    if init is not None and options:
        raise ValueError(f"give either init or KalmanNet options ({', '.join(options)}), not both")
    knet = KalmanNet(model, seed=seed, **options) if init is None else copy.deepcopy(init)
    if init is not None and (init.model.name, init.model.nx, init.model.nz) != (model.name, model.nx, model.nz):
        raise ValueError(f"init is a KalmanNet for model {init.model.name!r}, not for {model.name!r}")
    if loss == "unsupervised" and knet.options["model_grad"] == "detach":
        raise ValueError("the unsupervised loss reaches the weights only through f and h: use model_grad='jacobian'")
    ds = int(seed if data_seed is None else data_seed)
    T = n_steps or (train.n_steps if train is not None else model.n_steps)
    if train is None or val is None:
        if T is None:
            raise ValueError(f"model {model.name!r} has no horizon: give n_steps")
    train = _check_traj(train, model, "train") if train is not None else model.simulate(
        int(n_train), T, rng=np.random.default_rng([ds, 0]))
    val = _check_traj(val, model, "val") if val is not None else model.simulate(
        int(n_val), T, rng=np.random.default_rng([ds, 1]))
    opt = torch.optim.Adam(knet.net.parameters(), lr=lr, weight_decay=weight_decay)
    order_rng = np.random.default_rng([int(seed), 2])
    hist = {"train_loss": [], "val_loss": [], "best_epoch": 0, "loss": loss, "epochs": int(epochs),
            "batch_size": int(batch_size), "lr": lr, "weight_decay": weight_decay, "tbptt": tbptt, "clip": clip,
            "n_train": train.n_runs, "n_val": val.n_runs, "n_steps": train.n_steps, "data_seed": ds,
            "calibration": calibration, "on_diverged": on_diverged, "restores": [], "max_cpu_s": max_cpu_s,
            "stopped_by_budget": False, "stopped_by_divergence": None}
    M, Tn = train.n_runs, train.n_steps
    L = Tn if tbptt is None else int(tbptt)
    z_prev_all = knet._z_prev(train.z)
    bar = range(1, int(epochs) + 1)
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(bar, desc=f"train {knet!r}", leave=False)
    def diverged(what: str, epoch: int, step: int, state: dict, opt: torch.optim.Optimizer) -> torch.optim.Optimizer:
        """Raise, or restore the best weights with half the learning rate (``on_diverged``)."""
        msg = f"KalmanNet training: {what}"
        if on_diverged == "raise" or len(hist["restores"]) >= int(max_restores):
            extra = f" after {len(hist['restores'])} restores" if on_diverged != "raise" else ""
            if on_diverged == "stop":
                warnings.warn(msg + extra + "; training stopped with the best weights so far", RuntimeWarning,
                              stacklevel=3)
                hist["stopped_by_divergence"] = {"epoch": epoch, "step": step, "what": what}
                knet.net.load_state_dict(state)
                return opt
            raise TrainingDiverged(msg + extra + "; try clip=..., a smaller lr, tbptt=... or another feature_norm")
        lr_now = opt.param_groups[0]["lr"] * 0.5
        warnings.warn(msg + f"; restored the best weights so far, learning rate halved to {lr_now:.3g}",
                      RuntimeWarning, stacklevel=3)
        hist["restores"].append({"epoch": epoch, "step": step, "what": what, "lr": lr_now})
        knet.net.load_state_dict(state)
        return torch.optim.Adam(knet.net.parameters(), lr=lr_now, weight_decay=weight_decay)

    with one_torch_thread(), torch.random.fork_rng(devices=[]), np.errstate(over="ignore", invalid="ignore"):
        # numpy's overflow warnings of a diverging estimate are replaced by the check of the loss
        torch.manual_seed(int(seed) + 1)
        best = _evaluate(knet, val, loss, calibration)
        if not math.isfinite(best):  # an untrained filter that diverges on validation: any finite epoch beats it
            best = math.inf
        best_state = copy.deepcopy(knet.net.state_dict())
        hist["val_loss"].append(best)
        step = 0
        kept: dict[int, tuple[dict, dict]] = {}  # epoch -> (best weights so far, history then)
        for epoch in bar:
            knet.net.train()
            perm = order_rng.permutation(M)
            losses = []
            for a in range(0, M, int(batch_size)):
                idx = np.sort(perm[a:a + int(batch_size)])
                z, zp = train.z[idx], z_prev_all[idx]
                x = torch.from_numpy(train.x[idx])
                carry = knet._start(len(idx))
                for t0 in range(0, Tn, L):
                    t1 = min(Tn, t0 + L)
                    out, carry = knet._window(z[:, t0:t1], zp[:, t0:t1], t0, carry)
                    ell = _loss(knet, out, x[:, t0:t1], loss, calibration)
                    step += 1
                    if not torch.isfinite(ell):
                        opt = diverged(f"non-finite loss at epoch {epoch}, optimiser step {step} (steps {t0}..{t1 - 1})",
                                       epoch, step, best_state, opt)
                        break
                    opt.zero_grad()
                    ell.backward()
                    if clip is not None:
                        gnorm = nn.utils.clip_grad_norm_(knet.net.parameters(), float(clip))
                    else:
                        gnorm = torch.sqrt(sum((p.grad ** 2).sum() for p in knet.net.parameters() if p.grad is not None))
                    if not torch.isfinite(gnorm):
                        opt = diverged(f"non-finite gradient at epoch {epoch}, optimiser step {step} "
                                       f"(steps {t0}..{t1 - 1})", epoch, step, best_state, opt)
                        break
                    opt.step()
                    carry = carry.detach()
                    losses.append(float(ell.detach()))
                    if max_cpu_s is not None and time.process_time() - cpu0 >= max_cpu_s:
                        hist["stopped_by_budget"] = True
                        break
                if hist["stopped_by_budget"] or hist["stopped_by_divergence"]:
                    break
            if hist["stopped_by_divergence"]:
                break
            hist["train_loss"].append(float(np.mean(losses)) if losses else math.nan)
            v = _evaluate(knet, val, loss, calibration)
            hist["val_loss"].append(v)
            if not math.isfinite(v):
                opt = diverged(f"non-finite validation loss after epoch {epoch}", epoch, step, best_state, opt)
                if hist["stopped_by_divergence"]:
                    break
                continue
            if v < best:
                best, hist["best_epoch"] = v, epoch
                best_state = copy.deepcopy(knet.net.state_dict())
            if progress:
                bar.set_postfix(train=f"{hist['train_loss'][-1]:.4g}", val=f"{v:.4g}")
            if epoch in snaps:
                kept[epoch] = (copy.deepcopy(best_state), {
                    **hist, "train_loss": list(hist["train_loss"]), "val_loss": list(hist["val_loss"]),
                    "restores": list(hist["restores"]), "epochs": epoch, "best_val_loss": best,
                    "optimiser_steps": step, "cpu_s": time.process_time() - cpu0})
            if hist["stopped_by_budget"]:
                break
    if hist["stopped_by_divergence"]:  # the later snapshots are the filter a longer training would return
        for e in snaps:
            if e not in kept:
                kept[e] = (copy.deepcopy(best_state), {
                    **hist, "train_loss": list(hist["train_loss"]), "val_loss": list(hist["val_loss"]),
                    "restores": list(hist["restores"]), "epochs": e, "best_val_loss": best,
                    "optimiser_steps": step, "cpu_s": time.process_time() - cpu0})
    knet.net.load_state_dict(best_state)
    knet.net.eval()
    hist["best_val_loss"] = best
    hist["optimiser_steps"] = step
    hist["cpu_s"] = time.process_time() - cpu0
    knet.history = hist
    knet._snapshots = kept
    return knet
