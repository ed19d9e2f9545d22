r"""Parameter adaptation as a Markov decision problem (Section IV of the paper).

At step ``t`` the filter has predicted ``N(x_pred, P_pred)`` and received ``z``.
A policy picks the update parameter ``theta_t`` from a discrete grid, the
update runs with it, a cost ``L(s_t, z_t, theta_t)`` is paid, and the filter
predicts to the next step. :class:`FilterEnv` wraps exactly that loop, batched
over Monte-Carlo runs; training and evaluation drive the same environment.

**Information state** (Section VI-D)

.. math::
    \bar s_t = [\hat x_{t|t-1}^T,\ \mathrm{tr} P_{t|t-1},\ \log\det P_{t|t-1},\ z_t^T,\
    \tilde z_{t|t-1}^T]^T,

``nx + 2 + 2 nz`` numbers. The innovation ``z~`` at decision time is computed
with the *default* parameter: the chosen parameter is not known yet when the
state is formed. Networks see the features through a :class:`FeatureScaler`
that is stored with a trained policy.

**Costs** (Section VI-D), all functions of the update under the chosen parameter:
``L_NIS = (NIS - nz)^2``, ``L_logmaxNIS = log(1 + max(0, NIS - nz))``,
``L_stateInnov = ||K z~||``, plus an optional computational term
``weight * n_iter`` (the paper uses ``1/50``); beyond the paper ``L_sqerr = ||x_{t|t} - x_t||^2``
against the episode's true state (:meth:`FilterEnv._charge` hands it to the cost): :class:`~adaptfilt.costs.Cost`, in
:mod:`adaptfilt.costs` with every other cost (this module's ``Cost`` is that one).

:class:`FilterEnv` meets :class:`~adaptfilt.paramenv.ParamEnv`, the interface every parameter MDP
declares (:func:`~adaptfilt.paramenv.check_env` checks it).
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Sequence

import numpy as np

from adaptfilt.costs import Cost, StepCost
from adaptfilt.features import PAPER, FeatureScaler, FeatureSet, feature_names, fit_scaler
from adaptfilt.filters import FilterRun
from adaptfilt.gaf import FilterError, GaussianAssumedFilter
from adaptfilt.linalg import NotPositiveDefinite, chol, clip_to_pd, logdet_chol, sym
from adaptfilt.models import Trajectory
from adaptfilt.paramenv import ParamEnv, grid_actions

__all__ = ["Cost", "FeatureScaler", "FeatureSet", "Decision", "FilterEnv", "feature_names", "fit_scaler",
           "rollout", "run_policy", "PREDICT", "UPDATE"]

#: Keys of the two steps' random streams (``filt.rng(PREDICT, t, stream)``): a look-ahead that simulates
#: the filter's next steps draws what the environment would (:mod:`adaptfilt.lookahead`).
PREDICT, UPDATE = 0, 1


# ------------------------------------------------------------------ decision
@dataclass
class Decision:
    """What a policy sees at step ``t``, batched over ``M`` runs.

    ``features (M, d)``: the paper's information state (unscaled, see
    :func:`feature_names`); :meth:`observe` gives any other
    :class:`~adaptfilt.features.FeatureSet`. ``x_pred (M, nx)``,
    ``P_pred (M, nx, nx)``, ``z (M, nz)``; ``grid``: the parameter values an
    action indexes. :meth:`candidates` runs the update for every grid value
    (what the maximum-likelihood and greedy baselines need); it is computed
    once and, when a policy used it, the step reuses it so that the chosen
    candidate is exactly the update that happens.

    Features are computed on first access and cached: the innovation feature
    costs an extra update with the default parameter, which fixed, ML and
    greedy policies never need. What a decision computed beyond the chosen
    update is counted in ``extra_spent``, in the rule's unit of compute
    (:meth:`~adaptfilt.rules.MomentRule.spent`: SIF iterations, UKF updates),
    so that an evaluation can report, and a cost can charge, what looking at
    the information state costs. Covariance repairs made only to decide
    (features, candidates not chosen) are not repairs of the filter that ran:
    they are not counted (``info["repaired"]``). A decision keeps its own
    predicted moments, so its features and candidates stay correct even when
    read after the environment has stepped on.
    """

    t: int
    grid: np.ndarray
    default_index: int
    _env: "FilterEnv" = field(repr=False)
    _m: np.ndarray = field(repr=False)  # (nx, M) run-last predicted mean
    _P: np.ndarray = field(repr=False)  # (nx, nx, M)
    _z: np.ndarray = field(repr=False)  # (nz, M)
    _stream: int | None = field(default=None, repr=False)
    _cand: dict | None = field(default=None, repr=False)
    _obs: dict = field(default_factory=dict, repr=False)  # feature-set name -> (M, d)
    _innov: dict = field(default_factory=dict, repr=False)  # innovation parameter -> (nz, M)
    extra_spent: float = 0.0

    @property
    def features(self) -> np.ndarray:
        """The paper's information state ``(M, nx + 2 + 2 nz)`` (computed once, on first access)."""
        return self.observe(PAPER)

    def observe(self, features: "str | FeatureSet | None" = None) -> np.ndarray:
        """The information state for a feature set (default: the paper's), ``(M, d)``, cached."""
        fs = FeatureSet.parse(features)
        if fs.name not in self._obs:
            self._obs[fs.name] = self._env._observe(self, fs)
        return self._obs[fs.name]

    @property
    def n_runs(self) -> int:
        return self._m.shape[1]

    @property
    def env(self) -> "FilterEnv":
        """The environment that made this decision: its filter, cost, grid and horizon, what a
        look-ahead policy simulates with (:mod:`adaptfilt.lookahead`)."""
        return self._env

    @property
    def stream(self) -> int | None:
        """The episode's key of a stochastic rule's random numbers (``FilterEnv.reset(stream=...)``)."""
        return self._stream

    @property
    def x_pred(self) -> np.ndarray:
        return self._m.T

    @property
    def P_pred(self) -> np.ndarray:
        return np.moveaxis(self._P, -1, 0)

    @property
    def z(self) -> np.ndarray:
        return self._z.T

    def candidates(self) -> dict:
        """Update results for every grid value: ``nis``, ``loglik``, ``cost``
        as ``(G, M)`` arrays (``cost`` is None when the env has no cost)."""
        if self._cand is None:
            self._cand = self._env._candidates(self._m, self._P, self._z, self.t, self._stream)
            self.extra_spent += self._env.filt.candidates_spent(self.grid)
        return self._cand

    def _innovation(self, param: float) -> np.ndarray:
        if param not in self._innov:
            self._innov[param] = self._env._innovation(self._m, self._P, self._z, self.t, self._stream, param)
            self.extra_spent += float(self._env.filt.rule.spent(param))
        return self._innov[param]


