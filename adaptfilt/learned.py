r"""Learned parameter policies: the actor and critic networks, and their files.

* :class:`Actor` -- ``f_phi``: information state -> ``|Theta|`` logits; the
  policy is ``softmax(f_phi(s))`` (Section IV-B). Two hidden layers of 64 ReLU
  units (Section VI-C).
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
learning-curve summary; a policy anchored on greedy or ML (:mod:`adaptfilt.anchor`) also records
``anchor = {policy, strength, kl}``, which ``act`` applies. The zip is written with a fixed date and sorted
entries and the JSON with sorted keys, so the same training gives a
byte-identical file.

>>> import numpy as np
>>> from adaptfilt.learned import Actor, LearnedPolicy
>>> from adaptfilt.features import FeatureScaler, FeatureSet, observe
>>> scaler = FeatureScaler(center=np.zeros(3), scale=np.ones(3))
>>> pol = LearnedPolicy(Actor(3, 4), scaler, grid=[0.0, 1.0, 2.0, 5.0], gamma=0.5)
>>> pol.name, pol.probs(np.zeros((2, 3))).shape
('adaptive', (2, 4))
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import torch
from torch import nn

from adaptfilt.anchor import Anchor, allowed_mask, anchor_onehot, anchored_logits
from adaptfilt.experiment_registry import resolve
from adaptfilt.features import FeatureScaler, FeatureSet, observe
from adaptfilt.files import read_npz, write_npz
from adaptfilt.nets import arrays_to_state, one_torch_thread, state_to_arrays
from adaptfilt.policies import grid_indices, grid_matches

__all__ = ["Actor", "Critic", "mlp", "LearnedPolicy", "load_policy", "POLICY_FORMAT", "check_compatible",
           "describe_target", "learned_name", "learned_names"]

POLICY_FORMAT = "adaptfilt-policy/1"
HIDDEN = (64, 64)


ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh}


def mlp(in_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN, activation: str = "relu") -> nn.Sequential:
    """``in_dim -> hidden[0] act -> hidden[1] act -> out_dim`` (PyTorch default init); ``act``
    is ReLU (the paper's) or tanh (Stable-Baselines3's default, for imported policies)."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
    layers: list[nn.Module] = []
    d = int(in_dim)
    for h in hidden:
        layers += [nn.Linear(d, int(h)), ACTIVATIONS[activation]()]
        d = int(h)
    layers.append(nn.Linear(d, int(out_dim)))
    return nn.Sequential(*layers)


class Actor(nn.Module):
    """``f_phi``: scaled information state ``(B, d)`` -> logits ``(B, |Theta|)``."""

    def __init__(self, in_dim: int, n_actions: int, hidden: Sequence[int] = HIDDEN, activation: str = "relu"):
        super().__init__()
        self.in_dim, self.n_actions, self.hidden = int(in_dim), int(n_actions), tuple(int(h) for h in hidden)
        self.activation = activation
        self.net = mlp(in_dim, n_actions, hidden, activation)

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


