r"""The paper's experiments by name (``adaptfilt experiments``).

=====================  ======  =====  ===============================  ==========================
name                   model   rule   cost                             grid
=====================  ======  =====  ===============================  ==========================
``ungm-ukf``           UNGM    UKF    ``L_NIS``                        kappa in UNGM_KAPPA_GRID
``ctm-ukf``            CTM     UKF    ``L_NIS``                        kappa in CTM_KAPPA_GRID
``ctm-sif-stateinnov``  CTM    SIF    ``L_stateInnov + n_iter/50``     n_iter in SIF_ITER_GRID
``ctm-sif-logmaxnis``  CTM     SIF    ``L_logmaxNIS + n_iter/50``      n_iter in SIF_ITER_GRID
``ctm-sif-nis``        CTM     SIF    ``L_NIS + n_iter/50``            n_iter in SIF_ITER_GRID
=====================  ======  =====  ===============================  ==========================

The paper does not give its discrete grids; these are ours. The UKF grids
are chosen with the fixed-kappa sweeps of chapter 4 (``notebooks/04``,
"Choosing the grid": update-step parameter only, predict at the default,
M = 2000 runs, seed 0):

* **UNGM, kappa** (``n = 1``, default 2). Every kappa < 0 makes ``P_filt``
  indefinite at the second step in (nearly) every run: ``Pzz`` of the
  quadratic measurement is ``(4 m^2 P + kappa P^2) / 400 + R``, too small for
  kappa < 0. Time-averaged RMSE falls from 6.82 (kappa = 2) to a flat minimum
  of 3.06 at kappa = 200 (3.07 at 100) and rises again beyond (3.67 at
  10^5); ANEES keeps falling as kappa grows because the gain ``K ~ 1/kappa``
  switches the update off. The grid is log-spaced from 0 to 10^4 so that the
  best fixed RMSE value is interior.
* **CTM, kappa** (``n = 4``, default 0). With Julier's standard form,
  kappa <= -1.5 (centre weight ``kappa / (4 + kappa) <= -0.6``) loses
  definiteness of the filtering covariance in some runs (chapter 4's 1000
  runs stop with that error at -1.5 already); the UKF of the CTM experiment uses the
  *modified* form where the centre weight is negative (``form="auto"``:
  covariances about the centre point, positive semi-definite for any kappa,
  identical to the standard form for kappa >= 0), so the grid reaches down to
  -3 (``n + kappa > 0`` requires kappa > -4). From -1 to 2 RMSE and ANEES
  change by a few percent (RMSE 39.6-40.9, ANEES 8.01-8.42); above 5 both
  rise steeply. The grid spans -3 .. 50. (The first reproduction used the
  standard form and -1 .. 50.)
* **SIF, n_iter** (default 10): 1 .. 30 iterations, not from a chapter-4
  sweep (chapter 11 evaluates every count of the grid); with the ``n_iter/50``
  term a low weight favours many iterations, a high weight few. The SIF is
  the form of the authors' Stone Soup port that ``tests/test_sif_reference.py``
  checks draw for draw (:data:`SIF_FORMS` ``"reference"``): degree 3, a fixed
  count (the policy chooses it), **two passes** (the mean from its own draws,
  then ``Pzz`` and ``Pxz`` about it from fresh draws), and the estimated
  variance of the averaged mean added to ``P_pred`` and ``Pzz``
  (``integration_error="diag"``): without that term a SIF with 2-5
  iterations is grossly overconfident on the CTM (ANEES in the thousands at
  n_iter = 5 against 6 with it). One iteration is one draw of each pass; the
  cost term ``n_iter / 50`` counts iterations. Until 2026-11-25 the
  experiments ran the *one-pass* form (covariances from the mean's own
  draws), which diverges far more often at one or two iterations; it stays
  available as the variants ``<name>-onepass`` (:data:`VARIANTS`).

Filters in the experiments use ``on_indefinite="clip"``, the documented
repair, so that one run whose covariance loses definiteness under an
exploratory parameter does not end a training or an evaluation; every
evaluation reports how many repairs happened.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Protocol

import numpy as np

from adaptfilt.costs import Cost, ParticleCost, StepCost
from adaptfilt.gaf import SIF, UKF, GaussianAssumedFilter
from adaptfilt.mdp import FilterEnv
from adaptfilt.models import StateSpaceModel, coordinated_turn, ungm
from adaptfilt.paramenv import ParamEnv, missing_members
from adaptfilt.particle_env import PARTICLE_GRID
from adaptfilt.policies import FixedPolicy, GreedyPolicy, MaxLikelihoodPolicy, default_policy

__all__ = ["Experiment", "EnvFactory", "RuleParameter", "ParticleCount", "Target", "resolve", "EXPERIMENTS",
           "VARIANTS", "PARTICLE_EXPERIMENTS", "SIF_FORMS", "get_experiment", "describe_experiments",
           "UNGM_KAPPA_GRID", "CTM_KAPPA_GRID", "SIF_ITER_GRID", "PARTICLE_PRICES", "ESS_TARGETS", "KLD_BIN_SCALES",
           "SIF_EXPERIMENTS", "scaled_truth", "parse_truth", "truth_words", "truth_model",
           "NLL_WEIGHTS"]

UNGM_KAPPA_GRID = (0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 3000.0, 10000.0)
CTM_KAPPA_GRID = (-3.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
SIF_ITER_GRID = (1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0)


class EnvFactory(Protocol):
    """A kind of parameter as an experiment uses it: it builds the experiment's environment (a
    :class:`~adaptfilt.paramenv.ParamEnv`), knows the parameter's name and default, and the baselines
    that choose it. A new kind of parameter is a new environment and one of these.

    ``make_env`` builds the variants too: ``truth``, the model trajectories are simulated from when the world
    differs from the filter's model (out of distribution); ``grid``, a subset of the experiment's grid (a
    safe action set), already checked by :meth:`Experiment.make_env`; both are passed (as keywords) only for
    a variant, so a factory that builds none takes the first four arguments alone. A variant carries the
    experiment's name (``env.experiment``): a policy trained on it is still "for" the experiment."""

    param_name: str

    def make_env(self, exp: "Experiment", seed: int, n_steps: int | None, model: StateSpaceModel | None,
                 truth: StateSpaceModel | None = None, grid: np.ndarray | None = None) -> ParamEnv: ...

    def default_value(self, exp: "Experiment") -> float: ...

    def baselines(self, exp: "Experiment", grid: np.ndarray, fixed: bool) -> list: ...


