r"""The particle count as the parameter of a Markov decision problem, and its non-learned baselines.

The paper adapts the UKF's kappa and the SIF's iteration count; its introduction names the number of
particles as the first example of a filter parameter. :class:`ParticleCountEnv` poses that choice with
the interface of :class:`~adaptfilt.mdp.FilterEnv` (``reset``, ``step``, a decision per step, a grid of
counts), so that :func:`~adaptfilt.mdp.rollout`, :func:`~adaptfilt.evaluation.evaluate`, the greedy
policy and the trainers run on it unchanged. At step ``t`` a policy sees the information state of the
last posterior cloud and the new measurement, picks ``N_t`` from the grid, the filter
(:class:`~adaptfilt.particles.ParticleCountFilter`) resamples ``N_t`` particles, propagates and weighs
them, and the step pays

.. math::
    L(s_t, z_t, N_t) = L_\mathrm{est} + \lambda N_t,

with ``L_est`` one of the paper's costs computed from the particles (:class:`~adaptfilt.costs.ParticleCost`) and
``lambda`` a price per particle (the computation term, as ``n_iter/50`` for the SIF).

**Information state** (:data:`FEATURES`, ``nx + 4 + 2 nz + 1`` numbers, plus the model's time features):
the last posterior's mean, ``log tr P``, effective sample size over count ``ESS/N``, weight entropy over
``log N``, and log-likelihood; the measurement; the innovation ``z_t - mean h(x_j)`` and ``log tr`` of the
spread of the first ``grid[0]`` predicted particles. Those particles are the first ones of any count on
the grid (particle ``j`` is the same whatever the count), so the state costs no particle beyond the ones
the chosen count keeps. For a circular measurement (the CTM's bearing) ``z`` enters as sine and cosine.

**Compute** is counted in particles per step (``spent``): the chosen count, plus what a decision drew
beyond it (``extra_spent``): greedy weighs every grid count, i.e. ``max(grid)`` particles a step.

**Baselines** (besides :class:`~adaptfilt.policies.FixedPolicy` over the grid and
:class:`~adaptfilt.policies.GreedyPolicy`): :class:`KLDSamplingPolicy` (Fox 2003) and
:class:`ESSTargetPolicy`.

Example
-------
>>> import numpy as np, adaptfilt as af
>>> from adaptfilt.costs import ParticleCost
>>> from adaptfilt.particle_env import ParticleCountEnv, KLDSamplingPolicy
>>> env = ParticleCountEnv(af.models.ungm(), ParticleCost("logmaxnis", price=1e-4), n_steps=20)
>>> run, cost = af.mdp.rollout(env, KLDSamplingPolicy(bin_size=1.0), n_runs=4, rng=0)
>>> cost.shape, bool(np.isin(run.params, env.grid).all())
((4, 20), True)
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from adaptfilt.costs import Cost, ParticleCost, StepCost
from adaptfilt.features import FeatureSet
from adaptfilt.models import StateSpaceModel, Trajectory
from adaptfilt.paramenv import grid_actions

__all__ = ["PARTICLE_GRID", "ParticleUpdate", "check_counts", "FILTER_DESCRIPTION", "ParticleDecision", "ParticleCountEnv",
           "KLDSamplingPolicy", "ESSTargetPolicy", "particle_feature_names"]

#: Counts a policy chooses from: 50 to 5000 in 13 steps of at most 1.67x (as many values as the kappa grid).
PARTICLE_GRID = (50, 75, 100, 150, 200, 300, 500, 750, 1000, 1500, 2000, 3000, 5000)


@dataclass
class ParticleUpdate:
    """What a :class:`~adaptfilt.costs.ParticleCost` reads of one update, per run: ``nis (M,)``, ``dx = x_filt - x_pred
    (M, nx)``, ``err = x_filt - x (M, nx)`` (NaN where the truth is unknown)."""

    nis: np.ndarray
    dx: np.ndarray
    err: np.ndarray


def check_counts(grid) -> None:
    """ValueError unless ``grid`` is an increasing sequence of integer counts >= 1."""
    g = np.asarray(grid, dtype=float)
    if not (np.isfinite(g).all() and (g >= 1).all() and (g == np.round(g)).all()):
        raise ValueError(f"particle counts must be integers >= 1, got {g.tolist()}")
    if np.any(np.diff(g) <= 0):
        raise ValueError(f"the grid of counts must increase, got {g.tolist()}")


#: The filter as policy files record it: its form, not its seed (which keys random streams; a policy
#: trained with one seed acts in an environment with another, learned.check_compatible compares this).
FILTER_DESCRIPTION = "ParticleCountFilter(bootstrap, multinomial resampling)"


def particle_feature_names(model: StateSpaceModel) -> list[str]:
    """Names of :class:`ParticleCountEnv`'s information state for ``model``, in order."""
    z = []
    for i in range(model.nz):
        z += [f"sin z[{i}]", f"cos z[{i}]"] if i in model.circular_z else [f"z[{i}]"]
    return ([f"x_prev[{i}]" for i in range(model.nx)] + ["log tr P_prev", "ESS/N prev", "entropy/log N prev",
                                                         "loglik prev"]
            + z + [f"innov[{i}]" for i in range(model.nz)] + ["log tr P_pred"]
            + [f"time[{n}]" for n in model.time_feature_names])


