r"""The gain networks of KalmanNet's two architectures (:mod:`adaptfilt.kalmannet` filters with them).

Written from the paper (Revach, Shlezinger, Ni, López Escoriza, van Sloun, Eldar, "KalmanNet: Neural
network aided Kalman filtering for partially known dynamics", IEEE Trans. Signal Processing 70, 2022);
no code of the authors' (unlicensed) repository is used. ``m = nx``, ``n = nz``; the features are the
paper's F1 (observation difference), F2 (innovation), F3 (forward evolution difference) and F4
(forward update difference), each ``(B, n)`` or ``(B, m)``, already normalised by the filter.

Both networks have one interface, which the filter's recursion calls once per step:
``initial_states(B)`` (a tuple of recurrent states), ``dropout_mask(B)`` (the Bayesian variant's mask,
or None) and ``step(F1, F2, F3, F4, *states, mask=None) -> (K, *states)`` with the gain
``K (B, m, n)``.

**Architecture 2** (:class:`GainNet`, the paper's main one): three GRUs that mirror the Kalman
filter's covariances Q, Sigma and S,

.. math::
    h^Q_t = \mathrm{GRU}_Q(\mathrm{FC}_5(F_4), h^Q_{t-1}),\quad
    \Sigma_t = \mathrm{GRU}_\Sigma([h^Q_t, \mathrm{FC}_6(F_3)], h^\Sigma_{t-1}),\quad
    h^S_t = \mathrm{GRU}_S([\mathrm{FC}_1(\Sigma_t), \mathrm{FC}_7([F_1, F_2])], h^S_{t-1}),

.. math::
    K_t = \mathrm{FC}_2([\Sigma_t, h^S_t]),\qquad
    h^\Sigma_t = \mathrm{FC}_4([\Sigma_t, \mathrm{FC}_3([h^S_t, K_t])])\ \text{(the backward flow)},

hidden sizes ``m^2``, ``m^2``, ``n^2`` (times ``hidden_mult``, default 1: the paper's), input layers
``in_mult = 5`` times wider than their input, FC2's hidden layer ``(m^2 + n^2) out_mult`` with
``out_mult = 40``; every FC layer but FC2's output has a ReLU. The GRU states start from the priors
``vec(I_m)``, ``0``, ``vec(I_n)`` (tiled ``hidden_mult`` times). On a scalar model each GRU has one
unit and the network 472 weights; ``hidden_mult`` (a departure, recorded) widens the three GRUs.

**Architecture 1** (:class:`GainNet1`, the paper's first and simpler one): one recurrent network over
the concatenated features,

.. math::
    a_t = \mathrm{ReLU}(\mathrm{FC}_{in}([F_1, F_3, F_4])),\qquad
    h_t = \mathrm{GRU}(a_t, h_{t-1})\ (\text{layers } \ell = 1..L),\qquad K_t = \mathrm{FC}_{out}(h^{(L)}_t),

hidden size ``10 (m^2 + n^2)`` and ``L = 2`` layers by default (the public code's sizes), the input
layer ``80 (m + n)`` wide, states starting at zero. ``inputs`` chooses the features (default
``"134"``: F1, F3, F4 as the paper; ``"1234"`` adds the innovation). On a scalar model: 14,101 weights.

Example
-------
>>> import torch
>>> from adaptfilt.gainnets import GainNet, GainNet1
>>> net = GainNet1(1, 1).double()
>>> F = [torch.zeros(4, 1, dtype=torch.float64)] * 4
>>> K, *h = net.step(*F, *net.initial_states(4))
>>> K.shape, len(h), sum(p.numel() for p in net.parameters())
(torch.Size([4, 1, 1]), 2, 14101)
"""
from __future__ import annotations

import torch
from torch import nn

__all__ = ["GainNet", "GainNet1", "ARCHS", "make_gain_net"]

#: The architectures of the paper: 1 (one GRU over the concatenated features) and 2 (three GRUs).
ARCHS = (1, 2)
_DT = torch.float64


