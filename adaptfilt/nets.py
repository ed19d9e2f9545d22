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


def state_to_arrays(prefix: str, module: nn.Module) -> dict[str, np.ndarray]:
    """``module.state_dict()`` as ``{prefix/name: array}``."""
    return {f"{prefix}/{k}": v.detach().cpu().numpy().copy() for k, v in module.state_dict().items()}


def arrays_to_state(prefix: str, arrays: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """The ``prefix/`` entries of ``arrays`` as a ``state_dict`` (tensors that own their memory)."""
    p = prefix + "/"
    return {k[len(p):]: torch.from_numpy(np.array(v)) for k, v in arrays.items() if k.startswith(p)}


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