@dataclass(frozen=True)
class RuleParameter:
    """The moment rule's parameter of a Gaussian-assumed filter (``filter_class``: :class:`~adaptfilt.gaf.UKF`
    kappa, :class:`~adaptfilt.gaf.SIF` iterations), in a :class:`~adaptfilt.mdp.FilterEnv`. ``seeded``:
    the filter draws random numbers (keyed by the environment's seed)."""

    filter_class: type
    param_name: str
    seeded: bool = False

    def make_filter(self, exp: "Experiment", seed: int = 0, model: StateSpaceModel | None = None) -> GaussianAssumedFilter:
        model = exp.make_model() if model is None else model
        seeds = {"seed": seed} if self.seeded else {}
        return self.filter_class(model, **seeds, on_indefinite="clip", **exp.filter_options)

    def make_env(self, exp: "Experiment", seed: int, n_steps: int | None, model: StateSpaceModel | None,
                 truth: StateSpaceModel | None = None, grid: np.ndarray | None = None) -> FilterEnv:
        variant = truth is not None or grid is not None
        return FilterEnv(self.make_filter(exp, seed, model), exp.grid if grid is None else grid, cost=exp.cost,
                         n_steps=n_steps, truth=truth, experiment=exp.name if variant else None)

    def default_value(self, exp: "Experiment") -> float:
        return self.make_filter(exp).param

    def baselines(self, exp: "Experiment", grid: np.ndarray, fixed: bool) -> list:
        pols = [default_policy(self.default_value(exp), grid=grid)]
        if fixed:
            pols += [FixedPolicy(v, self.param_name, grid=grid) for v in exp.grid]
            if exp.make_model().F is None:
                pols += [FixedPolicy(v, self.param_name, grid=grid, both_steps=True) for v in exp.grid]
        if exp.ml_baseline:
            pols.append(MaxLikelihoodPolicy(grid=grid))
        pols.append(GreedyPolicy(grid=grid))
        return pols