# ----------------------------------------------------------------- policy
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

    #: acts on its own grid, which may be a subset of the environment's (:func:`grid_indices`)
    acts_on_subset = True

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
        self.feature_set = FeatureSet.parse(self.metadata.get("feature_set"))
        #: an anchored policy adds ``c * onehot(the anchor's choice)`` to the actor's logits (:mod:`adaptfilt.anchor`)
        self.anchor = Anchor.from_dict(self.metadata.get("anchor"))

    @property
    def cost_blind(self) -> bool:
        """Whether its choices cannot depend on the cost: no candidate costs in its information state."""
        return not self.feature_set.candidates

    # --------------------------------------------------------- policy API
    def _logits(self, features: np.ndarray, anchor: np.ndarray | None, allowed: np.ndarray | None) -> torch.Tensor:
        s = torch.from_numpy(self.scaler.network_input(features))
        with torch.no_grad(), one_torch_thread():
            out = self.actor(s)
            if self.anchor is None:
                if anchor is not None or allowed is not None:
                    raise ValueError(f"policy {self.name!r} is not anchored: give no anchor")
                return out
            shape = tuple(out.shape)
            a = None if anchor is None else np.asarray(anchor, dtype=np.float32)
            if a is None or a.shape != shape:
                raise ValueError(f"policy {self.name!r} is anchored on {self.anchor.policy}: its logits need "
                                 f"anchor=anchor_onehot(decision, {self.anchor.policy!r}) of shape {shape}" + ("" if a is None else f", got {a.shape}"))
            m = None if allowed is None else np.asarray(allowed, dtype=np.float32)
            if (self.anchor.shield is None) != (m is None) or (m is not None and m.shape != shape):
                raise ValueError(f"policy {self.name!r}: " + (f"its shield needs allowed=allowed_mask(decision, "
                                 f"{self.anchor.shield:g}) of shape {shape}" if self.anchor.shield is not None
                                 else "it has no shield: give no allowed mask"))
            # float32 and one formula with training (adaptfilt.anchor.anchored_logits): the file acts as the model did
            return anchored_logits(out, torch.from_numpy(a), self.anchor.strength, None if m is None else torch.from_numpy(m))

    def logits(self, features: np.ndarray, anchor: np.ndarray | None = None, allowed: np.ndarray | None = None) -> np.ndarray:
        """Actor logits ``(M, |Theta|)`` for raw information states ``(M, d)``; an anchored policy
        (:mod:`adaptfilt.anchor`) also needs its anchor's one-hot ``anchor (M, |Theta|)`` and adds ``c`` times it,
        and with a shield its mask ``allowed (M, |Theta|)`` (masked candidates get ``MASKED_LOGIT``)."""
        return self._logits(features, anchor, allowed).double().numpy()

    def probs(self, features: np.ndarray, anchor: np.ndarray | None = None, allowed: np.ndarray | None = None) -> np.ndarray:
        """``pi(theta | s)`` as ``(M, |Theta|)`` for raw information states ``(M, d)`` (``anchor``, ``allowed``:
        see :meth:`logits`)."""
        return torch.softmax(self._logits(features, anchor, allowed), dim=-1).double().numpy()

    def act(self, decision) -> np.ndarray:
        """Grid indices ``(M,)``: ``argmax pi`` (or a draw from ``pi`` if ``sample``)."""
        to_env = grid_indices(self.grid, decision.grid, self.name)
        s = observe(decision, self.feature_set)
        anchor = allowed = None
        if self.anchor is not None:
            anchor = anchor_onehot(decision, self.anchor.policy, self.grid)
            if self.anchor.shield is not None:  # the anchor's own choice is always allowed (greedy's is anyway)
                keep = None if self.anchor.policy == "greedy" else anchor.argmax(axis=1)
                allowed = allowed_mask(decision, self.anchor.shield, self.grid, keep=keep)
        if not self.sample:
            return to_env[np.argmax(self.logits(s, anchor, allowed), axis=1)]
        p = self.probs(s, anchor, allowed)
        u = self.rng.random(p.shape[0])
        return to_env[np.minimum((np.cumsum(p, axis=1) < u[:, None]).sum(axis=1), p.shape[1] - 1)]

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
            "feature_set": self.feature_set.name,
            "actor": {"in_dim": self.actor.in_dim, "n_actions": self.actor.n_actions, "hidden": list(self.actor.hidden)},
        })
        if self.scaler.squash != "clip":  # absent in the first policy files: they all clip
            meta["scaler_squash"] = self.scaler.squash
        if self.actor.activation != "relu":
            meta["actor"]["activation"] = self.actor.activation
        return arrays, meta

    def save(self, path: str | os.PathLike) -> Path:
        """Write the policy file (see the module docstring); returns its path."""
        arrays, meta = self.to_arrays()
        return write_npz(path, arrays, meta)

    @classmethod
    def load(cls, path: str | os.PathLike, experiment=None) -> "LearnedPolicy":
        return load_policy(path, experiment)


