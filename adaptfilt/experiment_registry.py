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

The paper does not give its discrete grids; these are ours, chosen with the
fixed-parameter sweeps (``notebooks/04``, update-step parameter only, predict
at the default, M = 10^4, seed 0):

* **UNGM, kappa** (``n = 1``, default 2). Every kappa < 0 makes ``P_filt``
  indefinite at the second step in (nearly) every run: ``Pzz`` of the
  quadratic measurement is ``(4 m^2 P + kappa P^2) / 400 + R``, too small for
  kappa < 0. Time-averaged RMSE falls from 6.86 (kappa = 2) to a minimum of
  about 3.07 near kappa = 100-300 and rises again (3.23 at 1000, 3.57 at 10^4);
  ANEES keeps falling as kappa grows because the gain ``K ~ 1/kappa`` switches
  the update off. The grid is log-spaced from 0 to 10^4 so that the best fixed
  RMSE value is interior.
* **CTM, kappa** (``n = 4``, default 0). With Julier's standard form,
  kappa <= -2 (centre weight ``kappa / (4 + kappa) <= -1``) loses
  definiteness of ``Pzz`` in some runs; the UKF of the CTM experiment uses the
  *modified* form where the centre weight is negative (``form="auto"``:
  covariances about the centre point, positive semi-definite for any kappa,
  identical to the standard form for kappa >= 0), so the grid reaches down to
  -3 (``n + kappa > 0`` requires kappa > -4). From -1 to 2 RMSE and ANEES
  change by about 1 %, above 5 both degrade monotonically. The grid spans
  -3 .. 50. (The first reproduction used the standard form and -1 .. 50.)
* **SIF, n_iter** (default 10): 1 .. 30 iterations; with the ``n_iter/50``
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
from typing import Callable

import numpy as np

from adaptfilt.gaf import SIF, UKF, GaussianAssumedFilter
from adaptfilt.mdp import Cost, FilterEnv
from adaptfilt.models import StateSpaceModel, coordinated_turn, ungm
from adaptfilt.particle_env import PARTICLE_GRID, ESSTargetPolicy, KLDSamplingPolicy, ParticleCost, ParticleCountEnv
from adaptfilt.policies import FixedPolicy, GreedyPolicy, MaxLikelihoodPolicy, default_policy

__all__ = ["Experiment", "EXPERIMENTS", "VARIANTS", "PARTICLE_EXPERIMENTS", "SIF_FORMS", "get_experiment",
           "describe_experiments", "UNGM_KAPPA_GRID", "CTM_KAPPA_GRID", "SIF_ITER_GRID", "PARTICLE_PRICES",
           "ESS_TARGETS", "KLD_BIN_SCALES", "SIF_EXPERIMENTS"]