@dataclass(frozen=True)
class ParticleCount:
    """The particle count per step (:class:`~adaptfilt.particle_env.ParticleCountEnv`), ``default``
    particles for the "default" policy; ``noise_std``: the process noise's standard deviation per state
    dimension (the unit of KLD-sampling's bins)."""

    default: int
    noise_std: tuple[float, ...]
    param_name: str = "n_particles"

    def make_env(self, exp: "Experiment", seed: int, n_steps: int | None, model: StateSpaceModel | None,
                 truth: StateSpaceModel | None = None, grid: np.ndarray | None = None) -> ParamEnv:
        # here, not at the top: `import adaptfilt` loads no particle filter
        from adaptfilt.particle_env import ParticleCountEnv

        variant = truth is not None or grid is not None
        return ParticleCountEnv(exp.make_model() if model is None else model, exp.cost,
                                exp.grid if grid is None else grid, default=self.default, seed=seed, n_steps=n_steps,
                                truth=truth, experiment=exp.name if variant else None)

    def default_value(self, exp: "Experiment") -> float:
        return self.default

    def baselines(self, exp: "Experiment", grid: np.ndarray, fixed: bool) -> list:
        """``default``, every fixed count, KLD-sampling with bins of :data:`KLD_BIN_SCALES` times the process
        noise's standard deviation (``kld-x<k>``), the ESS targets and greedy."""
        from adaptfilt.particle_env import ESSTargetPolicy, KLDSamplingPolicy

        pols = [default_policy(self.default, grid=grid)]
        if fixed:
            pols += [FixedPolicy(v, self.param_name, grid=grid) for v in exp.grid]
        for k in KLD_BIN_SCALES:
            pols.append(KLDSamplingPolicy(k * np.asarray(self.noise_std), grid=grid, name=f"kld-x{k}"))
        pols += [ESSTargetPolicy(t, grid=grid) for t in ESS_TARGETS]
        pols.append(GreedyPolicy(grid=grid))
        return pols


@dataclass(frozen=True)
class Experiment:
    """A named experiment: model, kind of parameter (the environment's factory), grid, cost and horizon.

    ``make_env(seed)`` builds the MDP environment (through ``envs``, an :class:`EnvFactory`),
    ``make_filter(seed)`` a Gaussian-assumed filter's experiment's filter (predict step and default at
    the rule's default parameter) and ``baselines()`` the baseline policies in a fixed order.
    """

    name: str
    description: str
    model_factory: Callable[[], StateSpaceModel]
    #: the kind of parameter: builds the environment, knows the default and the baselines
    envs: EnvFactory
    grid: tuple[float, ...]
    cost: StepCost
    ml_baseline: bool = True
    #: the information state learned policies see by default (:mod:`adaptfilt.features`): the paper's
    #: plus the model's phase on UNGM (its dynamics depend on k) and the bearing as (sin, cos) on the CTM
    features: str = "paper"
    #: keyword options of the filter (``UKF(form=...)``, ``SIF(integration_error=...)`` ...)
    filter_options: dict = field(default_factory=dict)

    @property
    def param_name(self) -> str:
        return self.envs.param_name

    def make_model(self) -> StateSpaceModel:
        return self.model_factory()

    def make_filter(self, seed: int = 0, model: StateSpaceModel | None = None) -> GaussianAssumedFilter:
        if not isinstance(self.envs, RuleParameter):
            raise TypeError(f"{self.name}'s parameter ({self.param_name}) is not a moment rule's: its environment "
                            "owns its filter (make_env)")
        return self.envs.make_filter(self, seed, model)

    def make_env(self, seed: int = 0, n_steps: int | None = None, model: StateSpaceModel | None = None,
                 truth: StateSpaceModel | None = None, grid=None) -> ParamEnv:
        """The experiment's environment (:class:`EnvFactory`): its filter on ``model`` (default: the
        experiment's), horizon ``n_steps`` (default: the model's); a variant where ``truth`` (a model of the same
        dimensions, e.g. :func:`scaled_truth`) simulates the trajectories, or where the policy chooses among
        ``grid``, values of the experiment's grid (ValueError naming those that are not)."""
        if truth is None and grid is None:
            return self.envs.make_env(self, seed, n_steps, model)
        return self.envs.make_env(self, seed, n_steps, model, truth=truth,
                                  grid=None if grid is None else self.subgrid(grid))

    def subgrid(self, values) -> np.ndarray:
        """``values`` as a grid: sorted, each a value of the experiment's grid (ValueError naming those that
        are not)."""
        a = np.asarray(values, dtype=float).ravel()
        full = np.asarray(self.grid, dtype=float)
        off = [v for v in a if not np.isclose(v, full).any()]
        if a.size == 0 or off:
            raise ValueError(f"actions must be values of the {self.name} grid {full.tolist()}; not on it: "
                             f"{[float(v) for v in off] or 'none given'}")
        return np.unique(a)

    @property
    def default_value(self) -> float:
        return self.envs.default_value(self)

    def baselines(self, fixed: bool = True, kinds: tuple[str, ...] | None = None) -> list:
        """``default``, every fixed grid value, ``ml`` (UKF only: for the SIF
        the likelihood-optimal choice is always the most iterations) and ``greedy``;
        ``kinds``: only those of these kinds (each baseline's ``kind``: ``"default"``, ``"fixed"``,
        ``"fixed-both"``, ``"ml"``, ``"greedy"``; the particle count's ``"kld"``, ``"ess"``).

        Where the dynamics are nonlinear (UNGM; the CTM's are linear, so its
        predict step does not use the parameter) every fixed value comes twice:
        in the update only (``fixed-kappa=v``, the paper's convention for
        adaptation) and in both steps (``fixed-both-kappa=v``, a UKF with one
        constant kappa). The particle count's: :meth:`ParticleCount.baselines`."""
        pols = self.envs.baselines(self, np.asarray(self.grid), fixed)
        return pols if kinds is None else [p for p in pols if p.kind in kinds]


