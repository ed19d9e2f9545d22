r"""The parameter MDP as a declared interface, and its conformance check.

Every environment in which a policy chooses a filter's parameter meets :class:`ParamEnv`: the
Gaussian-assumed filters' rule parameter (:class:`~adaptfilt.mdp.FilterEnv`: UKF kappa, SIF
iterations), the particle count (:class:`~adaptfilt.particle_env.ParticleCountEnv`) and the toy MDPs
(:mod:`adaptfilt.toy`). :func:`~adaptfilt.mdp.rollout`, :func:`~adaptfilt.evaluation.evaluate`, the
trainers and the policy files ask nothing else of an environment, so a new kind of parameter is a
new class that meets it (and passes :func:`check_env`), not a parallel copy of those.

========================  =====================================================================
member                    meaning
========================  =====================================================================
``grid``                  the parameter values an action indexes, a 1-D float array
``default_index``         the index of the default value in ``grid`` (``default``: the value)
``n_steps``               the horizon (a time limit: the episode ends after it)
``cost``                  a :class:`~adaptfilt.costs.StepCost` or None (no cost: filtering only)
``param_name``            what the parameter is (``"kappa"``, ``"n_iter"``, ``"n_particles"``)
``compute_unit``          what :meth:`spent` counts (``"update"``, ``"iteration"``, ``"particles"``)
``spent(theta)``          compute per run of one step at parameter values ``theta`` ``(M,)``
``reset(n_runs, rng,      start ``n_runs`` episodes (or replay ``traj``), return the first decision
traj, stream)``
``step(actions,           ``(decision or None, cost (M,) or None, done, info)``; ``info`` has
predict_param)``          ``t`` and ``theta`` (``grid[actions]``)
``check_actions(a)``      ``a`` as grid indices ``(M,)``; ValueError naming what is wrong
``describe()``            what a policy file must match: ``model``, ``filter``, ``param_name``,
                          ``grid``, ``feature_names``, ``cost``
========================  =====================================================================

A decision (:class:`ParamDecision`) carries ``t``, ``grid``, ``default_index``, ``n_runs``,
``features (M, d)`` and ``extra_spent`` (what deciding computed beyond the chosen update).

An environment that filters (``model`` not None: what :func:`~adaptfilt.mdp.rollout` and
:func:`~adaptfilt.evaluation.evaluate` run) also has ``nx``, ``nz``, the ``truth`` it simulates from, and
its step's ``info`` holds :data:`FILTER_INFO`: the update's ``x_filt (M, nx)``, ``P_filt (M, nx, nx)``,
``nis``, ``loglik``, ``extra_spent``, ``repaired (M,)`` and ``update`` (what the cost reads). A toy
(``model`` None) is for learners only.

>>> from adaptfilt.toy import TrapEnv
>>> check_env(TrapEnv(n_steps=3))
>>> isinstance(TrapEnv(), ParamEnv)
True
"""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["ParamEnv", "ParamDecision", "EnvCheckError", "check_env", "missing_members", "grid_actions",
           "DESCRIBE_KEYS", "FILTER_INFO"]

#: What :meth:`ParamEnv.describe` returns (and a policy file records and is checked against).
DESCRIBE_KEYS = ("model", "filter", "param_name", "grid", "feature_names", "cost")
#: What the step of an environment that filters reports in ``info`` (read by :func:`~adaptfilt.mdp.rollout`).
FILTER_INFO = ("x_filt", "P_filt", "nis", "loglik", "extra_spent", "repaired", "update")


@runtime_checkable
class ParamDecision(Protocol):
    """What a policy sees at step ``t``, batched over ``M`` runs."""

    t: int
    grid: np.ndarray
    default_index: int
    extra_spent: float

    @property
    def n_runs(self) -> int: ...

    @property
    def features(self) -> np.ndarray: ...


