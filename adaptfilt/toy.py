r"""Tiny MDPs with the :class:`~adaptfilt.mdp.FilterEnv` interface, whose optimal
policies are known: they test (and teach) the actor-critic without a filter.

* :class:`BanditEnv` -- state ``s ~ N(0, 1)`` (plus a noise feature); the cost
  of action ``a`` is ``COSTS_POS[a] = (1, 0, 2)[a]`` when ``s > 0`` and
  ``COSTS_NEG[a] = (0, 1, 2)[a]`` otherwise, plus small noise: the best action
  is 1 for ``s > 0`` and 0 otherwise, action 2 is always the worst. Actions
  do not change the state: every gamma has the same optimum.
* :class:`TrapEnv` -- two states, *good* and *bad*. In *good*, action 0 costs 0
  now but moves to *bad*, where every later step costs 1 whatever is done;
  action 1 costs ``c1 = 0.25`` and stays *good*. Myopically (gamma = 0) action
  0 is better; with gamma = 0.5, ``Q(good, 0) = 0 + 0.5 * 1/(1 - 0.5) = 1``
  against ``Q(good, 1) = 0.25 / (1 - 0.5) = 0.5``: action 1 is better.

Both are batched over ``n_runs`` like the filter environment and meet the same interface,
:class:`~adaptfilt.paramenv.ParamEnv` (the parameter is the action itself):
``reset(n_runs, rng, traj=None, stream=None) -> ToyDecision``,
``step(actions) -> (decision | None, cost (M,), done, info)``.

>>> import numpy as np
>>> env = TrapEnv(n_steps=3)
>>> d = env.reset(n_runs=2, rng=np.random.default_rng(0))
>>> d, c, done, _ = env.step(np.array([0, 1])); c.tolist()
[0.0, 0.25]
>>> d, c, done, _ = env.step(np.array([1, 1])); c.tolist()
[1.0, 0.25]
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from adaptfilt.paramenv import grid_actions

__all__ = ["ToyDecision", "ToyCost", "BanditEnv", "TrapEnv"]


@dataclass
class ToyDecision:
    t: int
    features: np.ndarray
    grid: np.ndarray
    default_index: int = 0
    _env: "_ToyEnv | None" = field(default=None, repr=False)
    #: what a look-ahead policy computed to decide (the toys charge nothing: :mod:`adaptfilt.lookahead`)
    extra_spent: float = 0.0

    @property
    def n_runs(self) -> int:
        return self.features.shape[0]

    def candidates(self) -> dict:
        """One-step cost of every action, ``{"cost": (G, M)}`` (TrapEnv only): what greedy and a
        policy anchored on greedy (:mod:`adaptfilt.anchor`) read."""
        make = getattr(self._env, "_candidate_costs", None)
        if make is None:
            raise TypeError(f"{type(self._env).__name__} has no candidate costs")
        return {"cost": make(self)}

    def lookahead_model(self):
        """What :mod:`adaptfilt.lookahead` simulates from this decision (TrapEnv only)."""
        make = getattr(self._env, "_lookahead_model", None)
        if make is None:
            raise TypeError(f"{type(self._env).__name__} has no look-ahead model")
        return make(self)


@dataclass(frozen=True)
class ToyCost:
    """The toys' cost, by name: the environment computes it (a :class:`~adaptfilt.costs.StepCost` that
    charges nothing for compute)."""

    name: str
    compute_weight: float = 0.0
    needs_truth = False  # the environment computes it (not a field)

    def __call__(self, update, theta, nz) -> np.ndarray:
        raise TypeError(f"the {self.name} cost is the environment's own: read it from step()")


class _ToyEnv:
    name = "toy"
    param_name = "action"
    compute_unit = "step"
    n_actions = 3
    feature_names: tuple[str, ...] = ()

    def __init__(self, n_steps: int = 10):
        self.n_steps = int(n_steps)
        self.grid = np.arange(self.n_actions, dtype=float)
        self.default_index = 0
        self.cost = ToyCost(self.name)
        self.model = None
        self._rng = None
        self._M = None
        self._done = True

    @property
    def default(self) -> float:
        return float(self.grid[self.default_index])

    def spent(self, theta) -> np.ndarray:
        """One step per run, whatever the action."""
        return np.ones(np.shape(theta))

    def describe(self, features=None) -> dict:
        """What a policy file records and must match (no filter: the toy's name stands for the model)."""
        return {"model": self.name, "filter": None, "param_name": self.param_name, "grid": self.grid.tolist(),
                "feature_names": list(self.feature_names), "cost": self.cost.name}

    def _decision(self) -> ToyDecision:
        return ToyDecision(self._t, self._features(), self.grid, self.default_index, self)

    def reset(self, n_runs=None, rng=None, traj=None, stream=None) -> ToyDecision:
        if n_runs is None or int(n_runs) < 1:
            raise ValueError(f"reset needs n_runs >= 1 (a toy simulates its runs), got {n_runs!r}")
        self._rng = np.random.default_rng(rng)
        self._M = int(n_runs)
        self._t = 0
        self._done = False
        self._reset_state()
        return self._decision()

    def check_actions(self, actions) -> np.ndarray:
        """Actions as indices ``(M,)``; ValueError naming what is wrong."""
        if self._M is None:
            raise RuntimeError("call reset() before step()")
        return grid_actions(actions, self._M, self.n_actions)

    def step(self, actions, predict_param=None):
        if self._done:
            raise RuntimeError("call reset() before step() (the episode has ended)" if self._M else
                               "call reset() before step()")
        if predict_param is not None:
            raise ValueError("a toy has no separate predict parameter")
        a = self.check_actions(actions)
        cost = self._transition(a)
        info = {"t": self._t, "theta": self.grid[a]}
        self._t += 1
        self._done = self._t >= self.n_steps
        return (None if self._done else self._decision()), cost, self._done, info


class BanditEnv(_ToyEnv):
    """Contextual bandit with a known best action (see the module docstring)."""

    name = "toy-bandit"
    feature_names = ("s", "noise")
    COSTS_POS = (1.0, 0.0, 2.0)
    COSTS_NEG = (0.0, 1.0, 2.0)

    def _reset_state(self):
        self._s = self._rng.standard_normal(self._M)

    def _features(self):
        return np.stack([self._s, self._rng.standard_normal(self._M)], axis=1)

    def best_action(self, s: np.ndarray) -> np.ndarray:
        return np.where(np.asarray(s) > 0, int(np.argmin(self.COSTS_POS)), int(np.argmin(self.COSTS_NEG)))

    def _transition(self, a):
        cost = (np.where(self._s > 0, np.asarray(self.COSTS_POS)[a], np.asarray(self.COSTS_NEG)[a])
                + 0.1 * self._rng.standard_normal(self._M))
        self._s = self._rng.standard_normal(self._M)
        return cost


class TrapEnv(_ToyEnv):
    """Greedy is worse in the long run (see the module docstring)."""

    name = "toy-trap"
    n_actions = 2
    feature_names = ("bad", "noise")

    def __init__(self, n_steps: int = 10, c1: float = 0.25):
        super().__init__(n_steps)
        self.c1 = float(c1)

    def _reset_state(self):
        self._bad = np.zeros(self._M, dtype=bool)

    def _features(self):
        return np.stack([self._bad.astype(float), self._rng.standard_normal(self._M)], axis=1)

    def _transition(self, a):
        cost = np.where(self._bad, 1.0, np.where(a == 0, 0.0, self.c1))
        self._bad = self._bad | (a == 0)
        return cost

    def _candidate_costs(self, d: ToyDecision) -> np.ndarray:
        """``(2, M)``: action 0 is free in *good* (greedy's choice), every action costs 1 in *bad*."""
        bad = d.features[:, 0] > 0.5
        return np.stack([np.where(bad, 1.0, 0.0), np.where(bad, 1.0, self.c1)])

    def _lookahead_model(self, d: ToyDecision) -> "_TrapLookahead":
        return _TrapLookahead(self, d)


class _TrapLookahead:
    """The trap's exact model for :mod:`adaptfilt.lookahead` (the methods of its ``FilterLookahead``):
    a branch is a bool *bad* per run; nothing is random, so every sample is the same."""

    def __init__(self, env: TrapEnv, d: ToyDecision):
        self.c1, self.grid, self.n_runs = env.c1, env.grid, d.n_runs
        self.steps_left = env.n_steps - 1 - d.t
        self._bad = d.features[:, 0] > 0.5

    def _branch(self, bad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cost ``(2, B)`` of each action and the successors (``2 B``, action-major): 0 falls into *bad*."""
        cost = np.stack([np.where(bad, 1.0, 0.0), np.where(bad, 1.0, self.c1)])
        return cost, np.concatenate([np.ones_like(bad), bad])

    def root(self):
        return self._branch(self._bad)

    def noise(self, rng, H: int, S: int) -> list[dict]:
        return [{"v": np.zeros((0, S, self.n_runs))} for _ in range(H)]

    def take(self, Y: np.ndarray, idx: np.ndarray) -> np.ndarray:
        return Y[idx]

    def expand(self, Y: np.ndarray, h: int, noise: dict, rng, tile: int = 1):
        S, m = noise["v"].shape[1:]
        if h == 1:  # one copy per sample, as the filter's look-ahead lays them out
            Y = np.broadcast_to(Y.reshape(tile, 1, m), (tile, S, m)).ravel()
        return self._branch(Y)

    def spent(self, H: int, S: int) -> float:
        return 0.0
