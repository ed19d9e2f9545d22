r"""Look-ahead reference policies: rollout over a base policy (greedy, ML or the better of both), and the
two-step look-ahead.

How much can looking ahead buy? :class:`~adaptfilt.policies.GreedyPolicy` is
the exact one-step optimum; these policies are *not learned* and look
further, by simulating the filter beyond the current step. They answer the
question without a learner in the way: if they do not beat greedy, there is
little to gain on the model; if they do, a learner should find it too.

**Rollout** (Bertsekas' rollout algorithm, base policy greedy). At step
``t`` with predicted moments ``s_t`` and measurement ``z_t``, for every
candidate ``theta`` of the grid ``Theta`` (``G`` values):

.. math::

    Q_H(\theta) = L_0(\theta) + \sum_{h=1}^{H} \gamma^h\, \frac1S \sum_{i=1}^{S} L_h^{(i)}(\theta),
    \qquad \theta_t = \arg\min_\theta Q_H(\theta),

where ``L_0(theta) = L(s_t, z_t, theta)`` is the cost of the update the
environment would make (the decision's candidate updates: the same random
numbers), and ``L_h^{(i)}`` the cost at step ``t + h`` of sample ``i`` of
a simulated continuation: predict to ``t + h``, draw a measurement
``z_{t+h}^{(i)}``, update with greedy's choice ``argmin_theta' L`` (every
candidate tried, as greedy does), and so on for ``H`` steps. The filter's
own predict and update run the continuation at the right ``t`` (so the
time-varying UNGM dynamics ``f(x, k)`` are those of step ``k``). With
``H = 0`` (or ``gamma = 0``) it is greedy, bit for bit. The continuation
stops at the episode's last step (``H_eff = min(H, n_steps - 1 - t)``):
costs beyond the horizon are not the MDP's, so the last step is always
greedy's.

**The base policy** (``base``) is what the continuation follows after the
decision's candidate:

* ``"greedy"`` (default): ``argmin_theta' L`` at every continuation step, as above;
* ``"ml"``: maximum likelihood, ``argmax_theta' log N(z; z_pred(theta'), Pzz(theta'))``
  (:class:`~adaptfilt.policies.MaxLikelihoodPolicy`; the same ``np.argmax``), read from the
  same candidate updates (their log-likelihoods: no extra compute). On the CTM, ML's run is
  cheaper than greedy's although greedy is the one-step optimum, so rollout over ML bounds what
  looking ahead buys from the better base;
* ``"best"``: the better of the two per decision and candidate, ``Q(theta) = L_0(theta) +
  min(F_greedy(theta), F_ml(theta))`` with ``F_b`` the sampled discounted continuation cost under
  base ``b`` (parallel rollout, Chang, Givan and Chong 2004: with exact expectations it is no
  worse than either base). Both continuations share the first continuation step (its candidate
  updates serve both bases' choices) and the random numbers (common random numbers), so
  ``F_greedy`` is, bit for bit, rollout over greedy's.

``H = 0`` means no look-ahead: the policy is its base (greedy: ``argmin L_0``, also
``Q_0``'s argmin; ML: ML's choice, bit for bit; ``"best"``: the better of greedy's and ML's choice
by their estimate ``L_0``, i.e. greedy). The episode's last step (``H_eff = 0`` with ``H > 0``)
and ``gamma = 0`` have only the current cost to minimise: every base then takes its argmin.

Cost improvement: rollout with exact expectations over the whole remaining
horizon costs no more than its base policy (Bertsekas). Here the horizon is
truncated, the expectation sampled and taken under the filter's belief, not
the truth's law, so the property is a thing to measure, not a theorem: on
200 UNGM runs of 30 steps, ``H = 1``, ``S = 10``, rollout's mean cost is
0.027 +- 0.023 below greedy's (``tests/test_lookahead.py``), but over UNGM's
full 500 steps (``adaptfilt beyond --studies look``, M = 2000) every
rollout tried (H = 1, 2, 4; S = 4, 16) is *worse* than greedy by 0.056 to
0.065, while on the CTM it is better (H = 1, S = 16: -1.70 [-3.68, -0.21]):
the filter's Gaussian predictive is a poor model of UNGM's bimodal future.

Measurements of the continuation (``measurements``):

* ``"filter"`` (default): from the filter's own predictive,
  ``z^{(i)} = \hat z(\theta_d) + L_{zz}(\theta_d) v^{(i)}``, ``v ~ N(0, I)``,
  the moments under the filter's default parameter ``theta_d`` (as the
  innovation feature): what a real filter can do, it does not know the truth;
* ``"model"``: from the model given a state drawn from the filter's
  posterior: ``x_t^{(i)} ~ N(x_{t|t}(\theta), P_{t|t}(\theta))``, then
  ``x_{k+1} = f(x_k, k) + w``, ``z_k = h(x_k, k) + v`` with the model's noise.

Each branch ``theta`` follows its own filter's belief (its posterior, its
predictive): the certainty-equivalent reading of the information state.

**Common random numbers.** All candidates see the same ``S`` continuations'
noise (``v``, ``w``, ``x_t``'s standard normals) and, for a stochastic rule
(SIF), the same draws of the continuation's updates and predicts, so that
``Q(theta) - Q(theta')`` is a paired comparison. The continuation's numbers
come from ``default_rng([seed, KEY, stage, t, h, chunk, stream])`` (the
decision's ``t`` and episode ``stream``): same seed, same choices. The
predict right after the decision uses the environment's own random numbers
for that step (``filt.rng(predict, t, stream)``), so that, when all runs fit
in one chunk (see Memory), the chosen branch's first predict is the one the
environment makes (this matters only for a stochastic rule on nonlinear
dynamics). The continuation runs the filter's model (``env.model``), not the
environment's truth: what a real filter knows.

**Exhaustive two-step look-ahead** (:class:`TwoStepPolicy`), a cross-check:

.. math::

    Q(\theta_0) = L_0(\theta_0) + \gamma\, \frac1S \sum_{i=1}^{S} \min_{\theta_1} L_1^{(i)}(\theta_0, \theta_1),

``G x S x G`` updates per run and step (13 x S x 13 on UNGM). It is
rollout with ``H = 1`` (whose last step is greedy's), written as a loop over
``theta_0`` instead of one batch: with the same seed the two agree.

**Compute per step** (per run, in the rule's unit, :meth:`~adaptfilt.rules.MomentRule.spent`:
UKF updates, SIF iterations), added to the decision's ``extra_spent`` so that
an evaluation reports and charges it like greedy's candidates:

.. math::

    c_\text{cand} + G\,p + G S (H_\text{eff} - 1)\, p + G S H_\text{eff}\, c_\text{cand}
    \quad (H_\text{eff} \ge 1;\ c_\text{cand} \text{ alone for } H_\text{eff} = 0,
    \text{ and for } \gamma = 0),

``c_cand = filt.candidates_spent(grid)`` (all ``G`` candidate updates: ``G``
UKF updates; ``max(grid)`` SIF iterations with shared draws), ``p`` one
predict (``spent(param)`` with nonlinear dynamics; 0 with linear dynamics,
the exact Kalman predict of the CTM). The first predict is made once per
branch, then copied to the ``S`` samples. UKF on UNGM (``G = 13``, ``p = 1``):
``13 + 13 + 13 S (H - 1) + 169 S H``; the two-step policy is ``H_eff = 1``.
Sampling the continuation's states and measurements evaluates the model's
functions only, no moment computation, and is not counted. With ``base="best"`` the
continuation steps after the first run once per base: ``c_cand + G p + G S c_cand +
2 G S (H_eff - 1) (p + c_cand)``.

Memory: the continuation of ``m`` runs holds ``G^2 S m`` candidate updates at
once; runs are taken ``max_batch // (G^2 S)`` at a time (which changes the
continuation's SIF draws, not its measurement noise).

Other environments provide their own look-ahead model (the methods
:class:`FilterLookahead` has: ``root``, ``noise``, ``expand``, ``take``,
``spent``, ``steps_left``) through ``decision.lookahead_model()``, e.g. the
toy :class:`~adaptfilt.toy.TrapEnv`, whose optimum is known.

Example
-------
>>> import numpy as np
>>> from adaptfilt.experiment_registry import get_experiment
>>> from adaptfilt.lookahead import RolloutPolicy
>>> from adaptfilt.mdp import rollout
>>> exp = get_experiment("ungm-ukf")
>>> env = exp.make_env(n_steps=5)
>>> pol = RolloutPolicy(exp.grid, horizon=2, samples=4, gamma=0.5, seed=0)
>>> pol.name
'rollout-H2-S4'
>>> run, cost = rollout(env, pol, n_runs=8, rng=np.random.default_rng(0))
>>> cost.shape
(8, 5)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from adaptfilt.linalg import chol, mv, sym
from adaptfilt.mdp import PREDICT, Decision

__all__ = ["RolloutPolicy", "TwoStepPolicy", "FilterLookahead", "lookahead_model", "BASES"]

#: The base policies of :class:`RolloutPolicy` (module docstring).
BASES = ("greedy", "ml", "best")

#: keys the look-ahead's random numbers apart from the filter's and the trajectories'
_KEY = 0x100C
_NOISE, _DRAWS = 0, 1


@dataclass
class _Branches:
    """Filtered moments of ``B`` simulated runs at one step, run-last, and (``"model"``) their sampled states."""

    m: np.ndarray  # (nx, B)
    P: np.ndarray  # (nx, nx, B)
    x: np.ndarray | None = None  # (nx, B)


def _copies(a: np.ndarray, K: int) -> np.ndarray:
    """``a (n, S, m)`` -> ``(n, K * S * m)``: the same numbers for each of ``K`` branches (branch-major)."""
    return np.broadcast_to(a[:, None], (a.shape[0], K) + a.shape[1:]).reshape(a.shape[0], -1)


class FilterLookahead:
    """What a look-ahead simulates at one decision of a :class:`~adaptfilt.mdp.FilterEnv`.

    ``root()`` gives the cost ``(G, M)`` of every candidate at the decision and
    the branches' filtered moments (``G * M`` runs, tile-major, as
    ``Decision.candidates``); ``expand(Y, h, noise, rng, tile)`` takes
    filtered branches at step ``t + h - 1`` (``tile`` copies that share
    draws) to step ``t + h``: predict, draw the measurement, run every
    candidate update; it returns their cost ``(G, B)`` and filtered moments
    (``G * B`` runs). ``noise(rng, H, S)``: the standard normals of ``S``
    continuations of ``H`` steps. ``spent(H, S)``: the compute per run (see
    the module docstring).
    """

    #: ``expand(..., loglik=True)`` gives the candidates' log-likelihoods (what an ML base ranks)
    has_loglik = True

    def __init__(self, decision: Decision, measurements: Literal["filter", "model"] = "filter"):
        env = decision.env
        if env.cost is None:
            raise ValueError("a look-ahead needs an environment with a cost")
        if measurements not in ("filter", "model"):
            raise ValueError(f"measurements must be 'filter' or 'model', got {measurements!r}")
        self.env, self.filt, self.model = env, env.filt, env.model
        self.t, self.stream, self.n_runs = decision.t, decision.stream, decision.n_runs
        self.grid, self.measurements = env.grid, measurements
        #: steps after this one in the episode: the continuation's longest useful horizon
        self.steps_left = env.n_steps - 1 - decision.t
        self._decision = decision

    def root(self) -> tuple[np.ndarray, _Branches]:
        cand = self._decision.candidates()
        u = cand["update"]
        return cand["cost"], _Branches(u.x_filt, u.P_filt)

    def noise(self, rng: np.random.Generator, H: int, S: int) -> list[dict]:
        """Per continuation step ``h = 1..H`` the standard normals ``(n, S, M)``, drawn in ``h`` order so
        that a longer horizon extends a shorter one's samples."""
        nx, nz, M = self.model.nx, self.model.nz, self.n_runs
        out = []
        for h in range(1, H + 1):
            e = {}
            if self.measurements == "model":
                if h == 1:
                    e["x0"] = rng.standard_normal((nx, S, M))
                e["w"] = rng.standard_normal((nx, S, M))
            e["v"] = rng.standard_normal((nz, S, M))
            out.append(e)
        return out

    def take(self, Y: _Branches, idx: np.ndarray) -> _Branches:
        return _Branches(Y.m[..., idx], Y.P[..., idx], None if Y.x is None else Y.x[..., idx])

    def expand(self, Y: _Branches, h: int, noise: dict, rng: np.random.Generator,
               tile: int = 1, loglik: bool = False) -> tuple:
        """Step ``t + h``'s candidates from the branches ``Y`` filtered at ``t + h - 1``.

        ``noise``: arrays ``(n, S, m)`` (a chunk of ``m`` runs); ``Y`` holds
        ``tile * m`` runs at ``h = 1`` (copied here to the ``S`` samples after
        the predict) and ``tile * S * m`` later. ``loglik``: also return the
        candidates' log-likelihoods ``(G, B)`` (what an ML base ranks), third.
        """
        filt, model, grid, G = self.filt, self.model, self.grid, self.grid.size
        t = self.t + h
        S, m = noise["v"].shape[1:]
        K = tile
        if h == 1:
            # the predict the environment makes after the decision (its random numbers), once per branch
            mp, Pp = filt.predict_rl(Y.m, Y.P, t - 1, rng=filt.rng(PREDICT, t - 1, self.stream), tile=K)
            idx = (np.arange(K)[:, None, None] * m + np.arange(m)[None, None, :] + np.zeros((1, S, 1), int)).ravel()
            mp, Pp, Y = mp[..., idx], Pp[..., idx], self.take(Y, idx)
            r_upd = rng
        else:
            r_pred, r_upd = rng.spawn(2)
            mp, Pp = filt.predict_rl(Y.m, Y.P, t - 1, rng=r_pred, tile=K)
        B = mp.shape[1]
        x = None
        if self.measurements == "model":
            x = Y.x
            if x is None:  # the state at the decision, drawn from each branch's posterior
                x = Y.m + mv(chol(sym(Y.P), "P_filt"), _copies(noise["x0"], K))
            # the model's time convention: f(x, k) maps x_k to x_{k+1}, z_k = h(x_k, k), k = t + 1
            x = model.f(x.T, t).T + np.linalg.cholesky(model.Q) @ _copies(noise["w"], K)
            z = model.h(x.T, t + 1).T + np.linalg.cholesky(model.R) @ _copies(noise["v"], K)
        else:
            v, d = _copies(noise["v"], K), self.env.default_index

            def z(z_pred: np.ndarray, Lzz: np.ndarray) -> np.ndarray:
                # the filter's predictive under its default parameter, the same draw for every candidate
                block = slice(d * B, (d + 1) * B)
                return np.concatenate([z_pred[:, block] + mv(Lzz[..., block], v)] * G, axis=-1)

        u = filt.update_candidates_rl(mp, Pp, z, t, grid, rng=r_upd, tile=K)
        cost = self.env.cost(u, np.repeat(grid, B), model.nz).reshape(G, B)
        Y = _Branches(u.x_filt, u.P_filt, None if x is None else np.concatenate([x] * G, axis=-1))
        return (cost, Y, u.loglik.reshape(G, B)) if loglik else (cost, Y)

    def spent(self, H: int, S: int, bases: int = 1) -> float:
        """Compute per run of a continuation of ``H >= 1`` steps and ``S`` samples, beyond the decision's
        candidates; ``bases``: continuations that share their first step (``base="best"``: 2)."""
        filt, G = self.filt, self.grid.size
        p = 0.0 if self.model.F is not None else float(filt.predict_rule.spent(filt.param))
        c = filt.candidates_spent(self.grid)
        if bases == 1:
            return G * p + G * S * (H - 1) * p + G * S * H * c
        return G * p + G * S * c + bases * G * S * (H - 1) * (p + c)


