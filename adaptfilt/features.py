r"""What a policy sees: information-state feature sets and their scaling.

The paper's information state (Section VI-D) is

.. math::
    \bar s_t = [\hat x_{t|t-1}^T,\ \mathrm{tr} P_{t|t-1},\ \log\det P_{t|t-1},\ z_t^T,\
    \tilde z_{t|t-1}^T]^T,

``nx + 2 + 2 nz`` numbers, with the innovation ``z~`` computed at the *default*
parameter (the chosen one is not known when the state is formed). That is the
feature set ``"paper"``. :class:`FeatureSet` adds optional blocks, each named
by a token appended with ``+``:

=========  ==================================================================
token      what it adds or changes
=========  ==================================================================
``time``   the model's phase features ``model.time_features(k)`` (UNGM:
           ``cos 0.05k, sin 0.05k``, the forcing term of its dynamics); a
           time-invariant model (CTM) has none. The horizon itself is not a
           feature: the last step is a time limit, and the trainers bootstrap
           there (the process goes on).
``circ``   a measurement component that is an angle (``model.circular_z``) is
           fed as ``(sin z, cos z)`` instead of the raw angle, which jumps
           at ``+-pi``.
``cand``   for every grid value ``theta_g``, that candidate's one-step cost
           ``log(1 + L(s, z, theta_g))`` (needs an environment with a cost):
           what the exhaustive greedy policy sees, as features
           (one tiled update; see :meth:`adaptfilt.mdp.Decision.candidates`).
``lik``    for every grid value, that candidate's log-likelihood relative to
           the most likely one, ``log N(z; z_pred(theta_g), Pzz(theta_g)) -
           max_theta log N(...)`` (``<= 0``; 0 at ML's choice): what maximum
           likelihood ranks, from the same candidate updates (a non-finite
           one reads as ``-710``).
``innov@v`` the innovation feature computed with parameter ``v`` instead of
           the default: for the SIF, ``innov@1`` costs one iteration instead
           of the default's ten, every step (the paper's information state is
           not free: what it costs is counted in ``Decision.extra_spent``).
=========  ==================================================================

e.g. ``FeatureSet.parse("paper+time+circ")``. The feature *names* are stored
in a policy file, so a policy is only ever applied to the layout it was
trained on.

:class:`FeatureScaler` maps raw features to what a network sees:
``squash((s - center) / scale)`` with a robust centre and scale (median,
IQR / 1.349) and ``squash`` either ``clip`` to ``+-10`` (the first policies)
or ``asinh`` (linear near 0, logarithmic in the tails: a predicted variance
of 100 stays distinguishable from 1.3, and nothing saturates).
:func:`fit_scaler` fits it on the states that a *mix* of parameter values
visits, not only the default's: a scaler fitted on default-policy states
put ``tr P`` and ``log det P`` at the clip in 16-29 % of the steps that other
policies visit on UNGM.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

__all__ = ["FeatureSet", "FeatureScaler", "feature_names", "fit_scaler", "visited_states", "PAPER"]

_TOKENS = ("time", "circ", "cand", "lik")


@dataclass(frozen=True)
class FeatureSet:
    """Which features make up the information state (see the module docstring).

    >>> FeatureSet.parse("paper+circ+time").name
    'paper+time+circ'
    >>> FeatureSet.parse(None) == FeatureSet()
    True
    """

    time: bool = False
    circular: bool = False
    candidates: bool = False
    innovation: float | None = None  # parameter of the innovation feature (None: the filter's default)
    likelihoods: bool = False  # the candidates' relative log-likelihoods (token ``lik``)

    @classmethod
    def parse(cls, spec: "str | FeatureSet | None") -> "FeatureSet":
        """``None`` or ``"paper"`` -> the paper's; ``"paper+time+circ+cand"`` -> those blocks."""
        if spec is None:
            return cls()
        if isinstance(spec, FeatureSet):
            return spec
        if not isinstance(spec, str):
            raise TypeError(f"a feature set is a string like 'paper+time', got {type(spec).__name__}")
        tokens = spec.strip().split("+")
        if tokens[0] != "paper":
            raise ValueError(f"feature set {spec!r} must start with 'paper' (e.g. 'paper+time+circ')")
        innov = [t for t in tokens[1:] if t.startswith("innov@")]
        bad = [t for t in tokens[1:] if t not in _TOKENS and t not in innov]
        if bad:
            raise ValueError(f"unknown feature token(s) {bad} in {spec!r}; known: {', '.join(_TOKENS)}, innov@<value>")
        value = None
        if innov:
            try:
                value = float(innov[-1][len("innov@"):])
            except ValueError:
                raise ValueError(f"innov@ needs a parameter value (e.g. innov@1), got {innov[-1]!r}") from None
        return cls(time="time" in tokens, circular="circ" in tokens, candidates="cand" in tokens, innovation=value,
                   likelihoods="lik" in tokens)

    @property
    def name(self) -> str:
        tokens = [t for t, on in zip(_TOKENS, (self.time, self.circular, self.candidates, self.likelihoods)) if on]
        if self.innovation is not None:
            tokens.append(f"innov@{self.innovation:g}")
        return "+".join(["paper"] + tokens)

    def __str__(self) -> str:
        return self.name

    def names(self, model, grid: Sequence[float] | None = None) -> list[str]:
        """Feature names for ``model`` (and the grid, for ``cand``), in order."""
        nx, nz = model.nx, model.nz
        circ = set(model.circular_z) if self.circular else set()
        z = []
        for i in range(nz):
            z += [f"sin z[{i}]", f"cos z[{i}]"] if i in circ else [f"z[{i}]"]
        out = [f"x_pred[{i}]" for i in range(nx)] + ["tr P_pred", "logdet P_pred"] + z
        if self.innovation is None:
            out += [f"innov_default[{i}]" for i in range(nz)]
        else:
            out += [f"innov@{self.innovation:g}[{i}]" for i in range(nz)]
        if self.time:
            out += [f"time[{n}]" for n in model.time_feature_names]
        if self.candidates:
            if grid is None:
                raise ValueError("the 'cand' features need the parameter grid")
            out += [f"log1p cost[{g:g}]" for g in grid]
        if self.likelihoods:
            if grid is None:
                raise ValueError("the 'lik' features need the parameter grid")
            out += [f"loglik - max[{g:g}]" for g in grid]
        return out

    def size(self, model, grid: Sequence[float] | None = None) -> int:
        return len(self.names(model, grid))


