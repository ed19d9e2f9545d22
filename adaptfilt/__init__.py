"""adaptfilt: learning adaptive parameter policies for nonlinear Bayesian filters.

A reference implementation of Straka, Giraldo-Grueso and Zanetti, "Learning
Adaptive Parameter Policies for Nonlinear Bayesian Filtering": Gaussian-assumed
filters (UKF, SIF) whose update parameter is chosen at every step by a policy
trained with a TD(0) actor-critic.

>>> import numpy as np, adaptfilt as af
>>> model = af.models.ungm()
>>> traj = model.simulate(n_runs=100, rng=np.random.default_rng(0))
>>> run = af.UKF(model).run(traj.z)
>>> af.metrics.rmse(traj.x, run.mean).shape
(500,)
"""
from adaptfilt import linalg, metrics, models, rules
from adaptfilt.exact import KalmanFilter, PointMassFilter
from adaptfilt.gaf import CKF, SIF, UKF, FilterError, FilterRun, GaussianAssumedFilter, Prediction, Update
from adaptfilt.models import StateSpaceModel, Trajectory

__version__ = "0.1.0"

__all__ = [
    "linalg", "metrics", "models", "rules",
    "StateSpaceModel", "Trajectory",
    "GaussianAssumedFilter", "UKF", "SIF", "CKF", "FilterRun", "FilterError", "Prediction", "Update",
    "KalmanFilter", "PointMassFilter",
    "__version__",
]