# ----------------------------------------------------------------- the env
class FilterEnv:
    """The filter loop as a batched MDP environment.

    Parameters
    ----------
    filt : GaussianAssumedFilter
        Its own parameter is used in the predict step and is the *default*.
    grid : sequence of float
        The discrete parameter set ``Theta`` (update step).
    cost : Cost or None
        The one-step cost; None (e.g. to filter real data) returns no cost.
    n_steps : int, optional
        Horizon; defaults to the model's.
    truth : StateSpaceModel, optional
        The model trajectories are simulated from (default: the filter's own).
    experiment : str, optional
        The experiment this environment is a variant of (another truth, a cut grid:
        :meth:`~adaptfilt.experiment_registry.Experiment.make_env`): policies trained on it record it.

    ``reset(n_runs, rng)`` simulates fresh trajectories (or takes ``traj``),
    initialises the filter and returns the first :class:`Decision`;
    ``step(actions)`` takes grid indices ``(M,)`` and returns
    ``(next_decision or None, cost (M,), done, info)``.

    Common random numbers: ``reset(traj=...)`` replays given trajectories, and
    a stochastic rule draws the same numbers for the same ``(stream, t)``
    whatever the policy, so policies compared on one env are paired.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> from adaptfilt.mdp import FilterEnv, Cost
    >>> model = af.models.ungm()
    >>> env = FilterEnv(af.UKF(model), grid=[0.0, 2.0, 10.0], cost=Cost("nis"), n_steps=20)
    >>> d = env.reset(n_runs=4, rng=np.random.default_rng(0))
    >>> d.features.shape
    (4, 5)
    >>> d, cost, done, info = env.step(np.full(4, d.default_index))
    """

    def __init__(self, filt: GaussianAssumedFilter, grid: Sequence[float], cost: Cost | None = None,
                 n_steps: int | None = None, truth=None, experiment: str | None = None):
        self.filt = filt
        self.model = filt.model
        self.experiment = experiment
        #: the model ``reset`` simulates trajectories from: the filter's own (default), or another one with the
        #: same dimensions (a mismatched truth: other noise levels or prior, for out-of-distribution studies)
        self.truth = self.model if truth is None else truth
        if (self.truth.nx, self.truth.nz) != (self.model.nx, self.model.nz):
            raise ValueError(f"the truth model has nx = {self.truth.nx}, nz = {self.truth.nz}; the filter's model "
                             f"nx = {self.model.nx}, nz = {self.model.nz}")
        grid = np.asarray(grid, dtype=float)
        if grid.ndim != 1 or grid.size < 1:
            raise ValueError(f"grid must be a non-empty 1-D sequence of parameter values, got shape {grid.shape}")
        filt.rule.check_param(grid, self.model.nx)  # e.g. kappa <= -n is a ValueError naming it
        self.grid = grid
        matches = np.flatnonzero(np.isclose(grid, filt.param))
        if matches.size == 0:
            raise ValueError(f"the grid {grid.tolist()} must contain the filter's default {filt.rule.param_name} = {filt.param:g}")
        self.default_index = int(matches[0])
        self.cost = cost
        self.n_steps = self.model.n_steps if n_steps is None else int(n_steps)
        if self.n_steps is None or self.n_steps < 1:
            raise ValueError("n_steps must be given (the model has no default horizon)")
        self.nx, self.nz = self.model.nx, self.model.nz
        self.n_features = self.nx + 2 + 2 * self.nz
        self.stream: int | None = None
        self.traj: Trajectory | None = None
        self._decision: Decision | None = None

    # ----------------------------------------------------------- helpers
    def _repaired(self, P: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        """``(P, L)``: ``P_pred`` symmetrised, repaired as the update will repair it (the update counts it)."""
        P = sym(P)
        try:
            return P, chol(P, "P_pred")
        except NotPositiveDefinite as e:
            if self.filt.on_indefinite == "raise":
                raise FilterError("P_pred is not positive definite", t, e.runs) from None
            P = sym(clip_to_pd(P, e.runs))
            return P, chol(P, "P_pred")

    def _innovation(self, m, P, z, t: int, stream: int | None, param: float) -> np.ndarray:
        """The innovation ``z - z_pred(param)`` ``(nz, M)``, with the chosen update's random numbers."""
        P, _ = self._repaired(P, t)
        return self.filt.update_rl(m, P, z, t, param, rng=self.filt.rng(UPDATE, t, stream)).innovation

    def _observe(self, d: "Decision", fs: FeatureSet) -> np.ndarray:
        """The raw information state of decision ``d`` for feature set ``fs`` (see :mod:`adaptfilt.features`)."""
        P, L = self._repaired(d._P, d.t)
        M = d.n_runs
        z = d._z
        if fs.circular and self.model.circular_z:
            rows = []
            for i in range(self.nz):
                rows += [np.sin(z[i]), np.cos(z[i])] if i in self.model.circular_z else [z[i]]
            z = np.stack(rows)
        blocks = [d._m, np.trace(P, axis1=0, axis2=1)[None], logdet_chol(L)[None], z,
                  d._innovation(self.filt.param if fs.innovation is None else fs.innovation)]
        if fs.time and self.model.time_features is not None:
            # The paper's k = t + 1 is the index of this step; its dynamics' phase is what the next predict uses.
            tf = np.asarray(self.model.time_features(d.t + 1), dtype=float)
            blocks.append(np.repeat(tf[:, None], M, axis=1))
        if fs.candidates:
            if self.cost is not None and self.cost.needs_truth:
                # the candidates' costs would hand the policy the true state
                raise ValueError(f"the 'cand' features would read the true state through the cost {self.cost.name!r}")
            cost = d.candidates()["cost"]
            if cost is None:
                raise ValueError("the 'cand' features need an environment with a cost")
            # log1p keeps the heavy-tailed NIS cost (up to 1e7) in range; a non-finite
            # candidate (a diverging update) reads as the largest log-cost a float has.
            blocks.append(np.nan_to_num(np.log1p(np.maximum(cost, 0.0)), nan=710.0, posinf=710.0))
        if fs.likelihoods:
            # what ML ranks, without the step's common offset; a non-finite candidate reads as -710
            ll = d.candidates()["loglik"]
            ok = np.isfinite(ll)
            top = np.max(np.where(ok, ll, -np.inf), axis=0)
            with np.errstate(invalid="ignore"):
                rel = ll - np.where(np.isfinite(top), top, 0.0)
            blocks.append(np.where(ok, np.maximum(rel, -710.0), -710.0))
        return np.concatenate(blocks, axis=0).T

    def _logging_repairs(self, n: int, fn):
        """Run ``fn()`` and return ``(its result, bool (n,) runs repaired meanwhile)``."""
        self.filt.repair_log = []
        try:
            out = fn()
            flags = np.zeros(n, dtype=bool)
            for runs in self.filt.repair_log:
                flags[np.asarray(runs) % n] = True
            return out, flags
        finally:
            self.filt.repair_log = None

    def _candidates(self, m: np.ndarray, P: np.ndarray, z: np.ndarray, t: int, stream: int | None) -> dict:
        G, M = self.grid.size, m.shape[1]
        # Repair (and count) an indefinite P_pred once here, not once per grid value.
        (_, P), pred_flags = self._logging_repairs(M, lambda: self.filt.factor(sym(P), "P_pred", t))
        theta = np.repeat(self.grid, M)
        u, flags = self._logging_repairs(
            G * M, lambda: self.filt.update_candidates_rl(m, P, z, t, self.grid, rng=self.filt.rng(UPDATE, t, stream)))
        out = {"update": u, "theta": theta, "repaired": flags.reshape(G, M) | pred_flags[None],
               "nis": u.nis.reshape(G, M), "loglik": u.loglik.reshape(G, M), "cost": None}
        if self.cost is not None:
            out["cost"] = self._charge(u, theta, t, G).reshape(G, M)
        return out

    def _charge(self, u, theta: np.ndarray, t: int, repeat: int = 1) -> np.ndarray:
        """The cost of update ``u`` at step ``t``; a cost that reads the truth (``needs_truth``: the
        ``"sqerr"`` :class:`~adaptfilt.costs.Cost`, a :class:`~adaptfilt.costs.FunctionCost` that says so)
        gets the true state of step ``t`` from the episode's trajectory, run-last ``(nx, M)``, tiled
        ``repeat`` times for the grid's candidates (candidate ``g`` of run ``m`` sits at ``g M + m``).
        Every other cost is called exactly as always."""
        if not self.cost.needs_truth:
            return self.cost(u, theta, self.nz)
        x = self.traj.x
        if x.ndim != 3 or x.shape[1] <= t:
            raise ValueError(f"cost {self.cost.name!r} needs the true state of step {t}: the trajectory has "
                             f"states of shape {x.shape}")
        truth = np.ascontiguousarray(x[:, t].T)
        return self.cost(u, theta, self.nz, truth=np.tile(truth, (1, repeat)) if repeat > 1 else truth)

    def _new_decision(self) -> Decision:
        self._decision = Decision(self._t, self.grid, self.default_index, self,
                                  self._m, self._P, self._z_t, self.stream)
        return self._decision

    # --------------------------------------------------------------- API
    @property
    def default(self) -> float:
        """The default parameter value (the filter's own): ``grid[default_index]``."""
        return self.filt.param

    @property
    def param_name(self) -> str:
        return self.filt.rule.param_name

    @property
    def compute_unit(self) -> str:
        return self.filt.rule.compute_unit

    def spent(self, theta: np.ndarray) -> np.ndarray:
        """Compute of one update per run at ``theta``, in :attr:`compute_unit` (the rule's count)."""
        return self.filt.rule.spent(theta)

    def describe(self, features: "str | FeatureSet | None" = None) -> dict:
        """What a policy file records and must match: the model, the filter (its ``repr``: rule and options,
        e.g. the SIF's passes), the parameter, the grid, the names of feature set ``features`` (default the
        paper's) and the cost."""
        return {"model": self.model.name, "filter": repr(self.filt), "param_name": self.param_name,
                "grid": self.grid.tolist(), "feature_names": FeatureSet.parse(features).names(self.model, self.grid),
                "cost": None if self.cost is None else self.cost.name}

    def reset(self, n_runs: int | None = None, rng: np.random.Generator | int | None = None,
              traj: Trajectory | None = None, stream: int | None = None) -> Decision:
        """Start an episode: simulate ``n_runs`` trajectories with ``rng`` (or
        replay ``traj``), set the prior, return the first decision.
        ``stream`` keys a stochastic rule's random numbers (e.g. the episode)."""
        if traj is None:
            if n_runs is None:
                raise ValueError("reset needs n_runs (to simulate) or traj (to replay)")
            # One step beyond the horizon: the episode ends at a time limit, not in a
            # terminal state, and a learner bootstraps from the next information
            # state (``info["final_decision"]``), which needs the next measurement.
            # The first n_steps steps are those of simulate(n_runs, n_steps, rng).
            traj = self.truth.simulate(n_runs, self.n_steps + 1, rng=rng)
        if traj.z.shape[1] < self.n_steps or traj.z.shape[2] != self.nz:
            raise ValueError(f"traj.z must have shape (M, >= {self.n_steps}, {self.nz}), got {traj.z.shape}")
        self.traj, self.stream = traj, stream
        self._zs = np.ascontiguousarray(np.moveaxis(traj.z, 0, -1))  # (T, nz, M)
        self._t = 0
        self._m, self._P = self.filt.initial(traj.z.shape[0])
        self._z_t = self._zs[0]
        return self._new_decision()

    def check_actions(self, actions) -> np.ndarray:
        """Grid indices as an int array ``(M,)``; ValueError naming what is wrong."""
        return grid_actions(actions, self._m.shape[1], self.grid.size)

    def step(self, actions, predict_param: float | None = None) -> tuple[Decision | None, np.ndarray | None, bool, dict]:
        """Update with ``grid[actions]``, pay the cost, predict to the next step.

        Returns ``(decision, cost, done, info)``; ``info`` holds the update's
        ``x_filt (M, nx)``, ``P_filt (M, nx, nx)``, ``nis``, ``loglik``,
        ``theta``, ``t``, ``extra_spent`` (what the decision computed
        beyond the chosen update, see :class:`Decision`), ``update`` (the
        update's quantities a :class:`Cost` reads) and ``repaired``
        (bool ``(M,)``: runs whose covariance the filter repaired in this step,
        ``on_indefinite="clip"``; what a learner may be charged for).
        ``predict_param`` replaces the filter's default in the following predict
        step (a "fixed in both steps" policy); the paper adapts the update only.

        After the last step ``decision`` is None and ``done`` True. The horizon
        is a time limit, not a terminal state (Gymnasium: ``terminated`` False,
        ``truncated`` True, both in ``info``): when the trajectory has a
        measurement beyond the horizon (``reset`` simulates one),
        ``info["final_decision"]`` is the next information state, predicted as
        any other, for a learner to bootstrap from; otherwise it is None.
        """
        if self._decision is None:
            raise RuntimeError("call reset() before step()")
        a = self.check_actions(actions)
        theta = self.grid[a]
        d, t, M = self._decision, self._t, self._m.shape[1]
        if d._cand is not None:
            idx = a * M + np.arange(M)  # the chosen candidate of each run
            cu = d._cand["update"]
            u = type(cu)(*(getattr(cu, f.name)[..., idx] for f in fields(cu)))
            cost = None if d._cand["cost"] is None else d._cand["cost"][a, np.arange(M)]
            repaired = d._cand["repaired"][a, np.arange(M)]
        else:
            u, repaired = self._logging_repairs(M, lambda: self.filt.update_rl(
                self._m, self._P, self._z_t, t, theta, rng=self.filt.rng(UPDATE, t, self.stream)))
            cost = None if self.cost is None else self._charge(u, theta, t)
        info = {"t": t, "theta": theta, "update": u, "x_filt": u.x_filt.T, "P_filt": np.moveaxis(u.P_filt, -1, 0),
                "nis": u.nis, "loglik": u.loglik, "x_pred": self._m.T, "P_pred": np.moveaxis(self._P, -1, 0),
                # the chosen candidate is the update that happens: not spent on top of it
                "extra_spent": d.extra_spent - (self.filt.rule.spent(theta) if d._cand is not None else 0.0),
                "repaired": repaired, "terminated": False, "truncated": False}
        done = t + 1 >= self.n_steps
        if done and self._zs.shape[0] <= self.n_steps:
            self._decision = None
            info.update(truncated=True, final_decision=None)
            return None, cost, True, info
        # the update's factor of P_filt (None after a repair, or for a chosen candidate): one Cholesky less
        (self._m, self._P), pred_repaired = self._logging_repairs(M, lambda: self.filt.predict_rl(
            u.x_filt, u.P_filt, t, rng=self.filt.rng(PREDICT, t, self.stream), param=predict_param, L=u.L_filt))
        info["repaired"] = repaired | pred_repaired
        self._t = t + 1
        self._z_t = self._zs[self._t]
        if done:
            info.update(truncated=True, final_decision=self._new_decision())
            self._decision = None
            return None, cost, True, info
        return self._new_decision(), cost, False, info


def rollout(env: ParamEnv, policy, traj: Trajectory | None = None, n_runs: int | None = None,
            rng=None, stream: int | None = None, keep_pred: bool = False, progress: bool = False,
            extra_costs: Sequence[StepCost] = ()) -> tuple[FilterRun, np.ndarray | None]:
    """Run ``policy`` through ``env`` for a whole episode. ``env``: a :class:`~adaptfilt.paramenv.ParamEnv`
    that filters (its step reports :data:`~adaptfilt.paramenv.FILTER_INFO`): a :class:`FilterEnv`, a
    :class:`~adaptfilt.particle_env.ParticleCountEnv`.

    Returns the filter run (moments, NIS, log-likelihood, parameters chosen)
    and the cost ``(M, T)`` (None when the env has no cost). ``extra_costs``:
    other costs to charge the same steps, ``run.info["extra_costs"]`` (one
    ``(M, T)`` array each): what the episode would cost in environments that
    differ from ``env`` in their cost only.

    Compute, per run and averaged over steps, in the rule's ``compute_unit``
    (SIF iterations, UKF updates): ``run.info["extra_spent"] (M,)``, what the
    policy computed to decide (features, candidates), and
    ``run.info["spent"] (M,)``, that plus the update that happened.
    ``run.n_repairs``: the run-steps in which the filter that ran repaired a
    covariance (``info["repaired"]``; repairs made only to decide are not counted).
    """
    d = env.reset(n_runs=n_runs, rng=rng, traj=traj, stream=stream)
    M, T, nx = d.n_runs, env.n_steps, env.nx
    # Time-major buffers: each step writes one contiguous block (a run-major
    # (M, T, ...) buffer would be written with a stride of T elements).
    mean, cov = np.empty((T, M, nx)), np.empty((T, M, nx, nx))
    nis, ll, params = np.empty((T, M)), np.empty((T, M)), np.empty((T, M))
    costs = np.empty((T, M)) if env.cost is not None else None
    xp = np.empty((T, M, nx)) if keep_pred else None
    Pp = np.empty((T, M, nx, nx)) if keep_pred else None
    steps = range(T)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(steps, desc=getattr(policy, "name", "policy"), leave=False)
    predict_param = getattr(policy, "predict_param", None)  # a policy fixed in both steps
    extra_spent, spent, n_repairs = np.zeros(M), np.zeros(M), 0
    extra = [np.empty((T, M)) for _ in extra_costs]
    for t in steps:
        d, c, done, info = env.step(policy.act(d), predict_param=predict_param)
        extra_spent += info["extra_spent"]
        spent += env.spent(info["theta"])
        n_repairs += int(np.count_nonzero(info["repaired"]))
        for buf, cost_fn in zip(extra, extra_costs):
            buf[t] = cost_fn(info["update"], info["theta"], env.nz)
        mean[t], cov[t], nis[t], ll[t], params[t] = (
            info["x_filt"], info["P_filt"], info["nis"], info["loglik"], info["theta"])
        if costs is not None:
            costs[t] = c
        if keep_pred:
            xp[t], Pp[t] = info["x_pred"], info["P_pred"]
    tr = lambda a: None if a is None else np.swapaxes(a, 0, 1)  # public (M, T, ...) views
    return FilterRun(mean=tr(mean), cov=tr(cov), nis=tr(nis), loglik=tr(ll), params=tr(params),
                     x_pred=tr(xp), P_pred=tr(Pp), n_repairs=n_repairs,
                     info={**getattr(env, "run_info", {}), "extra_spent": extra_spent / T, "spent": (spent + extra_spent) / T,
                           "extra_costs": [tr(b) for b in extra]}), tr(costs)


def run_policy(filt: GaussianAssumedFilter, z: np.ndarray, policy, keep_pred: bool = False, progress: bool = False) -> FilterRun:
    """Filter measurements ``z (M, T, nz)`` with the update parameter chosen
    by ``policy`` (which carries its ``grid``); used by ``filt.run(z, policy=...)``."""
    grid = getattr(policy, "grid", None)
    if grid is None:
        raise ValueError("the policy has no parameter grid (policy.grid)")
    env = FilterEnv(filt, grid, cost=None, n_steps=z.shape[1])
    traj = Trajectory(x=np.full(z.shape[:2] + (filt.model.nx,), np.nan), z=z)
    run, _ = rollout(env, policy, traj=traj, keep_pred=keep_pred, progress=progress)
    return run


GaussianAssumedFilter.policy_runner = staticmethod(run_policy)