_UKF, _SIF = RuleParameter(UKF, "kappa"), RuleParameter(SIF, "n_iter", seeded=True)


#: Forms of the SIF (keyword options of :class:`~adaptfilt.gaf.SIF`): ``"reference"``, the form tested
#: against Stone Soup, runs the Table I experiments; ``"one-pass"`` ran them until 2026-11-25.
SIF_FORMS = {"reference": {"integration_error": "diag", "passes": 2},
             "one-pass": {"integration_error": "diag", "passes": 1}}
_SIF_OPTIONS = SIF_FORMS["reference"]
#: Their policies' information state: the bearing as (sin, cos), and the innovation feature from one SIF
#: iteration rather than the default's ten, every step (the information state is not free: evaluations
#: report what it costs, ``cost_charged``).
_SIF_FEATURES = "paper+circ+innov@1"

EXPERIMENTS: dict[str, Experiment] = {
    e.name: e
    for e in [
        Experiment("ungm-ukf", "UKF kappa on UNGM, NIS cost (Figs 1-3)", ungm, _UKF, UNGM_KAPPA_GRID, Cost("nis"),
                   features="paper+time"),
        Experiment("ctm-ukf", "UKF kappa on bearing-only CTM, NIS cost (Figs 4-6)", coordinated_turn, _UKF,
                   CTM_KAPPA_GRID, Cost("nis"), features="paper+circ", filter_options={"form": "auto"}),
        Experiment("ctm-sif-stateinnov", "SIF n_iter on CTM, ||K innov|| + n_iter/50 (Table I)", coordinated_turn,
                   _SIF, SIF_ITER_GRID, Cost("stateinnov", 1 / 50), ml_baseline=False, features=_SIF_FEATURES,
                   filter_options=_SIF_OPTIONS),
        Experiment("ctm-sif-logmaxnis", "SIF n_iter on CTM, log(1+max(0,NIS-nz)) + n_iter/50 (Table I)",
                   coordinated_turn, _SIF, SIF_ITER_GRID, Cost("logmaxnis", 1 / 50), ml_baseline=False,
                   features=_SIF_FEATURES, filter_options=_SIF_OPTIONS),
        Experiment("ctm-sif-nis", "SIF n_iter on CTM, (NIS-nz)^2 + n_iter/50 (Table I)", coordinated_turn, _SIF,
                   SIF_ITER_GRID, Cost("nis", 1 / 50), ml_baseline=False, features=_SIF_FEATURES,
                   filter_options=_SIF_OPTIONS),
    ]
}