class GainNet(nn.Module):
    """KalmanNet's architecture 2: three GRUs (Q, Sigma, S) and the fully connected layers FC1-FC7.

    ``step`` maps the four (normalised) features and the GRU states of one step (batch ``B``) to the
    gain ``K (B, m, n)`` and the next GRU states; ``mask`` is the Bayesian variant's dropout mask.
    ``hidden_mult`` multiplies the three GRUs' widths (1: the paper's ``m^2``, ``m^2``, ``n^2``).
    """

    def __init__(self, nx: int, nz: int, in_mult: int = 5, out_mult: int = 40, dropout: float = 0.0,
                 hidden_mult: int = 1):
        super().__init__()
        m, n, w = int(nx), int(nz), int(hidden_mult)
        self.nx, self.nz, self.dropout, self.hidden_mult = m, n, float(dropout), w
        mm, nn_ = m * m * w, n * n * w  # the GRUs' widths
        relu = nn.ReLU
        self.fc5 = nn.Sequential(nn.Linear(m, in_mult * m), relu())            # F4 -> Q-GRU
        self.gru_Q = nn.GRUCell(in_mult * m, mm)
        self.fc6 = nn.Sequential(nn.Linear(m, in_mult * m), relu())            # F3 -> Sigma-GRU
        self.gru_Sigma = nn.GRUCell(mm + in_mult * m, mm)
        self.fc1 = nn.Sequential(nn.Linear(mm, nn_), relu())                   # Sigma -> S-GRU
        self.fc7 = nn.Sequential(nn.Linear(2 * n, 2 * in_mult * n), relu())    # [F1, F2] -> S-GRU
        self.gru_S = nn.GRUCell(nn_ + 2 * in_mult * n, nn_)
        hidden = (m * m + n * n) * out_mult
        self.fc2_hidden = nn.Linear(mm + nn_, hidden)                          # FC2: the gain head
        self.fc2_out = nn.Linear(hidden, m * n)
        self.fc3 = nn.Sequential(nn.Linear(nn_ + m * n, mm), relu())           # backward flow
        self.fc4 = nn.Sequential(nn.Linear(2 * mm, mm), relu())

    def initial_states(self, B: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """GRU states from the priors ``vec(I_m)``, ``0``, ``vec(I_n)`` (tiled ``hidden_mult`` times)."""
        m, n, w = self.nx, self.nz, self.hidden_mult
        h_Q = torch.eye(m, dtype=_DT).reshape(1, -1).repeat(1, w).expand(B, -1).contiguous()
        h_Sigma = torch.zeros(B, m * m * w, dtype=_DT)
        h_S = torch.eye(n, dtype=_DT).reshape(1, -1).repeat(1, w).expand(B, -1).contiguous()
        return h_Q, h_Sigma, h_S

    def dropout_mask(self, B: int) -> torch.Tensor | None:
        """A Monte-Carlo dropout mask of FC2's hidden layer per run (scaled by ``1/(1-p)``), or None."""
        return _mask(self.dropout, B, self.fc2_hidden.out_features)

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


class GainNet1(nn.Module):
    """KalmanNet's architecture 1: an input FC layer, a ``layers``-layer GRU and an output FC layer.

    ``hidden`` GRU units (default ``10 (m^2 + n^2)``), ``in_width`` units in the input layer (default
    ``80 (m + n)``), ``inputs`` the features fed in (digits of F1..F4, default ``"134"``). ``mask``
    (the Bayesian variant) drops units of the top GRU's output before the gain layer.
    """

    def __init__(self, nx: int, nz: int, hidden: int | None = None, layers: int = 2, in_width: int | None = None,
                 inputs: str = "134", dropout: float = 0.0):
        super().__init__()
        m, n = int(nx), int(nz)
        feats = tuple(int(c) for c in str(inputs))
        if not feats or len(set(feats)) != len(feats) or not set(feats) <= {1, 2, 3, 4}:
            raise ValueError(f"inputs must name distinct features among 1-4 (e.g. '134'), got {inputs!r}")
        if int(layers) < 1:
            raise ValueError(f"layers must be a positive integer, got {layers}")
        self.nx, self.nz, self.dropout, self.inputs = m, n, float(dropout), feats
        self.hidden = int(hidden) if hidden is not None else 10 * (m * m + n * n)
        width = int(in_width) if in_width is not None else 80 * (m + n)
        if self.hidden < 1 or width < 1:
            raise ValueError(f"hidden and in_width must be positive, got {self.hidden}, {width}")
        d_in = sum(n if i in (1, 2) else m for i in feats)
        self.fc_in = nn.Sequential(nn.Linear(d_in, width), nn.ReLU())
        self.grus = nn.ModuleList(nn.GRUCell(width if i == 0 else self.hidden, self.hidden) for i in range(int(layers)))
        self.fc_out = nn.Linear(self.hidden, m * n)

    def initial_states(self, B: int) -> tuple[torch.Tensor, ...]:
        """One zero state per GRU layer (architecture 1 has no priors)."""
        return tuple(torch.zeros(B, self.hidden, dtype=_DT) for _ in self.grus)

    def dropout_mask(self, B: int) -> torch.Tensor | None:
        return _mask(self.dropout, B, self.hidden)

    def step(self, F1: torch.Tensor, F2: torch.Tensor, F3: torch.Tensor, F4: torch.Tensor, *h: torch.Tensor,
             mask: torch.Tensor | None = None) -> tuple[torch.Tensor, ...]:
        F = (F1, F2, F3, F4)
        a = self.fc_in(torch.cat([F[i - 1] for i in self.inputs], -1))
        new = []
        for gru, h_l in zip(self.grus, h):
            a = gru(a, h_l)
            new.append(a)
        if mask is not None:
            a = a * mask
        return (self.fc_out(a).reshape(-1, self.nx, self.nz), *new)


def _mask(p: float, B: int, width: int) -> torch.Tensor | None:
    if p == 0.0:
        return None
    keep = 1.0 - p
    return torch.bernoulli(torch.full((B, width), keep, dtype=_DT)) / keep


def make_gain_net(arch: int, nx: int, nz: int, *, in_mult: int = 5, out_mult: int = 40, hidden_mult: int = 1,
                  gru_hidden: int | None = None, gru_layers: int = 2, in_width: int | None = None,
                  inputs: str = "134", dropout: float = 0.0) -> nn.Module:
    """The gain network of architecture ``arch`` (float64); the options of the other one must keep their
    defaults (a ValueError names the first that does not)."""
    if arch == 2:
        other = dict(gru_hidden=(gru_hidden, None), gru_layers=(gru_layers, 2), in_width=(in_width, None),
                     inputs=(inputs, "134"))
        net = lambda: GainNet(nx, nz, in_mult, out_mult, dropout, hidden_mult)  # noqa: E731
    elif arch == 1:
        other = dict(in_mult=(in_mult, 5), out_mult=(out_mult, 40), hidden_mult=(hidden_mult, 1))
        net = lambda: GainNet1(nx, nz, gru_hidden, gru_layers, in_width, inputs, dropout)  # noqa: E731
    else:
        raise ValueError(f"arch must be one of {ARCHS} (the paper's architectures), got {arch!r}")
    for k, (v, d) in other.items():
        if v != d:
            raise ValueError(f"{k}={v!r} is an option of the other architecture, not of architecture {arch}")
    return net().to(_DT)
