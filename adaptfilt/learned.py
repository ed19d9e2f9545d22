r"""Learned parameter policies: the actor and critic networks, and their files.

* :class:`Actor` -- ``f_phi``: information state -> ``|Theta|`` logits; the
  policy is ``softmax(f_phi(s))`` (Section IV-B). Two hidden layers of 64 ReLU
  units (Section V-C).
* :class:`Critic` -- ``V_psi``: information state -> scalar (same architecture).
* :class:`LearnedPolicy` -- an actor plus the :class:`~adaptfilt.mdp.FeatureScaler`
  it was trained with and the metadata that says what it is for. It implements
  the :class:`~adaptfilt.policies.Policy` protocol: ``act(decision)`` is the
  greedy ``argmax_theta pi(theta | s, z)`` of Algorithm 3 (``sample=True``
  draws from ``pi`` instead, as during training).

Policy files
------------
A policy is saved as one ``.npz`` (a zip of ``.npy`` arrays) that is read with
``np.load(..., allow_pickle=False)``: loading never executes pickled code.
It holds the actor weights (``actor/<parameter>``), the feature scaling
(``scaler/center``, ``scaler/scale``), the learning curve (``curve/<key>``)
and one JSON document (``__metadata__``, UTF-8 bytes) with the experiment,
model, rule parameter, grid, feature names, gamma, cost, seed, episodes,
parallel, hyperparameters, package version, the training command and a
learning-curve summary. The zip is written with a fixed date and sorted
entries and the JSON with sorted keys, so the same training gives a
byte-identical file.

>>> import numpy as np
>>> from adaptfilt.learned import Actor, LearnedPolicy
>>> from adaptfilt.mdp import FeatureScaler
>>> scaler = FeatureScaler(center=np.zeros(3), scale=np.ones(3))
>>> pol = LearnedPolicy(Actor(3, 4), scaler, grid=[0.0, 1.0, 2.0, 5.0], gamma=0.5)
>>> pol.name, pol.probs(np.zeros((2, 3))).shape
('adaptive', (2, 4))
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import zipfile
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch
from torch import nn

from adaptfilt.mdp import FeatureScaler

__all__ = ["Actor", "Critic", "mlp", "LearnedPolicy", "load_policy", "write_npz", "read_npz",
           "POLICY_FORMAT", "check_compatible"]

POLICY_FORMAT = "adaptfilt-policy/1"
HIDDEN = (64, 64)


def mlp(in_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN) -> nn.Sequential:
    """``in_dim -> hidden[0] ReLU -> hidden[1] ReLU -> out_dim`` (PyTorch default init)."""
    layers: list[nn.Module] = []
    d = int(in_dim)
    for h in hidden:
        layers += [nn.Linear(d, int(h)), nn.ReLU()]
        d = int(h)
    layers.append(nn.Linear(d, int(out_dim)))
    return nn.Sequential(*layers)


class Actor(nn.Module):
    """``f_phi``: scaled information state ``(B, d)`` -> logits ``(B, |Theta|)``."""

    def __init__(self, in_dim: int, n_actions: int, hidden: Sequence[int] = HIDDEN):
        super().__init__()
        self.in_dim, self.n_actions, self.hidden = int(in_dim), int(n_actions), tuple(int(h) for h in hidden)
        self.net = mlp(in_dim, n_actions, hidden)

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        return self.net(s)


class Critic(nn.Module):
    """``V_psi``: scaled information state ``(B, d)`` -> value ``(B,)``."""

    def __init__(self, in_dim: int, hidden: Sequence[int] = HIDDEN):
        super().__init__()
        self.in_dim, self.hidden = int(in_dim), tuple(int(h) for h in hidden)
        self.net = mlp(in_dim, 1, hidden)

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        return self.net(s).squeeze(-1)


# ------------------------------------------------------------------ files
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def write_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], metadata: Mapping[str, Any] | None = None) -> Path:
    """Write ``arrays`` (and ``metadata`` as a JSON ``__metadata__`` entry) to a
    byte-reproducible ``.npz``: sorted entries, fixed zip date, no pickles,
    atomic replace. ``np.load(path, allow_pickle=False)`` reads it back."""
    path = Path(path)
    items = dict(arrays)
    if metadata is not None:
        text = json.dumps(metadata, sort_keys=True, indent=1, allow_nan=True)
        items["__metadata__"] = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(items):
            arr = np.asarray(items[name])
            if arr.dtype == object:
                raise TypeError(f"{name}: object arrays cannot be stored without pickling")
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())
    os.replace(tmp, path)
    return path


def read_npz(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Arrays and metadata of a file written by :func:`write_npz` (no pickles)."""
    with np.load(Path(path), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta_bytes = arrays.pop("__metadata__", None)
    meta = {} if meta_bytes is None else json.loads(meta_bytes.tobytes().decode("utf-8"))
    return arrays, meta


def state_to_arrays(prefix: str, module: nn.Module) -> dict[str, np.ndarray]:
    """``module.state_dict()`` as ``{prefix/name: array}``."""
    return {f"{prefix}/{k}": v.detach().cpu().numpy().copy() for k, v in module.state_dict().items()}


def arrays_to_state(prefix: str, arrays: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
    p = prefix + "/"
    return {k[len(p):]: torch.from_numpy(np.array(v)) for k, v in arrays.items() if k.startswith(p)}


# ----------------------------------------------------------------- policy
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


class LearnedPolicy:
    """A trained actor used as a policy (Algorithm 3).

    Parameters
    ----------
    actor : Actor
    scaler : FeatureScaler
        The scaling of the raw information state the actor was trained on.
    grid : sequence of float
        The parameter values the actor's outputs index.
    gamma : float
        Discount it was trained with; names the policy ``adaptive`` (gamma > 0)
        or ``myopic`` (gamma = 0) unless ``name`` is given.
    metadata : dict
        Everything else (experiment, model, cost, seed, command, curve summary...).
    sample : bool
        ``False`` (default): ``act`` returns the most probable index (Algorithm 3);
        ``True``: draws from ``pi`` with ``rng`` (as during training).
    """

    def __init__(self, actor: Actor, scaler: FeatureScaler, grid: Sequence[float], gamma: float = 0.5,
                 name: str | None = None, metadata: dict | None = None, sample: bool = False,
                 rng: np.random.Generator | int | None = None, curve: Mapping[str, np.ndarray] | None = None):
        self.actor = actor.eval()
        self.scaler = scaler
        self.grid = np.asarray(grid, dtype=float)
        if self.grid.size != actor.n_actions:
            raise ValueError(f"the actor has {actor.n_actions} outputs but the grid has {self.grid.size} values")
        if scaler.center.shape[0] != actor.in_dim:
            raise ValueError(f"the scaler has {scaler.center.shape[0]} features but the actor expects {actor.in_dim}")
        self.gamma = float(gamma)
        self.name = name or ("adaptive" if self.gamma > 0 else "myopic")
        self.metadata = dict(metadata or {})
        self.curve = {k: np.asarray(v) for k, v in (curve or {}).items()}
        self.sample = bool(sample)
        self.rng = np.random.default_rng(rng)

    # --------------------------------------------------------- policy API
    def logits(self, features: np.ndarray) -> np.ndarray:
        """Actor logits ``(M, |Theta|)`` for raw information states ``(M, d)``."""
        s = torch.from_numpy(self.scaler(features).astype(np.float32))
        with torch.no_grad(), one_torch_thread():
            return self.actor(s).double().numpy()

    def probs(self, features: np.ndarray) -> np.ndarray:
        """``pi(theta | s)`` as ``(M, |Theta|)`` for raw information states ``(M, d)``."""
        s = torch.from_numpy(self.scaler(features).astype(np.float32))
        with torch.no_grad(), one_torch_thread():
            return torch.softmax(self.actor(s), dim=-1).double().numpy()

    def act(self, decision) -> np.ndarray:
        """Grid indices ``(M,)``: ``argmax pi`` (or a draw from ``pi`` if ``sample``)."""
        if decision.grid.shape != self.grid.shape or not np.allclose(decision.grid, self.grid):
            raise ValueError(f"policy {self.name!r} was trained on the grid {self.grid.tolist()}, "
                             f"the environment uses {np.asarray(decision.grid).tolist()}")
        if not self.sample:
            return np.argmax(self.logits(decision.features), axis=1)
        p = self.probs(decision.features)
        u = self.rng.random(p.shape[0])
        return np.minimum((np.cumsum(p, axis=1) < u[:, None]).sum(axis=1), p.shape[1] - 1)

    def __repr__(self) -> str:
        e = self.metadata.get("experiment")
        return f"LearnedPolicy(name={self.name!r}, experiment={e!r}, gamma={self.gamma:g}, grid={self.grid.tolist()})"

    # --------------------------------------------------------------- files
    def to_arrays(self) -> tuple[dict[str, np.ndarray], dict]:
        arrays = state_to_arrays("actor", self.actor)
        arrays["scaler/center"] = np.asarray(self.scaler.center, float)
        arrays["scaler/scale"] = np.asarray(self.scaler.scale, float)
        for k, v in self.curve.items():
            arrays[f"curve/{k}"] = np.asarray(v)
        meta = dict(self.metadata)
        meta.update({
            "format": POLICY_FORMAT,
            "name": self.name,
            "gamma": self.gamma,
            "grid": self.grid.tolist(),
            "feature_names": list(self.scaler.names),
            "scaler_clip": float(self.scaler.clip),
            "actor": {"in_dim": self.actor.in_dim, "n_actions": self.actor.n_actions, "hidden": list(self.actor.hidden)},
        })
        return arrays, meta

    def save(self, path: str | os.PathLike) -> Path:
        """Write the policy file (see the module docstring); returns its path."""
        arrays, meta = self.to_arrays()
        return write_npz(path, arrays, meta)

    @classmethod
    def load(cls, path: str | os.PathLike, experiment=None) -> "LearnedPolicy":
        return load_policy(path, experiment)


def _describe_target(experiment) -> dict:
    """What a policy must match: from an experiment name / Experiment / FilterEnv / dict."""
    if experiment is None:
        return {}
    if isinstance(experiment, Mapping):
        return dict(experiment)
    if isinstance(experiment, str):
        from adaptfilt.experiments import get_experiment

        experiment = get_experiment(experiment)
    if hasattr(experiment, "make_env"):  # an Experiment
        env = experiment.make_env()
        out = describe_env(env)
        out["experiment"] = experiment.name
        return out
    return describe_env(experiment)


def describe_env(env) -> dict:
    """Model name, rule parameter, grid, feature names and cost of an environment."""
    from adaptfilt.mdp import feature_names

    model = getattr(env, "model", None)
    filt = getattr(env, "filt", None)
    names = getattr(env, "feature_names", None)
    if names is None and model is not None:
        names = feature_names(model.nx, model.nz)
    cost = getattr(env, "cost", None)
    return {
        "model": getattr(model, "name", getattr(env, "name", None)),
        "param_name": getattr(getattr(filt, "rule", None), "param_name", getattr(env, "param_name", None)),
        "grid": np.asarray(env.grid, float).tolist(),
        "feature_names": list(names) if names is not None else None,
        "cost": getattr(cost, "name", None),
    }


def check_compatible(meta: Mapping, target: Mapping, what: str = "policy") -> None:
    """ValueError naming the first field in which ``meta`` and ``target`` disagree."""
    for key in ("experiment", "model", "param_name", "feature_names", "grid", "cost"):
        want = target.get(key)
        have = meta.get(key)
        if want is None or (have is None and key != "experiment"):
            continue  # the experiment is strict: a policy trained on a bare env is not "for" any experiment
        if key == "grid":
            same = len(want) == len(have) and np.allclose(want, have)
        else:
            same = (list(want) == list(have)) if isinstance(want, (list, tuple)) else want == have
        if not same:
            raise ValueError(f"{what} mismatch in {key}: the file was trained for {key} = {have!r}, "
                             f"but the target has {key} = {want!r}")


def load_policy(path: str | os.PathLike, experiment=None, name: str | None = None) -> LearnedPolicy:
    """Read a policy file written by :meth:`LearnedPolicy.save` (no pickles).

    ``experiment`` (a name, an :class:`~adaptfilt.experiments.Experiment`, a
    :class:`~adaptfilt.mdp.FilterEnv` or a dict of expected fields), if given,
    is checked against the file: a different experiment, model, rule
    parameter, grid, feature layout or cost is a ``ValueError`` naming it.
    """
    arrays, meta = read_npz(path)
    if meta.get("format") != POLICY_FORMAT:
        raise ValueError(f"{path}: not an adaptfilt policy file (format {meta.get('format')!r}, expected {POLICY_FORMAT!r})")
    check_compatible(meta, _describe_target(experiment), what=f"policy {Path(path).name}")
    a = meta["actor"]
    actor = Actor(a["in_dim"], a["n_actions"], a["hidden"])
    actor.load_state_dict(arrays_to_state("actor", arrays))
    scaler = FeatureScaler(arrays["scaler/center"], arrays["scaler/scale"], float(meta["scaler_clip"]),
                           tuple(meta.get("feature_names") or ()))
    curve = {k[len("curve/"):]: v for k, v in arrays.items() if k.startswith("curve/")}
    meta_rest = {k: v for k, v in meta.items() if k not in ("gamma", "grid", "actor", "scaler_clip", "format")}
    return LearnedPolicy(actor, scaler, meta["grid"], gamma=meta["gamma"], name=name or meta.get("name"),
                         metadata=meta_rest, curve=curve)
