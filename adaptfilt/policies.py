r"""Policies: information state (and measurement) -> index into the parameter grid.

Every policy has a ``name`` (used in results: ``default``, ``fixed-kappa=2``,
``ml``, ``greedy``, ...) and ``act(decision) -> (M,)`` grid indices, where
``decision`` is an :class:`adaptfilt.mdp.Decision`. A policy that carries a
``grid`` can also drive ``filter.run(z, policy=...)``.

Baselines (Section VI-D of the paper, and ours):

* :class:`FixedPolicy` / :func:`default_policy`: one value for all steps;
* :class:`MaxLikelihoodPolicy`: ``argmax_theta N(z; z_pred(theta), Pzz(theta))``
  per step (Dunik, Simandl and Straka);
* :class:`GreedyPolicy`: ``argmin_theta L(s, z, theta)``, the exact one-step
  (myopic) optimum of the cost, found by trying every grid value;
* look-ahead references in :mod:`adaptfilt.lookahead`, not learned:
  :class:`~adaptfilt.lookahead.RolloutPolicy` (rollout with greedy as the base
  policy: each candidate followed by ``H`` greedy steps on ``S`` sampled
  continuations, ``argmin`` of the discounted cost; ``H = 0`` is greedy) and
  :class:`~adaptfilt.lookahead.TwoStepPolicy` (the exhaustive two-step
  look-ahead, its cross-check); what they compute is charged like greedy's
  candidates (``Decision.extra_spent``);
* learned policies (the actor network) live in :mod:`adaptfilt.learned`.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["grid_matches", "Policy", "FixedPolicy", "default_policy", "MaxLikelihoodPolicy", "GreedyPolicy", "RandomPolicy",
           "grid_indices"]


@runtime_checkable
class Policy(Protocol):
    """What the environment and ``evaluate`` need from a policy. A policy may also declare
    ``cost_blind = True``: its choices cannot depend on the environment's cost, so
    :func:`~adaptfilt.evaluation.evaluate_costs` may charge one rollout of it several costs (undeclared:
    it may choose by the cost, and is evaluated per cost)."""

    name: str

    def act(self, decision) -> np.ndarray:  # pragma: no cover - protocol
        """Grid indices ``(M,)`` for the runs of ``decision``."""
        ...


class FixedPolicy:
    """Always the grid value ``value`` (named ``fixed-<param>=<value>``).

    ``both_steps=True`` uses the value in the predict step too (named
    ``fixed-both-<param>=<value>``): a filter run with one constant parameter,
    the natural reading of a "fixed" baseline when the dynamics are nonlinear
    (UNGM). By default only the update step changes, as for every adaptive
    policy (the paper adapts the update only; the predict uses the default).
    ``kind`` (what :meth:`~adaptfilt.experiment_registry.Experiment.baselines` selects by): ``"fixed"``
    (update only), ``"fixed-both"``, or the given one (``"default"``, :func:`default_policy`).

    >>> FixedPolicy(2.0, param_name="kappa").name, FixedPolicy(2.0, "kappa", both_steps=True).kind
    ('fixed-kappa=2', 'fixed-both')
    """

    cost_blind = True

    def __init__(self, value: float, param_name: str = "param", name: str | None = None, grid=None,
                 both_steps: bool = False, kind: str | None = None):
        self.value = float(value)
        self.name = name or f"fixed-{'both-' if both_steps else ''}{param_name}={self.value:g}"
        self.kind = kind or ("fixed-both" if both_steps else "fixed")
        self.grid = None if grid is None else np.asarray(grid, dtype=float)
        #: read by :func:`adaptfilt.mdp.rollout`: the predict step's parameter (None: the filter's default)
        self.predict_param = self.value if both_steps else None

    def act(self, decision) -> np.ndarray:
        hit = np.flatnonzero(np.isclose(decision.grid, self.value))
        if hit.size == 0:
            raise ValueError(f"policy {self.name!r}: value {self.value:g} is not on the grid {decision.grid.tolist()}")
        return np.full(decision.n_runs, hit[0], dtype=np.int64)


def default_policy(default_value: float, grid=None) -> FixedPolicy:
    """The practitioner's default (``kappa = max(0, 3 - n)``, SIF ``n_iter = 10``), named ``default``."""
    return FixedPolicy(default_value, name="default", grid=grid, kind="default")


class MaxLikelihoodPolicy:
    """``argmax_theta log N(z; z_pred(theta), Pzz(theta))`` at every step."""

    name = kind = "ml"
    cost_blind = True

    def __init__(self, grid=None):
        self.grid = None if grid is None else np.asarray(grid, dtype=float)

    def act(self, decision) -> np.ndarray:
        return np.argmax(decision.candidates()["loglik"], axis=0)


class GreedyPolicy:
    """``argmin_theta L(s, z, theta)``: the exact myopic optimum over the grid.

    It is what a perfectly trained ``gamma = 0`` policy would do, so it is the
    honest bar for "non-myopic helps".
    """

    name = kind = "greedy"
    cost_blind = False

    def __init__(self, grid=None):
        self.grid = None if grid is None else np.asarray(grid, dtype=float)

    def act(self, decision) -> np.ndarray:
        cost = decision.candidates()["cost"]
        if cost is None:
            raise ValueError("the greedy policy needs an environment with a cost")
        return np.argmin(cost, axis=0)


class RandomPolicy:
    """Uniformly random grid indices (a sanity baseline), seeded."""

    name = "random"
    cost_blind = True

    def __init__(self, rng: np.random.Generator | int | None = 0, grid=None):
        self.rng = np.random.default_rng(rng)
        self.grid = None if grid is None else np.asarray(grid, dtype=float)

    def act(self, decision) -> np.ndarray:
        return self.rng.integers(0, decision.grid.size, size=decision.n_runs)


def grid_indices(own: np.ndarray, env_grid, name: str = "policy") -> np.ndarray:
    """Where each of a policy's grid values sits in the environment's grid. A policy trained on a
    subset of the grid (``train_policy(..., actions=...)``: e.g. only SIF iteration counts that do not
    diverge) acts in the full environment; any other grid is a ValueError naming both."""
    env_grid = np.asarray(env_grid, dtype=float)
    if own.shape == env_grid.shape and np.allclose(own, env_grid):
        return np.arange(own.size)
    hit = grid_matches(own, env_grid)
    if not hit.any(axis=1).all():
        raise ValueError(f"policy {name!r} was trained on the grid {own.tolist()}, which is not a subset of the "
                         f"environment's grid {env_grid.tolist()}")
    return hit.argmax(axis=1)


def grid_matches(own, env_grid) -> np.ndarray:
    """``(len(own), len(env_grid))``: which environment value each of a policy's grid values is."""
    return np.isclose(np.asarray(own, dtype=float)[:, None], np.asarray(env_grid, dtype=float)[None, :])
