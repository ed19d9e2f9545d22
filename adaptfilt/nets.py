"""What a torch network shares with its file: its weights as named numpy arrays, and inference on one thread.

The networks of the library (the policies' actor and critic, :mod:`adaptfilt.learned`; KalmanNet's gain,
:mod:`adaptfilt.kalmannet`) store their weights in an ``.npz`` (:func:`adaptfilt.files.write_npz`) as
``{prefix/name: array}`` (:func:`state_to_arrays`, :func:`arrays_to_state`) and run inference with
:func:`one_torch_thread`.

>>> from torch import nn
>>> net = nn.Linear(2, 3)
>>> arrays = state_to_arrays("net", net)
>>> sorted(arrays), arrays["net/weight"].shape
(['net/bias', 'net/weight'], (3, 2))
>>> nn.Linear(2, 3).load_state_dict(arrays_to_state("net", arrays))
<All keys matched successfully>
"""
from __future__ import annotations

import contextlib
from typing import Mapping

import numpy as np
import torch
from torch import nn

__all__ = ["state_to_arrays", "arrays_to_state", "one_torch_thread"]


def state_to_arrays(prefix: str, module: nn.Module | Mapping[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """``module.state_dict()`` (or a state dict itself) as ``{prefix/name: array}``."""
    state = module.state_dict() if isinstance(module, nn.Module) else module
    return {f"{prefix}/{k}": v.detach().cpu().numpy().copy() for k, v in state.items()}


def arrays_to_state(prefix: str, arrays: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """The ``prefix/`` entries of ``arrays`` as a ``state_dict`` (tensors that own their memory)."""
    p = prefix + "/"
    return {k[len(p):]: torch.from_numpy(np.array(v)) for k, v in arrays.items() if k.startswith(p)}


def adam_to_arrays(prefix: str, opt: torch.optim.Optimizer) -> dict[str, np.ndarray]:
    """An optimiser's per-parameter state (Adam's step and moments) as ``{prefix/i/name: array}``; the learning
    rate and the other settings live in its param groups, which the caller builds again."""
    out = {}
    for i, st in opt.state_dict()["state"].items():
        for k, v in st.items():
            out[f"{prefix}/{i}/{k}"] = v.detach().cpu().numpy().copy() if torch.is_tensor(v) else np.asarray(v)
    return out


def arrays_to_adam(prefix: str, opt: torch.optim.Optimizer, arrays: Mapping[str, np.ndarray]) -> None:
    """Load what :func:`adam_to_arrays` wrote into ``opt`` (built with the same parameters and settings)."""
    sd = opt.state_dict()
    state: dict[int, dict] = {}
    p = prefix + "/"
    for key, v in arrays.items():
        if key.startswith(p):
            i, k = key[len(p):].split("/")
            state.setdefault(int(i), {})[k] = torch.from_numpy(np.array(v))
    sd["state"] = state
    opt.load_state_dict(sd)


@contextlib.contextmanager
def one_torch_thread():
    """Run torch on one thread inside the block and restore the caller's setting.

    The networks are tiny (2 x 64 units): with several intra-op threads on a
    busy machine one forward pass was measured 40-170x slower than on one
    thread (the threads wait on each other), so inference always uses one.
    """
    n = torch.get_num_threads()
    if n != 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if n != 1:
            torch.set_num_threads(n)