def describe_target(experiment: Any, features: "str | FeatureSet | None" = None) -> dict:
    """What a policy must match (:func:`check_compatible`): the fields of a dict as they are, or the
    :meth:`~adaptfilt.paramenv.ParamEnv.describe` of what :func:`~adaptfilt.experiment_registry.resolve`
    makes of a name, an Experiment or an environment (plus the experiment's name for an experiment)."""
    if experiment is None:
        return {}
    if isinstance(experiment, Mapping):
        return dict(experiment)
    target = resolve(experiment)
    out = target.env.describe(features)
    if target.experiment is not None:
        out["experiment"] = target.experiment.name
    return out


def check_compatible(meta: Mapping, target: Mapping, what: str = "policy") -> None:
    """ValueError naming the first field in which ``meta`` and ``target`` disagree."""
    for key in ("experiment", "model", "filter", "param_name", "feature_names", "grid", "cost"):
        want = target.get(key)
        have = meta.get(key)
        if want is None or (have is None and key != "experiment"):
            continue  # the experiment is strict: a policy trained on a bare env is not "for" any experiment
        if key == "grid":  # a policy may act on a subset of the grid (grid_indices)
            same = grid_matches(have, want).any(axis=1).all()
        else:
            same = (list(want) == list(have)) if isinstance(want, (list, tuple)) else want == have
        if not same:
            raise ValueError(f"{what} mismatch in {key}: the file was trained for {key} = {have!r}, "
                             f"but the target has {key} = {want!r}")


def _check_policy_file(path, arrays: Mapping[str, np.ndarray], meta: Mapping) -> None:
    """ValueError "<path>: not an adaptfilt policy file (why)" unless ``read_npz``'s
    ``arrays`` and ``meta`` hold everything :func:`load_policy` reads."""
    def bad(why: str) -> ValueError:
        return ValueError(f"{path}: not an adaptfilt policy file ({why})")

    fmt = meta.get("format")
    if fmt != POLICY_FORMAT:
        if fmt is None and {"config", "episode"} <= set(meta):
            raise bad("it is a training checkpoint; finish the training with `adaptfilt train ... --resume`")
        raise bad(f"format {fmt!r}, expected {POLICY_FORMAT!r}")
    missing = [k for k in ("gamma", "grid", "actor", "scaler_clip") if k not in meta]
    missing += [k for k in ("scaler/center", "scaler/scale") if k not in arrays]
    if missing:
        raise bad(f"missing {', '.join(missing)}")
    a = meta["actor"]
    try:
        in_dim, n_actions, hidden = int(a["in_dim"]), int(a["n_actions"]), [int(h) for h in a["hidden"]]
        grid = np.asarray(meta["grid"], dtype=float)
        gamma = float(meta["gamma"])
    except (KeyError, TypeError, ValueError) as e:
        raise bad(f"malformed actor, grid or gamma metadata: {type(e).__name__}: {e}") from None
    if grid.ndim != 1 or grid.size != n_actions or not np.isfinite(grid).all():
        raise bad(f"the grid {grid.tolist()} does not give the actor's {n_actions} finite values")
    if not 0.0 <= gamma < 1.0:
        raise bad(f"gamma = {gamma!r} is outside [0, 1)")
    for k in ("scaler/center", "scaler/scale"):
        if arrays[k].shape != (in_dim,):
            raise bad(f"{k} has shape {arrays[k].shape}, the actor expects ({in_dim},)")
    if min(hidden, default=1) < 1 or in_dim < 1 or n_actions < 1:
        raise bad(f"an empty network layer in {a}")
    try:
        Anchor.from_dict(meta.get("anchor"))
    except ValueError as e:
        raise bad(str(e)) from None


