"""adaptfilt: learning adaptive parameter policies for nonlinear Bayesian filters.

A reference implementation of Straka, Giraldo-Grueso and Zanetti, "Learning
Adaptive Parameter Policies for Nonlinear Bayesian Filtering": Gaussian-assumed
filters (UKF, SIF) whose update parameter is chosen at every step by a policy
trained with a TD(0) actor-critic.

This face exports the library only. The reproduction pipeline (``adaptfilt.experiments``) and the
course (``adaptfilt.course``) are imported by their own names; the layers and their rule are in
``docs/ARCHITECTURE.md`` (checked by ``tests/test_layers.py``).

>>> import numpy as np, adaptfilt as af
>>> model = af.models.ungm()
>>> traj = model.simulate(n_runs=100, rng=np.random.default_rng(0))
>>> run = af.UKF(model).run(traj.z)
>>> af.metrics.rmse(traj.x, run.mean).shape
(500,)
"""
import importlib as _importlib

from adaptfilt import (costs, evaluation, experiment_registry, filters, linalg, lookahead, mdp, metrics, models,
                       paramenv, policies, rules, seed_stats)
from adaptfilt._version import __version__
from adaptfilt.exact import BootstrapParticleFilter, KalmanFilter, PointMassFilter
from adaptfilt.filters import Filter, FilterRun, check_filter
from adaptfilt.gaf import CKF, SIF, UKF, FilterError, GaussianAssumedFilter, Prediction, Update
from adaptfilt.models import StateSpaceModel, Trajectory


# Modules that pull in torch or matplotlib load on first use: `import adaptfilt`
# stays fast for filtering alone.
# The course (adaptfilt.course) and the pipeline (adaptfilt.experiments) are imported by their own names.
_LAZY = ("plots", "learned", "actor_critic", "toy", "style", "gym", "trainers", "features", "anchor", "distill", "files",
         "kalmannet")


def __getattr__(name: str):
    if name in _LAZY:
        return _importlib.import_module(f"adaptfilt.{name}")
    raise AttributeError(f"module 'adaptfilt' has no attribute {name!r}")

__all__ = [
    "linalg", "metrics", "models", "rules", "costs", "filters", "paramenv", "mdp", "policies", "lookahead",
    "experiment_registry", "seed_stats", "evaluation",
    "StateSpaceModel", "Trajectory",
    "GaussianAssumedFilter", "UKF", "SIF", "CKF", "Filter", "FilterRun", "check_filter", "FilterError", "Prediction", "Update",
    "KalmanFilter", "PointMassFilter", "BootstrapParticleFilter",
    "__version__",
]