@dataclass
class ParticleDecision:
    """What a policy sees at step ``t``, batched over ``M`` runs (the particle form of
    :class:`~adaptfilt.mdp.Decision`): ``features (M, d)``, ``z (M, nz)``, ``grid``, and

    * :meth:`predicted` ``(n)``: the first ``n`` predicted particles of every run, ``(M, n, nx)``, the
      same particles whatever count is chosen (charged to nobody: a rule that keeps at least the
      particles it looked at, as KLD-sampling, spends only what it keeps);
    * :meth:`candidates`: the cost of every grid count (greedy), which weighs ``max(grid)`` particles
      (``extra_spent``); the step then runs the chosen count.
    * ``ess_prev``, ``n_prev`` ``(M,)``: the last update's effective sample size and count.
    """

    t: int
    grid: np.ndarray
    default_index: int
    _env: "ParticleCountEnv" = field(repr=False)
    _state: dict = field(repr=False)
    z: np.ndarray = field(repr=False)
    _pred: np.ndarray | None = field(default=None, repr=False)
    _feat: np.ndarray | None = field(default=None, repr=False)
    _cand: dict | None = field(default=None, repr=False)
    extra_spent: float = 0.0

    @property
    def n_runs(self) -> int:
        return self.z.shape[0]

    @property
    def env(self) -> "ParticleCountEnv":
        return self._env

    @property
    def ess_prev(self) -> np.ndarray:
        return self._state["ess"]

    @property
    def n_prev(self) -> np.ndarray:
        return self._state["n"]

    def predicted(self, n: int) -> np.ndarray:
        """The first ``n`` predicted particles of every run, ``(M, n, nx)`` (computed once, extended on demand)."""
        n = int(n)
        if self._pred is None or self._pred.shape[1] < n:
            self._pred = self._env._predict(self._state, self.t, np.full(self.n_runs, n))
        return self._pred[:, :n]

    @property
    def features(self) -> np.ndarray:
        if self._feat is None:
            self._feat = self._env._features(self)
        return self._feat

    def candidates(self) -> dict:
        """``{"cost": (G, M), "nis": (G, M)}`` of every grid count (a common weight shift for all counts:
        the chosen count's cost may differ from the step's in the last bits)."""
        if self._cand is None:
            self._cand = self._env._candidates(self)
            self.extra_spent = float(self.grid.max())
        return self._cand