PAPER = FeatureSet()


def feature_names(nx: int, nz: int) -> list[str]:
    """Names of the paper's information-state features, in order."""
    return ([f"x_pred[{i}]" for i in range(nx)] + ["tr P_pred", "logdet P_pred"]
            + [f"z[{i}]" for i in range(nz)] + [f"innov_default[{i}]" for i in range(nz)])


#: Bound of every network input (:meth:`FeatureScaler.network_input`); the Gymnasium observation space.
OBS_LIMIT = 50.0


@dataclass
class FeatureScaler:
    """Feature scaling ``squash((s - center) / scale)``; travels with a trained policy.

    ``squash="clip"``: ``clip(., -clip, clip)`` (the first policies);
    ``squash="asinh"``: ``asinh(.)``, which never saturates. ``fit`` is
    robust (median and IQR / 1.349): the states are heavy-tailed (UNGM's
    log-determinant and innovation) and a mean/std fit would follow a few runs.

    >>> s = FeatureScaler(center=np.zeros(1), scale=np.ones(1), squash="asinh")
    >>> round(float(s(np.array([[100.0]]))[0, 0]), 3)
    5.298
    """

    center: np.ndarray
    scale: np.ndarray
    clip: float = 10.0
    names: tuple[str, ...] = ()
    squash: Literal["clip", "asinh"] = "clip"

    def __post_init__(self):
        if self.squash not in ("clip", "asinh"):
            raise ValueError(f"squash must be 'clip' or 'asinh', got {self.squash!r}")
        self.center = np.asarray(self.center, dtype=float)
        self.scale = np.asarray(self.scale, dtype=float)
        if self.center.shape != self.scale.shape or self.center.ndim != 1:
            raise ValueError(f"center {self.center.shape} and scale {self.scale.shape} must be equal 1-D shapes")
        if not (np.isfinite(self.scale).all() and (self.scale > 0).all()):
            raise ValueError("every feature scale must be finite and > 0")

    @classmethod
    def fit(cls, features: np.ndarray, names: Sequence[str] = (), clip: float = 10.0,
            squash: Literal["clip", "asinh"] = "clip") -> "FeatureScaler":
        f = np.asarray(features, dtype=float).reshape(-1, np.shape(features)[-1])
        q25, med, q75 = np.quantile(f, [0.25, 0.5, 0.75], axis=0)
        scale = (q75 - q25) / 1.349
        fallback = f.std(axis=0)
        scale = np.where(scale > 1e-12, scale, np.where(fallback > 1e-12, fallback, 1.0))
        return cls(center=med, scale=scale, clip=float(clip), names=tuple(names), squash=squash)

    def __call__(self, features: np.ndarray) -> np.ndarray:
        f = np.asarray(features, dtype=float)
        if f.shape[-1] != self.center.shape[0]:
            raise ValueError(f"features have {f.shape[-1]} columns, the scaler was fitted on {self.center.shape[0]}")
        u = (f - self.center) / self.scale
        return np.arcsinh(u) if self.squash == "asinh" else np.clip(u, -self.clip, self.clip)

    def network_input(self, features: np.ndarray) -> np.ndarray:
        """What a network sees, in training and in acting alike: the scaled features as float32,
        finite and within ``+-OBS_LIMIT`` (a diverging filter's state, ``1e300``, ``inf`` or
        ``nan``, would otherwise reach the network as such: ``nan`` reads as 0)."""
        s = np.nan_to_num(self(features), nan=0.0, posinf=OBS_LIMIT, neginf=-OBS_LIMIT)
        return np.clip(s, -OBS_LIMIT, OBS_LIMIT).astype(np.float32)

    def to_dict(self) -> dict:
        return {"center": self.center.tolist(), "scale": self.scale.tolist(), "clip": self.clip,
                "names": list(self.names), "squash": self.squash}

    @classmethod
    def from_dict(cls, d: dict) -> "FeatureScaler":
        return cls(np.asarray(d["center"], float), np.asarray(d["scale"], float), float(d["clip"]),
                   tuple(d.get("names", ())), d.get("squash", "clip"))