#: The three SIF experiments of Table I (one filter, three costs), in the paper's column order.
SIF_EXPERIMENTS: tuple[str, ...] = tuple(e.name for e in EXPERIMENTS.values() if e.envs == _SIF)


#: Variants of the paper's experiments, by name, for comparison (``adaptfilt evaluate/train`` take them;
#: ``adaptfilt reproduce`` runs :data:`EXPERIMENTS` only): the SIF experiments on the one-pass SIF.
VARIANTS: dict[str, Experiment] = {
    f"{e.name}-onepass": replace(e, name=f"{e.name}-onepass", filter_options=SIF_FORMS["one-pass"],
                                 description=e.description + "; one-pass SIF (the experiments' form until 2026-11-25)")
    for e in EXPERIMENTS.values() if e.envs == _SIF
}

#: The kappa experiments on the squared error ``||x_{t|t} - x_t||^2`` (beyond the paper; the learned-gain
#: study, :mod:`adaptfilt.experiments.studies.gain`): grid, features and filter of ``ungm-ukf`` and
#: ``ctm-ukf``, the cost of supervised KalmanNet. A simulation-only cost (training knows the truth; the
#: policy sees its information state only); their greedy baseline reads the truth (an oracle).
SQERR_VARIANTS: dict[str, Experiment] = {
    f"{e.name}-sqerr": replace(e, name=f"{e.name}-sqerr", cost=Cost("sqerr"),
                               description=e.description.split(", NIS cost")[0] + ", ||x_filt - x||^2 cost (beyond the paper)")
    for e in EXPERIMENTS.values() if e.name in ("ungm-ukf", "ctm-ukf")
}
VARIANTS.update(SQERR_VARIANTS)

#: Weights of the consistency term the learned-gain study's consistency arm may add to the squared error
#: (:attr:`adaptfilt.costs.Cost.nll_weight`: the true state's Gaussian negative log-likelihood under the
#: filter's mean and covariance); the study chooses one on validation runs.
NLL_WEIGHTS = (0.01, 0.1, 1.0)
#: UNGM's kappa experiment on ``||x_{t|t} - x_t||^2 + w (NEES + log det P_{t|t})``, one per weight of
#: :data:`NLL_WEIGHTS` (beyond the paper: the learned-gain study's consistency arm; simulation-only, as ``sqerr``).
NLL_VARIANTS: dict[str, Experiment] = {
    f"ungm-ukf-sqerr-nll{w:g}": replace(
        SQERR_VARIANTS["ungm-ukf-sqerr"], name=f"ungm-ukf-sqerr-nll{w:g}", cost=Cost("sqerr", nll_weight=w),
        description=SQERR_VARIANTS["ungm-ukf-sqerr"].description.replace(
            "||x_filt - x||^2 cost", f"||x_filt - x||^2 + {w:g} (NEES + log det P) cost"))
    for w in NLL_WEIGHTS
}
VARIANTS.update(NLL_VARIANTS)

#: Prices per particle of the particle-count experiments (beyond the paper), per model: the default's
#: 1000 particles cost about a tenth of, and about as much as, the default's mean squared error
#: (UNGM about 1.5 over 100 steps, the CTM about 10^3). The learned count is judged at each price.
PARTICLE_PRICES = {"ungm": ("1e-4", "1e-3"), "ctm": ("0.1", "1")}
#: Effective sample sizes the ESS-target baselines keep (:class:`~adaptfilt.particle_env.ESSTargetPolicy`).
ESS_TARGETS = (50, 200, 1000)
#: KLD-sampling's bins, in multiples of the process noise's standard deviation per state dimension: a
#: family of baselines (finer bins ask for more particles), the best of which is the bar.
KLD_BIN_SCALES = (1, 4, 16, 64)


def _ungm_short() -> StateSpaceModel:
    return ungm(n_steps=100)