@runtime_checkable
class ParamEnv(Protocol):
    """A filter's parameter per step as a batched Markov decision problem (see the module docstring)."""

    grid: np.ndarray
    default_index: int
    n_steps: int
    cost: Any
    model: Any

    @property
    def default(self) -> float: ...

    @property
    def param_name(self) -> str: ...

    @property
    def compute_unit(self) -> str: ...

    def spent(self, theta: np.ndarray) -> np.ndarray: ...

    def reset(self, n_runs: int | None = None, rng: Any = None, traj: Any = None,
              stream: int | None = None) -> Any: ...

    def step(self, actions: Any, predict_param: float | None = None) -> tuple: ...

    def check_actions(self, actions: Any) -> np.ndarray: ...

    def describe(self, features: Any = None) -> dict: ...


def grid_actions(actions, n_runs: int, grid_size: int) -> np.ndarray:
    """``actions`` as grid indices, an int array ``(n_runs,)``; ValueError naming what is wrong (shape,
    a non-integer, an index off the grid). Every environment's ``step`` checks its actions with it (the contract's own
    action check, :meth:`ParamEnv.check_actions`)."""
    a = np.asarray(actions)
    if a.shape != (n_runs,):
        raise ValueError(f"actions must be one grid index per run, shape ({n_runs},); got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.integer):
        if not (np.isfinite(a).all() and (a == np.round(a)).all()):
            raise ValueError("actions must be integer grid indices")
        a = a.astype(np.int64)
    if (a < 0).any() or (a >= grid_size).any():
        bad = a[(a < 0) | (a >= grid_size)]
        raise ValueError(f"action index {int(bad[0])} out of range: the grid has {grid_size} values (0..{grid_size - 1})")
    return a


class EnvCheckError(ValueError):
    """An environment breaks the :class:`ParamEnv` contract; the message names the member and what is wrong."""


def missing_members(env: Any) -> list[str]:
    """The members of :class:`ParamEnv` that ``env`` lacks, by name (empty when it has them all)."""
    return _missing(env, ParamEnv)


def _missing(obj: Any, proto: type) -> list[str]:
    # the members a runtime-checkable protocol declares (typing keeps them in __protocol_attrs__ on 3.12+;
    # on older versions they are the annotations and the functions of the class body)
    names = getattr(proto, "__protocol_attrs__", None)
    if names is None:
        names = set(getattr(proto, "__annotations__", {})) | {
            k for k, v in vars(proto).items() if not k.startswith("_") and (callable(v) or isinstance(v, property))}
    return sorted(n for n in names if not hasattr(obj, n))


def check_env(env: Any, n_runs: int = 3, seed: int = 0) -> None:
    """Check that ``env`` meets the :class:`ParamEnv` contract; :class:`EnvCheckError` naming the first
    thing that does not (the pattern of Stable-Baselines3's ``check_env`` and scikit-learn's
    ``check_estimator``).

    It runs two episodes of ``n_runs`` runs from ``rng=seed``, one at the default and one on the
    grid's last value, and checks: the declared members exist; ``grid`` is a non-empty, finite, 1-D
    float array and ``default_index`` on it; ``n_steps`` a positive integer; ``cost`` None or a
    :class:`~adaptfilt.costs.StepCost`; ``describe()`` names the same grid, parameter and cost;
    ``check_actions`` rejects a wrong shape, a non-integer and an index off the grid with a
    ValueError, and ``step`` does too; every decision has ``t``, the grid, ``n_runs`` and finite
    ``features (n_runs, d)`` of one width; ``step`` returns ``(decision, cost (n_runs,), done, info)``
    with ``info["theta"] == grid[actions]``, ``done`` exactly at the horizon, a finite cost and
    ``spent(theta)`` ``>= 0``; a step after the last is a RuntimeError; the same ``rng`` replays the
    same costs bit for bit (what paired evaluations rest on). The environment is left after an episode.
    """
    from adaptfilt.costs import StepCost

    def fail(what: str) -> EnvCheckError:
        return EnvCheckError(f"{type(env).__name__}: {what}")

    missing = missing_members(env)
    if missing:
        raise fail(f"missing member(s) of the ParamEnv interface: {', '.join(missing)}")
    grid = env.grid
    if not isinstance(grid, np.ndarray) or grid.ndim != 1 or grid.size < 1 or grid.dtype.kind != "f" \
            or not np.isfinite(grid).all():
        raise fail(f"grid must be a non-empty 1-D finite float array, got {grid!r}")
    di = env.default_index
    if isinstance(di, (bool, np.bool_)) or not isinstance(di, (int, np.integer)) or not 0 <= di < grid.size:
        raise fail(f"default_index must be an integer index into the grid of {grid.size} values, got {di!r}")
    if not np.isclose(float(env.default), grid[di]):
        raise fail(f"default = {env.default!r} is not grid[default_index] = {float(grid[di])!r}")
    T = env.n_steps
    if isinstance(T, (bool, np.bool_)) or not isinstance(T, (int, np.integer)) or T < 1:
        raise fail(f"n_steps must be an integer >= 1, got {T!r}")
    for attr in ("param_name", "compute_unit"):
        if not isinstance(getattr(env, attr), str) or not getattr(env, attr):
            raise fail(f"{attr} must be a non-empty string, got {getattr(env, attr)!r}")
    if env.cost is not None and not isinstance(env.cost, StepCost):
        raise fail(f"cost must be None or a StepCost (name, compute_weight, needs_truth, __call__(update, theta, nz)), "
                   f"got {type(env.cost).__name__}")
    desc = env.describe()
    if not isinstance(desc, dict) or set(desc) != set(DESCRIBE_KEYS):
        raise fail(f"describe() must return a dict with the keys {', '.join(DESCRIBE_KEYS)}, got "
                   f"{sorted(desc) if isinstance(desc, dict) else type(desc).__name__}")
    if env.model is not None:
        for attr in ("nx", "nz"):
            v = getattr(env, attr, None)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 1:
                raise fail(f"an environment that filters (model {env.model!r:.40}) needs {attr}, an integer >= 1; got {v!r}")
        if not callable(getattr(getattr(env, "truth", None), "simulate", None)):
            raise fail("an environment that filters needs truth, the model its reset simulates (truth.simulate)")
    want = {"grid": grid.tolist(), "param_name": env.param_name, "cost": None if env.cost is None else env.cost.name}
    for k, v in want.items():
        if desc[k] != v:
            raise fail(f"describe()[{k!r}] = {desc[k]!r}, but the environment's {k} is {v!r}")

    first = _episode(env, n_runs, seed, lambda d: np.full(n_runs, di), fail, check_actions=True)
    again = _episode(env, n_runs, seed, lambda d: np.full(n_runs, di), fail)
    if not all(np.array_equal(a, b, equal_nan=True) for a, b in zip(first, again)):
        raise fail(f"reset(rng={seed}) twice and the same actions gave different costs: an episode must be "
                   "a function of its seed (evaluations compare policies on the same runs)")
    _episode(env, n_runs, seed + 1, lambda d: np.full(n_runs, grid.size - 1), fail)


def _episode(env: Any, M: int, seed: int, act, fail, check_actions: bool = False) -> list:
    """One checked episode; the cost of every step."""
    d = env.reset(n_runs=M, rng=np.random.default_rng(seed), stream=0)
    costs, width = [], None
    for t in range(env.n_steps):
        if d is None:
            raise fail(f"step {t - 1} returned no decision before the horizon n_steps = {env.n_steps}")
        width = _check_decision(env, d, t, M, width, fail)
        if check_actions and t == 0:
            _check_bad_actions(env, M, fail)
        a = np.asarray(act(d))
        out = env.step(a)
        if not isinstance(out, tuple) or len(out) != 4:
            raise fail(f"step must return (decision, cost, done, info), got {type(out).__name__}")
        d, cost, done, info = out
        if not isinstance(info, dict) or "theta" not in info or "t" not in info:
            raise fail(f"step's info must be a dict with 't' and 'theta', got {info!r:.80}")
        if info["t"] != t:
            raise fail(f"step's info['t'] = {info['t']!r} at step {t}")
        if env.model is not None:
            _check_filter_info(env, info, M, fail)
        theta = np.asarray(info["theta"])
        if theta.shape != (M,) or not np.array_equal(theta, env.grid[a]):
            raise fail(f"step's info['theta'] must be grid[actions] {env.grid[a].tolist()}, got {theta.tolist()}")
        spent = np.asarray(env.spent(theta), dtype=float)
        if spent.shape not in ((), (M,)) or not (spent >= 0).all():
            raise fail(f"spent(theta) must be >= 0 per run, got {spent!r}")
        if env.cost is None:
            if cost is not None:
                raise fail("an environment without a cost must return cost None")
        else:
            c = np.asarray(cost)
            if c.shape != (M,) or c.dtype.kind != "f":
                raise fail(f"step's cost must be a float array of shape ({M},), got shape {c.shape}, dtype {c.dtype}")
            if not np.isfinite(c).all():
                raise fail(f"step {t} at the parameter(s) {sorted(set(theta.tolist()))} gave a non-finite cost")
            costs.append(c.copy())
        last = t == env.n_steps - 1
        if bool(done) != last:
            raise fail(f"step {t} returned done = {done!r}; an episode of n_steps = {env.n_steps} ends at step "
                       f"{env.n_steps - 1}")
        if last and d is not None:
            raise fail("the last step must return decision None")
    try:
        env.step(np.full(M, env.default_index))
    except RuntimeError:
        pass
    else:
        raise fail("a step after the episode's last must be a RuntimeError (call reset())")
    return costs


def _check_filter_info(env: Any, info: dict, M: int, fail) -> None:
    lacks = [k for k in FILTER_INFO if k not in info]
    if lacks:
        raise fail(f"step's info lacks {', '.join(lacks)} (an environment that filters reports its update)")
    shapes = {"x_filt": (M, env.nx), "P_filt": (M, env.nx, env.nx), "nis": (M,), "loglik": (M,), "repaired": (M,)}
    for k, shape in shapes.items():
        if np.shape(info[k]) != shape:
            raise fail(f"step's info[{k!r}] must have shape {shape}, got {np.shape(info[k])}")


def _check_decision(env: Any, d: Any, t: int, M: int, width: int | None, fail) -> int:
    missing = _missing(d, ParamDecision)
    if missing:
        raise fail(f"its decision ({type(d).__name__}) lacks {', '.join(missing)}")
    if d.t != t:
        raise fail(f"the decision of step {t} says t = {d.t!r}")
    if d.n_runs != M:
        raise fail(f"the decision's n_runs = {d.n_runs!r}, but reset asked for {M} runs")
    if not np.array_equal(np.asarray(d.grid), env.grid) or d.default_index != env.default_index:
        raise fail("the decision's grid and default_index must be the environment's")
    f = np.asarray(d.features)
    if f.ndim != 2 or f.shape[0] != M or not np.isfinite(f).all():
        raise fail(f"the decision's features must be finite, shape ({M}, d); got shape {f.shape} at step {t}")
    if width is not None and f.shape[1] != width:
        raise fail(f"the features' width changed from {width} to {f.shape[1]} at step {t}")
    return f.shape[1]


def _check_bad_actions(env: Any, M: int, fail) -> None:
    G = env.grid.size
    ok = np.asarray(env.check_actions(np.full(M, env.default_index)))
    if ok.shape != (M,) or ok.dtype.kind not in "iu":
        raise fail(f"check_actions must return integer indices of shape ({M},), got {ok.dtype} {ok.shape}")
    bad = {"a wrong shape": np.zeros(M + 1, dtype=int), "an index off the grid": np.full(M, G),
           "a negative index": np.full(M, -1), "a non-integer": np.full(M, 0.5)}
    for what, a in bad.items():
        for fn in ("check_actions", "step"):
            try:
                getattr(env, fn)(a)
            except ValueError:
                continue
            raise fail(f"{fn} accepted {what} ({a.tolist()}): it must raise a ValueError naming it")