def visited_states(env, features: "str | FeatureSet | None" = None, runs: int = 64, seed: int = 0,
                   visit: Literal["default", "mix"] = "mix") -> np.ndarray:
    """The raw information states ``(runs * T, d)`` of one seeded episode of ``runs`` runs.

    Trajectories from ``default_rng([seed, 3])``, stochastic-rule stream ``10**9``:

    * ``visit="default"``: every run keeps the default parameter;
    * ``visit="mix"``: run ``i`` keeps grid value ``i mod |grid|`` for its
      first half and the odd runs switch to uniformly random values per step
      afterwards (``default_rng([seed, 4])``), so the states are those that
      every constant, and a policy that switches, visit.

    Rows of a diverged run may be non-finite. These are the states
    :func:`fit_scaler` fits on (the course uses them to probe a policy).
    """
    fs = FeatureSet.parse(features)
    d = env.reset(n_runs=runs, rng=np.random.default_rng([seed, 3]), stream=10**9)
    G = len(env.grid)
    const = np.arange(runs) % G
    rng = np.random.default_rng([seed, 4])
    feats = []
    while d is not None:
        feats.append(observe(d, fs))
        if visit == "default":
            a = np.full(d.n_runs, d.default_index)
        elif visit == "mix":
            a = const.copy()
            if d.t >= env.n_steps // 2:
                odd = np.arange(runs) % 2 == 1
                a[odd] = rng.integers(0, G, size=int(odd.sum()))
        else:
            raise ValueError(f"visit must be 'default' or 'mix', got {visit!r}")
        d, _, _, _ = env.step(a)
    return np.concatenate(feats)


def fit_scaler(env, features: "str | FeatureSet | None" = None, runs: int = 64, seed: int = 0,
               visit: Literal["default", "mix"] = "mix", squash: Literal["clip", "asinh"] = "asinh") -> FeatureScaler:
    """Fit a :class:`FeatureScaler` on information states the environment visits.

    The states are those of :func:`visited_states` (one seeded episode of
    ``runs`` runs): ``visit="default"`` keeps the default parameter (how the
    first policies were scaled; reproduces their scalers exactly), ``"mix"``
    visits every grid value and a switching policy. ``features`` is the
    :class:`FeatureSet` (default: the paper's). Non-finite rows (a diverged
    run) are left out of the fit.
    """
    fs = FeatureSet.parse(features)
    f = visited_states(env, fs, runs, seed, visit)
    names = getattr(env, "feature_names", None)  # an environment with features of its own names them
    if names is None:
        model = getattr(env, "model", None)
        names = fs.names(model, env.grid) if model is not None else ()
    return FeatureScaler.fit(f[np.isfinite(f).all(axis=1)], names=names, squash=squash)


def observe(decision, features: "str | FeatureSet | None" = None) -> np.ndarray:
    """The raw information state of ``decision`` for a feature set, ``(M, d)``
    (the paper's is ``decision.features``; environments without feature sets,
    such as the toy MDPs, only have that one)."""
    fs = FeatureSet.parse(features)
    if fs == PAPER or not hasattr(decision, "observe"):
        if fs != PAPER:
            raise ValueError(f"this environment only has the paper's features, not {fs.name!r}")
        return decision.features
    return decision.observe(fs)