#: The particle count as the parameter (beyond the paper; :mod:`adaptfilt.particle_env`): UNGM (100 steps
#: of the paper's 500, so that a policy trains in minutes) and the CTM, the filter's squared error plus a
#: price per particle (a simulation-only cost: training knows the truth, the policy sees its information
#: state only).
PARTICLE_EXPERIMENTS: dict[str, Experiment] = {
    f"{m}-pf-{p}": Experiment(
        f"{m}-pf-{p}", f"particle count on {label}, ||x_filt - x||^2 + {p} N (beyond the paper)", factory,
        ParticleCount(1000, tuple(float(v) for v in np.sqrt(np.diag(factory().Q)))),
        tuple(float(g) for g in PARTICLE_GRID), ParticleCost("sqerr", float(p)), ml_baseline=False)
    for m, label, factory in (("ungm", "UNGM (100 steps)", _ungm_short), ("ctm", "the bearing-only CTM", coordinated_turn))
    for p in PARTICLE_PRICES[m]
}


def scaled_truth(model: StateSpaceModel, q: float = 1.0, r: float = 1.0) -> StateSpaceModel:
    """``model`` with its process noise ``Q`` scaled by ``q`` and its measurement noise ``R`` by ``r`` (the same
    functions, prior and horizon): a truth that differs from the model a filter keeps.

    >>> scaled_truth(ungm(), q=4).Q.tolist(), scaled_truth(ungm(), q=4).description
    ([[4.0]], 'ungm, Q x4, R x1')
    """
    return replace(model, Q=model.Q * q, R=model.R * r, description=f"{model.name}, Q x{q:g}, R x{r:g}")


def parse_truth(text: str) -> dict[str, float]:
    """The keyword arguments of :func:`truth_model` written as ``q=4``, ``q=1,r=0.25`` or ``forcing=10`` (what
    ``adaptfilt train-gain --truth`` and ``adaptfilt train --truth`` take): ``q`` and ``r`` scale the noise
    covariances, ``forcing`` is UNGM's forcing amplitude (a truth whose dynamics differ); ValueError naming what
    is wrong.

    >>> parse_truth("q=4"), truth_words(**parse_truth("r=0.5,q=2")), truth_words(**parse_truth("forcing=10"))
    ({'q': 4.0, 'r': 1.0}, 'q=2,r=0.5', 'q=1,r=1,forcing=10')
    """
    out = {"q": 1.0, "r": 1.0}
    for part in str(text).split(","):
        key, eq, value = part.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = float("nan")
        key = key.strip()
        ok = 0 < v < float("inf") if key in ("q", "r") else key == "forcing" and abs(v) < float("inf")
        if not eq or not ok:
            raise ValueError(f"a truth is written q=FACTOR,r=FACTOR (scales of the noise covariances Q and R, "
                             f"finite and > 0) and, on UNGM, forcing=AMPLITUDE (finite), e.g. q=4; got {text!r}")
        out[key] = v
    return out


def truth_words(q: float = 1.0, r: float = 1.0, forcing: float | None = None) -> str:
    """The one written form of a truth (:func:`parse_truth` reads it back): ``q=4,r=1``, ``q=1,r=1,forcing=10``."""
    return f"q={q:g},r={r:g}" + ("" if forcing is None else f",forcing={forcing:g}")


def truth_model(model: StateSpaceModel, text: str) -> StateSpaceModel:
    """The truth that ``text`` (:func:`parse_truth`) makes of ``model``: its noise covariances scaled
    (:func:`scaled_truth`) and, with ``forcing``, UNGM's forcing term ``forcing cos(0.05 k)`` in place of the
    model's (the same prior, noises and horizon): a truth whose dynamics differ from the model a filter keeps.
    ValueError for a forcing on another model.

    >>> truth_model(ungm(), "forcing=10,q=4").description
    'ungm, forcing 10 cos(0.05k), Q x4, R x1'
    >>> float(truth_model(ungm(), "forcing=10").f(np.zeros((1, 1)), 0)[0, 0])
    10.0
    """
    kw = parse_truth(text)
    forcing = kw.pop("forcing", None)
    if forcing is None:
        return scaled_truth(model, **kw)
    if model.name != "ungm" or model.nx != 1:
        raise ValueError(f"forcing= is UNGM's forcing amplitude; model {model.name!r} has none")
    dyn = ungm(Q=float(model.Q[0, 0]), R=float(model.R[0, 0]), P0=float(model.P0[0, 0]), n_steps=model.n_steps,
               forcing=forcing)
    t = scaled_truth(replace(model, f=dyn.f, f_torch=dyn.f_torch), **kw)
    return replace(t, description=f"{model.name}, forcing {forcing:g} cos(0.05k), Q x{kw['q']:g}, R x{kw['r']:g}")