class ParticleCountEnv:
    """The particle count per step as a Markov decision problem (see the module docstring).

    ``model``: a model with additive Gaussian noise; ``cost``: a :class:`~adaptfilt.costs.ParticleCost`
    (or another :class:`~adaptfilt.costs.StepCost` of a :class:`ParticleUpdate`; None: no cost);
    ``grid``: the counts (default :data:`PARTICLE_GRID`), ``default``: the count of the "default"
    policy (1000); ``seed`` keys the particles' random streams (run ``i`` of episode ``stream``: key
    ``(seed, stream * 2**32 + i)``); ``truth``: the model trajectories are simulated from (default: ``model``);
    ``experiment``: the experiment a variant belongs to (as :class:`~adaptfilt.mdp.FilterEnv`'s). The same
    interface as :class:`~adaptfilt.mdp.FilterEnv`: ``reset(n_runs, rng, traj, stream)``, ``step(actions)``.
    """

    param_name = "n_particles"
    compute_unit = "particles"

    def __init__(self, model: StateSpaceModel, cost: StepCost | None = None, grid: Sequence[int] = PARTICLE_GRID,
                 default: int = 1000, seed: int = 0, n_steps: int | None = None, truth: StateSpaceModel | None = None,
                 experiment: str | None = None):
        # Here, not at the top: `import adaptfilt` (which imports the registry, and so this module) loads no
        # particle filter, and through it no numba, until a particle environment is built.
        from adaptfilt.particles import ParticleCountFilter

        if cost is not None and (not isinstance(cost, StepCost) or isinstance(cost, Cost)):
            raise TypeError(f"cost must be a ParticleCost, another StepCost of a particle update (or None), "
                            f"got {type(cost).__name__}")
        self.model, self.experiment = model, experiment
        self.truth = model if truth is None else truth  # the model trajectories are simulated from
        if (self.truth.nx, self.truth.nz) != (model.nx, model.nz):
            raise ValueError(f"the truth model has nx = {self.truth.nx}, nz = {self.truth.nz}; the filter's model "
                             f"nx = {model.nx}, nz = {model.nz}")
        grid = np.asarray(grid, dtype=float)
        if grid.ndim != 1 or grid.size < 1:
            raise ValueError(f"grid must be a non-empty 1-D sequence of counts, got shape {grid.shape}")
        check_counts(grid)
        matches = np.flatnonzero(grid == default)
        if matches.size == 0:
            raise ValueError(f"the grid {grid.astype(int).tolist()} must contain the default count {default}")
        self.grid, self.default_index, self.cost = grid, int(matches[0]), cost
        self.pf = ParticleCountFilter(model, seed)
        self.n_steps = model.n_steps if n_steps is None else int(n_steps)
        if self.n_steps is None or self.n_steps < 1:
            raise ValueError("n_steps must be given (the model has no default horizon)")
        self.nx, self.nz = model.nx, model.nz
        self.feature_names = particle_feature_names(model)
        self.n_features = len(self.feature_names)
        self.traj: Trajectory | None = None
        self._decision: ParticleDecision | None = None
        #: read by :func:`~adaptfilt.mdp.rollout` into the run: a collapsed cloud's NEES is infinite
        self.run_info = {"on_indefinite": "inf"}

    def __repr__(self) -> str:
        return (f"ParticleCountEnv({self.model.name}, cost={None if self.cost is None else self.cost.name}, "
                f"grid={self.grid.astype(int).tolist()}, n_steps={self.n_steps})")

    @property
    def default(self) -> int:
        """The count of the "default" policy: ``grid[default_index]``, an integer (as results record it)."""
        return int(self.grid[self.default_index])

    @staticmethod
    def spent(theta: np.ndarray) -> np.ndarray:
        """Particles per run of one step at counts ``theta``."""
        return np.asarray(theta, dtype=float)

    def describe(self, features: "str | FeatureSet | None" = None) -> dict:
        """What a policy file records and must match (:meth:`FilterEnv.describe <adaptfilt.mdp.FilterEnv.describe>`);
        the information state is this environment's own, whatever ``features`` says."""
        return {"model": self.model.name, "filter": FILTER_DESCRIPTION, "param_name": self.param_name,
                "grid": self.grid.tolist(), "feature_names": list(self.feature_names),
                "cost": None if self.cost is None else self.cost.name}

    # ----------------------------------------------------------- helpers
    def _predict(self, state: dict, t: int, n: np.ndarray) -> np.ndarray:
        return self.pf.predict(state["x"], state["w"], state["n"], t, n.astype(np.int64), self._ids)

    def _features(self, d: ParticleDecision) -> np.ndarray:
        s, model = d._state, self.model
        x0 = d.predicted(int(self.grid[0]))
        r = model.diff_z(d.z[:, None, :], model.h(x0, d.t + 1))  # (M, n0, nz)
        spread = np.log(1e-12 + np.trace(np.einsum("mni,mnj->mij", x0 - x0.mean(1, keepdims=True),
                                           x0 - x0.mean(1, keepdims=True)) / x0.shape[1], axis1=1, axis2=2))
        zc = []
        for i in range(self.nz):
            zc += [np.sin(d.z[:, i]), np.cos(d.z[:, i])] if i in model.circular_z else [d.z[:, i]]
        # a cloud collapsed onto one point has no spread: it reads as 1e-12 (finite features)
        blocks = [s["mean"].T, np.log(np.maximum(np.trace(s["cov"], axis1=1, axis2=2), 1e-12))[None],
                  (s["ess"] / s["n"])[None],
                  s["entropy"][None], s["loglik"][None], np.stack(zc), r.mean(axis=1).T, spread[None]]
        if model.time_features is not None:
            tf = np.asarray(model.time_features(d.t + 1), dtype=float)
            blocks.append(np.repeat(tf[:, None], d.n_runs, axis=1))
        return np.concatenate(blocks, axis=0).T

    def _update(self, x: np.ndarray, n: np.ndarray, z: np.ndarray, t: int, logl: np.ndarray | None = None,
                r: np.ndarray | None = None) -> tuple[dict, ParticleUpdate]:
        """Weigh the first ``n`` of ``x``; the posterior and what a cost reads. ``logl``, ``r``: the particles'
        log-likelihoods and measurement residuals, when the caller has them already (greedy's candidates)."""
        post = self.pf.weigh(x, n, z, t, self._ids, logl=logl)
        valid = np.arange(x.shape[1])[None, :] < n[:, None]
        x_pred = (x * valid[..., None]).sum(axis=1) / n[:, None]
        dp = (x - x_pred[:, None, :]) * valid[..., None]
        post["x_pred"], post["P_pred"] = x_pred, np.einsum("mni,mnj->mij", dp, dp) / n[:, None, None]
        post["nis"] = self._nis(x, valid, n, z, t, r)
        truth = self.traj.x[:, t] if self.traj is not None and self.traj.x.shape[1] > t else np.nan
        return post, ParticleUpdate(nis=post["nis"], dx=post["mean"] - x_pred, err=post["mean"] - truth)

    def _nis(self, x: np.ndarray, valid: np.ndarray, n: np.ndarray, z: np.ndarray, t: int,
             r: np.ndarray | None = None) -> np.ndarray:
        """NIS of ``z`` under the Gaussian fit of the predicted measurement of the first ``n`` particles."""
        if r is None:
            r = self.model.diff_z(z[:, None, :], self.model.h(x, t + 1))
        r = r * valid[..., None]  # (M, cap, nz)
        innov = r.sum(axis=1) / n[:, None]
        d = (r - innov[:, None, :]) * valid[..., None]
        S = np.einsum("mni,mnj->mij", d, d) / np.maximum(n - 1, 1)[:, None, None] + self.model.R
        return np.einsum("mi,mi->m", innov, np.linalg.solve(S, innov[..., None])[..., 0])

    def _candidates(self, d: ParticleDecision) -> dict:
        G, M, cap = self.grid.size, d.n_runs, int(self.grid.max())
        x = d.predicted(cap)
        # every count's particles are a prefix of these: their likelihoods and residuals once, sliced per count
        logl = self.pf.loglik_particles(x, d.z, d.t)
        r = self.model.diff_z(d.z[:, None, :], self.model.h(x, d.t + 1))
        nis, cost = np.empty((G, M)), np.empty((G, M))
        for g, n in enumerate(self.grid.astype(np.int64)):
            nn = np.full(M, n)
            _, u = self._update(x[:, :n], nn, d.z, d.t, logl[:, :n], r[:, :n])
            nis[g] = u.nis
            cost[g] = self.cost(u, nn, self.nz) if self.cost is not None else np.nan
        return {"cost": cost if self.cost is not None else None, "nis": nis}

    def _new_decision(self) -> ParticleDecision:
        self._decision = ParticleDecision(self._t, self.grid, self.default_index, self, self._state,
                                          self._zs[self._t])
        return self._decision

    # --------------------------------------------------------------- API
    def reset(self, n_runs: int | None = None, rng: np.random.Generator | int | None = None,
              traj: Trajectory | None = None, stream: int | None = None) -> ParticleDecision:
        """Start an episode: simulate ``n_runs`` trajectories (one step beyond the horizon, for a learner's
        bootstrap) or replay ``traj``; ``stream`` keys the particles of this episode."""
        if traj is None:
            if n_runs is None:
                raise ValueError("reset needs n_runs (to simulate) or traj (to replay)")
            traj = self.truth.simulate(n_runs, self.n_steps + 1, rng=rng)
        if traj.z.ndim != 3 or traj.z.shape[1] < self.n_steps or traj.z.shape[2] != self.nz:
            raise ValueError(f"traj.z must have shape (M, >= {self.n_steps}, {self.nz}), got {traj.z.shape}")
        self.pf.check_z(traj.z)
        M = traj.z.shape[0]
        # run i's key is stream * 2**32 + i, an int64: a stream beyond 2**31 (or negative) would not fit
        if stream is not None and (isinstance(stream, (bool, np.bool_)) or not isinstance(stream, numbers.Integral)
                                   or not 0 <= stream < 2**31):
            raise ValueError(f"stream must be an integer in [0, 2**31) (run i of the episode draws from the "
                             f"particle streams of run id stream * 2**32 + i), got {stream!r}")
        # every run's max(grid) predicted particles are held at once (greedy's candidates weigh them all)
        self.pf.check_memory(int(self.grid.max()), M, label=f"the grid's n_particles = {int(self.grid.max())}")
        self.traj, self.stream = traj, stream
        self._ids = np.arange(M, dtype=np.int64) + (0 if stream is None else int(stream) << 32)
        self._zs = np.ascontiguousarray(np.moveaxis(traj.z, 1, 0))  # (T, M, nz)
        self._t = 0
        nx = self.nx
        self._state = {"x": None, "w": None, "n": np.ones(M, dtype=np.int64),
                       "mean": np.repeat(self.model.m0[None], M, axis=0),
                       "cov": np.repeat(self.model.P0[None], M, axis=0).reshape(M, nx, nx),
                       "ess": np.ones(M), "entropy": np.ones(M), "loglik": np.zeros(M)}
        return self._new_decision()

    def check_actions(self, actions) -> np.ndarray:
        """Grid indices as an int array ``(M,)``; ValueError naming what is wrong."""
        return grid_actions(actions, self._zs.shape[1], self.grid.size)

    def step(self, actions, predict_param=None) -> tuple[ParticleDecision | None, np.ndarray | None, bool, dict]:
        """Resample, propagate and weigh ``grid[actions]`` particles per run; pay the cost.

        Returns ``(decision, cost, done, info)`` with the keys of :meth:`FilterEnv.step
        <adaptfilt.mdp.FilterEnv.step>` (``x_filt``, ``P_filt``: the particles' weighted mean and
        covariance; ``nis``: of the Gaussian fit; ``loglik``: log p-hat(z_t | z^{t-1}); ``ess``)."""
        if self._decision is None:
            raise RuntimeError("call reset() before step()")
        if predict_param is not None:
            raise ValueError("a particle count is chosen per step: there is no separate predict parameter")
        a = self.check_actions(actions)
        theta = self.grid[a]
        n = theta.astype(np.int64)
        d, t = self._decision, self._t
        x = d._pred[:, :int(n.max())] if d._pred is not None and d._pred.shape[1] >= n.max() else \
            self._predict(self._state, t, n)
        post, u = self._update(x, n, self._zs[t], t)
        cost = None if self.cost is None else self.cost(u, theta, self.nz)
        w = post["w"]
        with np.errstate(divide="ignore", invalid="ignore"):
            entropy = -np.where(w > 0, w * np.log(w), 0.0).sum(axis=1) / np.log(np.maximum(n, 2))
        info = {"t": t, "theta": theta, "update": u, "x_filt": post["mean"], "P_filt": post["cov"],
                "nis": u.nis, "loglik": post["loglik"], "ess": post["ess"],
                "x_pred": post["x_pred"], "P_pred": post["P_pred"],
                "extra_spent": d.extra_spent - (theta if d._cand is not None else 0.0),
                "repaired": np.zeros(len(n), dtype=bool), "terminated": False, "truncated": False}
        self._state = {"x": x, "w": w, "n": n, "mean": post["mean"], "cov": post["cov"], "ess": post["ess"],
                       "entropy": entropy, "loglik": post["loglik"]}
        done = t + 1 >= self.n_steps
        if done and self._zs.shape[0] <= self.n_steps:
            self._decision = None
            info.update(truncated=True, final_decision=None)
            return None, cost, True, info
        self._t = t + 1
        if done:
            info.update(truncated=True, final_decision=self._new_decision())
            self._decision = None
            return None, cost, True, info
        return self._new_decision(), cost, False, info