def lookahead_model(decision, measurements: Literal["filter", "model"] = "filter"):
    """The look-ahead model of ``decision``: :class:`FilterLookahead` for a
    :class:`~adaptfilt.mdp.FilterEnv`'s decision, or the one another
    environment's decision provides (``decision.lookahead_model()``)."""
    if isinstance(decision, Decision):
        return FilterLookahead(decision, measurements)
    own = getattr(decision, "lookahead_model", None)
    if own is None:
        raise TypeError(f"a look-ahead policy needs a FilterEnv decision or one with lookahead_model(); "
                        f"got {type(decision).__name__}")
    return own()


def _check(grid, samples: int, gamma: float, measurements: str, seed: int) -> np.ndarray:
    grid = np.asarray(grid, dtype=float)
    if grid.ndim != 1 or grid.size == 0 or not np.isfinite(grid).all():
        raise ValueError(f"grid must be a non-empty 1-D sequence of finite parameter values, got {grid.tolist()}")
    if int(samples) != samples or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples}")
    if not (0.0 <= gamma < 1.0):
        raise ValueError(f"gamma must be in [0, 1), got {gamma}")
    if measurements not in ("filter", "model"):
        raise ValueError(f"measurements must be 'filter' or 'model', got {measurements!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    return grid


class _Lookahead:
    """What the look-ahead policies share: the grid check and their random numbers."""

    name: str
    grid: np.ndarray
    seed: int
    measurements: str

    def _model(self, decision):
        g = np.asarray(decision.grid, dtype=float)
        if g.shape != self.grid.shape or not np.allclose(g, self.grid):
            raise ValueError(f"policy {self.name!r} was made for the grid {self.grid.tolist()}, "
                             f"the environment's grid is {g.tolist()}")
        return lookahead_model(decision, self.measurements)

    def _rng(self, decision, stage: int, *key: int) -> np.random.Generator:
        stream = getattr(decision, "stream", None)
        return np.random.default_rng([self.seed, _KEY, stage, decision.t, *key] + ([] if stream is None else [int(stream)]))

    def act(self, decision) -> np.ndarray:
        """Grid indices ``(M,)``: ``argmin_theta`` of :meth:`q` (its compute is charged to the decision)."""
        return np.argmin(self.q(decision), axis=0)


def _finite(cost: np.ndarray) -> np.ndarray:
    # a continuation that broke down (NaN cost) counts as the worst, not as the best (argmin's NaN rule)
    return np.where(np.isnan(cost), np.inf, cost)


class RolloutPolicy(_Lookahead):
    """Rollout over a base policy (greedy by default): ``argmin_theta Q_H(theta)`` (see the module docstring).

    Parameters
    ----------
    grid : sequence of float
        The environment's parameter grid (a ValueError at the first decision otherwise).
    horizon : int
        ``H >= 0`` steps followed with the base policy after the decision; 0 is the base policy.
    samples : int
        ``S >= 1`` sampled continuations per candidate (the same for every candidate).
    gamma : float
        Discount in ``[0, 1)``.
    seed : int
        Keys the continuations' random numbers (with the decision's ``t`` and stream).
    measurements : "filter" or "model"
        Where the continuation's measurements come from.
    max_batch : int
        Candidate updates held at once (runs are taken in chunks to stay below it).
    base : "greedy", "ml" or "best"
        The policy the continuation follows (module docstring): greedy (default), maximum likelihood, or
        the better of the two per decision and candidate.
    name : str, optional
        Default ``rollout-H{H}-S{S}`` (``rollout-ml-...``, ``rollout-best-...`` for the other bases; plus
        ``-gamma{gamma}`` unless 0.5, ``-model`` for model measurements).
    """

    def __init__(self, grid, horizon: int = 1, samples: int = 10, gamma: float = 0.5, seed: int = 0,
                 measurements: Literal["filter", "model"] = "filter", max_batch: int = 2**18, name: str | None = None,
                 base: str = "greedy"):
        self.grid = _check(grid, samples, gamma, measurements, seed)
        if int(horizon) != horizon or horizon < 0:
            raise ValueError(f"horizon must be an integer >= 0, got {horizon}")
        if int(max_batch) != max_batch or max_batch < 1:
            raise ValueError(f"max_batch must be a positive integer, got {max_batch}")
        if base not in BASES:
            raise ValueError(f"unknown base policy {base!r}; choose one of {', '.join(BASES)}")
        self.horizon, self.samples, self.gamma = int(horizon), int(samples), float(gamma)
        self.seed, self.measurements, self.max_batch, self.base = int(seed), measurements, int(max_batch), base
        self.name = name or (f"rollout-{'' if base == 'greedy' else base + '-'}H{self.horizon}-S{self.samples}"
                             + ("" if self.gamma == 0.5 else f"-gamma{self.gamma:g}")
                             + ("-model" if measurements == "model" else ""))

    def act(self, decision) -> np.ndarray:
        """Grid indices ``(M,)``: ``argmin_theta`` of :meth:`q` (its compute is charged to the decision);
        with ``H = 0`` the base policy's choice (for ML, :class:`~adaptfilt.policies.MaxLikelihoodPolicy`'s)."""
        if self.horizon == 0 and self.base == "ml":
            self._model(decision)  # the grid check, as for every base
            ll = decision.candidates().get("loglik")
            if ll is None:
                raise ValueError(f"policy {self.name!r}: an ML base needs the candidates' log-likelihoods")
            return np.argmax(ll, axis=0)
        return super().act(decision)

    def q(self, decision) -> np.ndarray:
        """The estimated discounted cost ``Q_H (G, M)`` of every candidate; adds its compute to
        ``decision.extra_spent`` (each call computes anew)."""
        model = self._model(decision)
        L0, Y0 = model.root()
        H = min(self.horizon, model.steps_left) if self.gamma > 0 else 0
        if H == 0:
            return L0
        G, M = L0.shape
        S = self.samples
        bases = ("greedy", "ml") if self.base == "best" else (self.base,)
        ll = "ml" in bases  # the candidates' log-likelihoods are needed
        if ll and not getattr(model, "has_loglik", False):
            raise ValueError(f"policy {self.name!r}: an ML base needs a look-ahead model that gives the candidates' "
                             f"log-likelihoods (a FilterEnv's); {type(model).__name__} does not")
        noise = model.noise(self._rng(decision, _NOISE), H, S)
        future = {b: np.zeros((G, M)) for b in bases}
        per_chunk = max(1, self.max_batch // (G * G * S))
        for c, lo in enumerate(range(0, M, per_chunk)):
            J = np.arange(lo, min(lo + per_chunk, M))
            Y1 = model.take(Y0, (np.arange(G)[:, None] * M + J[None]).ravel())
            first = None  # the first continuation step, shared by the bases
            for b in bases:
                Y = Y1
                for h in range(1, H + 1):
                    if h == 1 and first is not None:
                        C, Y, LL = first
                    else:
                        out = model.expand(Y, h, {k: a[..., J] for k, a in noise[h - 1].items()},
                                           self._rng(decision, _DRAWS, h, c), tile=G, **({"loglik": True} if ll else {}))
                        C, Y, LL = (out if ll else (*out, None))
                        C = _finite(C)
                        if h == 1:
                            first = (C, Y, LL)
                    B = C.shape[1]
                    # the base's choice in every continuation: greedy's argmin, or ML's argmax (as MaxLikelihoodPolicy)
                    a = np.argmin(C, axis=0) if b == "greedy" else np.argmax(LL, axis=0)
                    future[b][:, J] += self.gamma**h * C[a, np.arange(B)].reshape(G, S, J.size).mean(axis=1)
                    if h < H:
                        Y = model.take(Y, a * B + np.arange(B))
        decision.extra_spent += model.spent(H, S) if len(bases) == 1 else model.spent(H, S, bases=len(bases))
        if len(bases) == 1:
            return L0 + future[bases[0]]
        return L0 + np.minimum(future["greedy"], future["ml"])


class TwoStepPolicy(_Lookahead):
    """Exhaustive two-step look-ahead, ``argmin_theta0 [L_0 + gamma E min_theta1 L_1]`` (see the module docstring).

    The cross-check of :class:`RolloutPolicy` at ``H = 1``: a loop over
    ``theta_0`` (``G`` batches of ``S M`` runs) instead of one batch; with
    the same ``seed`` (and all runs in one chunk of the rollout) both make the
    same choices. Parameters as :class:`RolloutPolicy`; named ``twostep-S{S}``.
    """

    def __init__(self, grid, samples: int = 10, gamma: float = 0.5, seed: int = 0,
                 measurements: Literal["filter", "model"] = "filter", name: str | None = None):
        self.grid = _check(grid, samples, gamma, measurements, seed)
        self.samples, self.gamma, self.seed, self.measurements = int(samples), float(gamma), int(seed), measurements
        self.name = name or (f"twostep-S{self.samples}" + ("" if self.gamma == 0.5 else f"-gamma{self.gamma:g}")
                             + ("-model" if measurements == "model" else ""))

    def q(self, decision) -> np.ndarray:
        """``L_0 + gamma * mean_i min_theta1 L_1^{(i)}`` ``(G, M)``; adds its compute to ``decision.extra_spent``."""
        model = self._model(decision)
        L0, Y0 = model.root()
        if model.steps_left == 0 or self.gamma == 0:
            return L0
        G, M = L0.shape
        S = self.samples
        noise = model.noise(self._rng(decision, _NOISE), 1, S)[0]
        Q = np.empty((G, M))
        for g in range(G):
            C, _ = model.expand(model.take(Y0, g * M + np.arange(M)), 1, noise, self._rng(decision, _DRAWS, 1, 0))
            Q[g] = L0[g] + self.gamma * _finite(C).min(axis=0).reshape(S, M).mean(axis=0)
        decision.extra_spent += model.spent(1, S)
        return Q