def get_experiment(name: str) -> Experiment:
    """The experiment (or variant) called ``name``; ``KeyError`` listing the known names otherwise."""
    for table in (EXPERIMENTS, VARIANTS, PARTICLE_EXPERIMENTS):
        if name in table:
            return table[name]
    raise KeyError(f"unknown experiment {name!r}; known: {', '.join([*EXPERIMENTS, *VARIANTS, *PARTICLE_EXPERIMENTS])}")


@dataclass(frozen=True)
class Target:
    """What a name, an :class:`Experiment` or an environment of one's own resolves to (:func:`resolve`):
    the environment, the experiment (None for an environment of one's own), its name (an environment may
    carry one: ``env.experiment``, for a policy still "for" an experiment whose grid it cuts), the feature
    set the experiment recommends (None for an environment: the caller's default) and a label for
    progress bars and messages."""

    env: ParamEnv
    experiment: Experiment | None
    name: str | None
    features: str | None

    @property
    def label(self) -> str:
        return self.name or getattr(getattr(self.env, "model", None), "name", None) or "env"


def resolve(target: Any, seed: int = 0, n_steps: int | None = None) -> Target:
    """The one reading of "a name, an :class:`Experiment` or an environment" that every entry point
    (evaluation, the trainers, the Gymnasium wrapper, policy files, distillation) uses.

    A name is looked up (:func:`get_experiment`, KeyError listing the known names); an experiment builds
    its environment with ``seed`` and ``n_steps`` (default: the model's horizon); a :class:`Target` is
    returned as it is (so that one resolved by a caller is not built again); an environment must meet
    :class:`~adaptfilt.paramenv.ParamEnv` (TypeError naming the members it lacks) and is used as it is: its
    horizon is its own, so an ``n_steps`` other than it is a ValueError.
    """
    if isinstance(target, Target):  # resolved already (a caller that passes it on): not built twice
        if n_steps is not None and n_steps != target.env.n_steps:
            raise ValueError(f"n_steps={n_steps} for a resolved target with horizon {target.env.n_steps}")
        return target
    if isinstance(target, str):
        target = get_experiment(target)
    if isinstance(target, Experiment):
        return Target(target.make_env(seed=seed, n_steps=n_steps), target, target.name, target.features)
    if not isinstance(target, ParamEnv):
        lacks = missing_members(target)
        raise TypeError(f"expected an experiment name, an Experiment or an environment (a ParamEnv such as a "
                        f"FilterEnv), got "
                        f"{type(target).__name__}" + (f", which lacks {', '.join(lacks)}" if lacks else ""))
    if n_steps is not None and n_steps != target.n_steps:
        raise ValueError(f"n_steps={n_steps} for an environment with horizon {target.n_steps}: "
                         "build the environment with the horizon you want (FilterEnv(..., n_steps=...))")
    return Target(target, None, getattr(target, "experiment", None), None)


def describe_experiments() -> str:
    """A table of the registered experiments and their variants (what ``adaptfilt experiments`` prints)."""
    rows = [f"{'name':<20} {'cost':<24} {'grid':<10} description"]
    for e in EXPERIMENTS.values():
        g = f"{e.param_name}: " + ", ".join(f"{v:g}" for v in e.grid)
        rows.append(f"{e.name:<20} {e.cost.name:<24} {e.param_name:<10} {e.description}\n{'':<20} {g}")
    rows.append("\nvariants (for comparison):")
    rows += [f"{e.name:<28} {e.description}" for e in VARIANTS.values()]
    rows.append("\nthe particle count (beyond the paper):")
    rows += [f"{e.name:<28} {e.description}" for e in PARTICLE_EXPERIMENTS.values()]
    return "\n".join(rows)