UNGM_KAPPA_GRID = (0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 3000.0, 10000.0)
CTM_KAPPA_GRID = (-3.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
SIF_ITER_GRID = (1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0)


@dataclass(frozen=True)
class Experiment:
    """A named experiment: model, filter, grid, cost and horizon.

    ``make_filter(seed)`` builds the filter (predict step and default at the
    rule's default parameter), ``make_env(seed)`` the MDP environment and
    ``baselines()`` the baseline policies in a fixed order.
    """

    name: str
    description: str
    model_factory: Callable[[], StateSpaceModel]
    filter_kind: str  # "ukf", "sif" or "pf" (a particle filter whose count is the parameter)
    grid: tuple[float, ...]
    cost: "Cost | ParticleCost"
    ml_baseline: bool = True
    extra: dict = field(default_factory=dict)
    #: the information state learned policies see by default (:mod:`adaptfilt.features`): the paper's
    #: plus the model's phase on UNGM (its dynamics depend on k) and the bearing as (sin, cos) on the CTM
    features: str = "paper"
    #: keyword options of the filter (``UKF(form=...)``, ``SIF(integration_error=...)`` ...)
    filter_options: dict = field(default_factory=dict)

    @property
    def param_name(self) -> str:
        return {"ukf": "kappa", "sif": "n_iter", "pf": "n_particles"}[self.filter_kind]

    def make_model(self) -> StateSpaceModel:
        return self.model_factory()

    def make_filter(self, seed: int = 0, model: StateSpaceModel | None = None) -> GaussianAssumedFilter:
        model = self.make_model() if model is None else model
        if self.filter_kind == "pf":
            return self.make_env(seed, model=model).filt
        if self.filter_kind == "ukf":
            return UKF(model, on_indefinite="clip", **self.filter_options)
        return SIF(model, seed=seed, on_indefinite="clip", **self.filter_options)

    def make_env(self, seed: int = 0, n_steps: int | None = None,
                 model: StateSpaceModel | None = None) -> "FilterEnv | ParticleCountEnv":
        if self.filter_kind == "pf":
            return ParticleCountEnv(self.make_model() if model is None else model, self.cost, self.grid,
                                    default=self.extra["default"], seed=seed, n_steps=n_steps)
        return FilterEnv(self.make_filter(seed, model), self.grid, cost=self.cost, n_steps=n_steps)

    @property
    def default_value(self) -> float:
        return self.extra["default"] if self.filter_kind == "pf" else self.make_filter().param

    def baselines(self, fixed: bool = True) -> list:
        """``default``, every fixed grid value, ``ml`` (UKF only: for the SIF
        the likelihood-optimal choice is always the most iterations) and ``greedy``.

        Where the dynamics are nonlinear (UNGM; the CTM's are linear, so its
        predict step does not use the parameter) every fixed value comes twice:
        in the update only (``fixed-kappa=v``, the paper's convention for
        adaptation) and in both steps (``fixed-both-kappa=v``, a UKF with one
        constant kappa)."""
        grid = np.asarray(self.grid)
        if self.filter_kind == "pf":
            return self._particle_baselines(grid, fixed)
        pols = [default_policy(self.default_value, grid=grid)]
        if fixed:
            pols += [FixedPolicy(v, self.param_name, grid=grid) for v in self.grid]
            if self.make_model().F is None:
                pols += [FixedPolicy(v, self.param_name, grid=grid, both_steps=True) for v in self.grid]
        if self.ml_baseline:
            pols.append(MaxLikelihoodPolicy(grid=grid))
        pols.append(GreedyPolicy(grid=grid))
        return pols

    def _particle_baselines(self, grid: np.ndarray, fixed: bool) -> list:
        """``default``, every fixed count, KLD-sampling with bins of :data:`KLD_BIN_SCALES` times the process
        noise's standard deviation (``kld-x<k>``), the ESS targets and greedy."""
        pols = [default_policy(self.default_value, grid=grid)]
        if fixed:
            pols += [FixedPolicy(v, self.param_name, grid=grid) for v in self.grid]
        for k in KLD_BIN_SCALES:
            pols.append(KLDSamplingPolicy(k * np.asarray(self.extra["noise_std"]), grid=grid, name=f"kld-x{k}"))
        pols += [ESSTargetPolicy(t, grid=grid) for t in ESS_TARGETS]
        pols.append(GreedyPolicy(grid=grid))
        return pols


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
        Experiment("ungm-ukf", "UKF kappa on UNGM, NIS cost (Figs 1-3)", ungm, "ukf", UNGM_KAPPA_GRID, Cost("nis"),
                   features="paper+time"),
        Experiment("ctm-ukf", "UKF kappa on bearing-only CTM, NIS cost (Figs 4-6)", coordinated_turn, "ukf",
                   CTM_KAPPA_GRID, Cost("nis"), features="paper+circ", filter_options={"form": "auto"}),
        Experiment("ctm-sif-stateinnov", "SIF n_iter on CTM, ||K innov|| + n_iter/50 (Table I)", coordinated_turn,
                   "sif", SIF_ITER_GRID, Cost("stateinnov", 1 / 50), ml_baseline=False, features=_SIF_FEATURES,
                   filter_options=_SIF_OPTIONS),
        Experiment("ctm-sif-logmaxnis", "SIF n_iter on CTM, log(1+max(0,NIS-nz)) + n_iter/50 (Table I)",
                   coordinated_turn, "sif", SIF_ITER_GRID, Cost("logmaxnis", 1 / 50), ml_baseline=False,
                   features=_SIF_FEATURES, filter_options=_SIF_OPTIONS),
        Experiment("ctm-sif-nis", "SIF n_iter on CTM, (NIS-nz)^2 + n_iter/50 (Table I)", coordinated_turn, "sif",
                   SIF_ITER_GRID, Cost("nis", 1 / 50), ml_baseline=False, features=_SIF_FEATURES,
                   filter_options=_SIF_OPTIONS),
    ]
}

#: The three SIF experiments of Table I (one filter, three costs), in the paper's column order.
SIF_EXPERIMENTS: tuple[str, ...] = tuple(e.name for e in EXPERIMENTS.values() if e.filter_kind == "sif")


#: Variants of the paper's experiments, by name, for comparison (``adaptfilt evaluate/train`` take them;
#: ``adaptfilt reproduce`` runs :data:`EXPERIMENTS` only): the SIF experiments on the one-pass SIF.
VARIANTS: dict[str, Experiment] = {
    f"{e.name}-onepass": replace(e, name=f"{e.name}-onepass", filter_options=SIF_FORMS["one-pass"],
                                 description=e.description + "; one-pass SIF (the experiments' form until 2026-11-25)")
    for e in EXPERIMENTS.values() if e.filter_kind == "sif"
}


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
        f"{m}-pf-{p}", f"particle count on {label}, ||x_filt - x||^2 + {p} N (beyond the paper)", factory, "pf",
        tuple(float(g) for g in PARTICLE_GRID), ParticleCost("sqerr", float(p)), ml_baseline=False,
        extra={"default": 1000, "noise_std": tuple(float(v) for v in np.sqrt(np.diag(factory().Q)))})
    for m, label, factory in (("ungm", "UNGM (100 steps)", _ungm_short), ("ctm", "the bearing-only CTM", coordinated_turn))
    for p in PARTICLE_PRICES[m]
}


def get_experiment(name: str) -> Experiment:
    """The experiment (or variant) called ``name``; ``KeyError`` listing the known names otherwise."""
    for table in (EXPERIMENTS, VARIANTS, PARTICLE_EXPERIMENTS):
        if name in table:
            return table[name]
    raise KeyError(f"unknown experiment {name!r}; known: {', '.join([*EXPERIMENTS, *VARIANTS, *PARTICLE_EXPERIMENTS])}")


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