def load_policy(path: str | os.PathLike, experiment=None, name: str | None = None) -> LearnedPolicy:
    """Read a policy file written by :meth:`LearnedPolicy.save` (no pickles).

    ``experiment`` (a name, an :class:`~adaptfilt.experiment_registry.Experiment`, a
    :class:`~adaptfilt.mdp.FilterEnv` or a dict of expected fields), if given,
    is checked against the file: a different experiment, model, filter (e.g. another SIF form), rule
    parameter, grid, feature layout or cost is a ``ValueError`` naming it.

    A file that is not a policy (random bytes, empty, truncated, an ``.npz``
    of plain arrays, a training checkpoint, missing or mis-shaped weights) is
    a ``ValueError`` "``<path>: not an adaptfilt policy file (<why>)``"; a
    missing file a ``FileNotFoundError`` naming the path.
    """
    arrays, meta = read_npz(path)
    _check_policy_file(path, arrays, meta)
    check_compatible(meta, describe_target(experiment, meta.get("feature_set")), what=f"policy {Path(path).name}")
    a = meta["actor"]
    actor = Actor(a["in_dim"], a["n_actions"], a["hidden"], a.get("activation", "relu"))
    try:
        actor.load_state_dict(arrays_to_state("actor", arrays))
    except RuntimeError as e:  # missing, unexpected or mis-shaped weights
        first = str(e).strip().splitlines()[:2]
        raise ValueError(f"{path}: not an adaptfilt policy file (its actor weights do not fit the "
                         f"{a['in_dim']}-{'-'.join(map(str, a['hidden']))}-{a['n_actions']} network: "
                         f"{' '.join(first)})") from None
    scaler = FeatureScaler(arrays["scaler/center"], arrays["scaler/scale"], float(meta["scaler_clip"]),
                           tuple(meta.get("feature_names") or ()), meta.get("scaler_squash", "clip"))
    curve = {k[len("curve/"):]: v for k, v in arrays.items() if k.startswith("curve/")}
    meta_rest = {k: v for k, v in meta.items()
                 if k not in ("gamma", "grid", "actor", "scaler_clip", "scaler_squash", "format")}
    return LearnedPolicy(actor, scaler, meta["grid"], gamma=meta["gamma"], name=name or meta.get("name"),
                         metadata=meta_rest, curve=curve)


def learned_name(path: str | Path, experiment: str) -> str:
    """Result name of a learned policy file: its stem, without the experiment
    prefix when it has one (``data/policies/ungm-ukf-adaptive-faithful.npz`` ->
    ``adaptive-faithful``, ``runs/try3.npz`` -> ``try3``)."""
    stem = Path(path).stem
    return stem[len(experiment) + 1:] if stem.startswith(experiment + "-") and len(stem) > len(experiment) + 1 else stem


def learned_names(paths: Iterable[str | Path], experiment: str) -> list[str]:
    """:func:`learned_name` of each file, made unique: files that would share a
    name (the same stem in different folders) are named ``<folder>/<name>``
    with as many trailing folders of their resolved path as it takes to tell
    them apart (``a/x/adaptive.npz``, ``b/x/adaptive.npz`` -> ``a/x/adaptive``,
    ``b/x/adaptive``). The same file given twice is a ``ValueError``.

    >>> learned_names(["data/policies/ungm-ukf-adaptive.npz", "runs/ungm-ukf-adaptive.npz", "runs/b.npz"], "ungm-ukf")
    ['policies/adaptive', 'runs/adaptive', 'b']
    """
    paths = [Path(p) for p in paths]
    resolved = [p.resolve() for p in paths]
    for i, r in enumerate(resolved):
        if r in resolved[:i]:
            raise ValueError(f"policy file {paths[i]} is given twice")
    names = [learned_name(p, experiment) for p in paths]
    for n in sorted({n for n in names if names.count(n) > 1}):
        group = [i for i, m in enumerate(names) if m == n]
        depth = max(len(resolved[i].parent.parts) for i in group)
        for d in range(1, depth + 1):
            cand = {i: "/".join([*resolved[i].parent.parts[-d:], n]) for i in group}
            if len(set(cand.values())) == len(group):
                break
        else:  # same folder, stems that strip to the same name (ungm-ukf-a.npz, a.npz): the file names
            cand = {i: str(resolved[i].parent / resolved[i].name) for i in group}
        for i in group:
            names[i] = cand[i]
    return names