class KLDSamplingPolicy:
    r"""KLD-sampling (Fox 2003) on the grid: the count is the smallest grid value at or above the
    sequential stopping count of :func:`~adaptfilt.particles.kld_count` (batched: :func:`~adaptfilt.particles.kld_counts`) on the step's predicted
    particles (bins of ``bin_size`` per state dimension; ``epsilon = 0.05``, ``delta = 0.01`` and at
    least ``n_min`` particles, Fox's usual values). The particles it examines are the first ones of
    the count it keeps, so it spends only that count."""

    cost_blind = True
    kind = "kld"

    def __init__(self, bin_size: float | Sequence[float], epsilon: float = 0.05, delta: float = 0.01,
                 n_min: int = 50, grid=None, name: str = "kld"):
        self.name = name
        self.bin_size = np.asarray(bin_size, dtype=float)
        if self.bin_size.ndim > 1:
            raise ValueError(f"bin_size must be a scalar or one per state dimension, got shape {self.bin_size.shape}")
        if not (np.isfinite(self.bin_size).all() and (self.bin_size > 0).all()):
            raise ValueError(f"bin_size must be finite and > 0, got {self.bin_size.tolist()}")
        from adaptfilt.particles import kld_bound  # the particle filter loads with its first use

        kld_bound(1, epsilon, delta)  # names a bad epsilon or delta now, not at the first step
        if isinstance(n_min, (bool, np.bool_)) or not isinstance(n_min, numbers.Integral) or n_min < 1:
            raise ValueError(f"n_min must be an integer >= 1, got {n_min!r}")
        self.epsilon, self.delta, self.n_min = float(epsilon), float(delta), int(n_min)
        self.grid = None if grid is None else np.asarray(grid, dtype=float)

    def counts(self, decision) -> np.ndarray:
        """The stopping count of every run, ``(M,)`` (before rounding up to the grid)."""
        from adaptfilt.particles import kld_counts  # the particle filter loads with its first use

        cap = int(decision.grid.max())
        x = decision.predicted(cap)
        return kld_counts(x, self.bin_size, self.epsilon, self.delta, self.n_min)

    def act(self, decision) -> np.ndarray:
        n = self.counts(decision)
        return np.minimum(np.searchsorted(decision.grid, n, side="left"), decision.grid.size - 1)


class ESSTargetPolicy:
    r"""Keep the effective sample size near a target: ``N_t`` is the smallest grid count at or above
    ``target * N_{t-1} / ESS_{t-1}`` (the count that, at the last step's weight degeneracy, would
    leave ``target`` effective particles), the default count at the first step."""

    cost_blind = True
    kind = "ess"

    def __init__(self, target: float = 200.0, grid=None):
        if not (np.isfinite(target) and target >= 1):
            raise ValueError(f"target must be >= 1, got {target}")
        self.target = float(target)
        self.name = f"ess-{self.target:g}"
        self.grid = None if grid is None else np.asarray(grid, dtype=float)

    def act(self, decision) -> np.ndarray:
        if decision.t == 0:
            return np.full(decision.n_runs, decision.default_index)
        want = self.target * decision.n_prev / decision.ess_prev
        return np.minimum(np.searchsorted(decision.grid, want, side="left"), decision.grid.size - 1)
