r"""Our earlier numbers, for the "what changed" comparisons of the course (chapters 9 and 10).

Before the seed-level reproduction, ``data/`` held one training seed per learned policy,
trained by the vectorised actor-critic (50 episodes per batched update), and the experiments
differed in four ways (issue 14):

* the SIF had no integration-error term (now ``integration_error="diag"``, the authors'
  Stone Soup SIF, which adds the estimated variance of the averaged mean to ``P_pred`` and
  ``Pzz``);
* greedy's SIF candidates drew independent random numbers (now one set of draws, shared
  by the candidates through prefix averages: a fair comparison of iteration counts);
* the SIF policies saw the innovation of a default (10-iteration) update (now of one
  iteration, ``innov@1``), and Table I reported the chosen iterations only (now also those
  really spent);
* the CTM UKF used Julier's standard form and a grid from kappa = -1 (now the modified form
  where the centre weight is negative, and a grid from -3).

The values below are copied, rounded to 4 significant digits, from ``data/`` as committed
at 7f5aa11 (``results/table1.json`` and the ``results.npz`` of ``ctm-sif-nis`` and
``ctm-ukf``, all at M = 10^4 runs, seed 0); they are a record, not something the library
recomputes. Learned policies are the single seed of that release.
"""
from __future__ import annotations

__all__ = ["BEFORE_COMMIT", "TABLE1_BEFORE", "SIF_FIXED_BEFORE", "CTM_UKF_BEFORE"]

#: The commit whose ``data/`` the numbers come from.
BEFORE_COMMIT = "7f5aa11"

#: Table I before: ``{experiment: {column: {"policy", "rmse", "anees", "cost", "mean_n_iter"}}}``.
TABLE1_BEFORE = {
    "ctm-sif-stateinnov": {
        "adaptive": {"policy": "adaptive", "rmse": 36.36, "anees": 1.002e5, "cost": 4.754, "mean_n_iter": 2.0},
        "fixed": {"policy": "default", "rmse": 33.53, "anees": 5.917, "cost": 4.724, "mean_n_iter": 10.0},
        "myopic": {"policy": "myopic", "rmse": 3.873e8, "anees": 3.458e14, "cost": 6.908e4, "mean_n_iter": 1.967},
        "greedy": {"policy": "greedy", "rmse": 37.48, "anees": 2.767e5, "cost": 3.962, "mean_n_iter": 4.013},
        "best fixed (cost)": {"policy": "fixed-n_iter=5", "rmse": 34.13, "anees": 4607.0, "cost": 4.686,
                              "mean_n_iter": 5.0},
    },
    "ctm-sif-logmaxnis": {
        "adaptive": {"policy": "adaptive", "rmse": 7.836e8, "anees": 5.422e14, "cost": 0.2854, "mean_n_iter": 1.0},
        "fixed": {"policy": "default", "rmse": 33.53, "anees": 5.917, "cost": 0.4171, "mean_n_iter": 10.0},
        "myopic": {"policy": "myopic", "rmse": 7.836e8, "anees": 5.422e14, "cost": 0.2854, "mean_n_iter": 1.0},
        "greedy": {"policy": "greedy", "rmse": 34.26, "anees": 3.755e5, "cost": 0.2388, "mean_n_iter": 1.279},
        "best fixed (cost)": {"policy": "fixed-n_iter=2", "rmse": 36.36, "anees": 1.066e5, "cost": 0.2842,
                              "mean_n_iter": 2.0},
    },
    "ctm-sif-nis": {
        "adaptive": {"policy": "adaptive", "rmse": 36.36, "anees": 1.066e5, "cost": 6.497, "mean_n_iter": 2.0},
        "fixed": {"policy": "default", "rmse": 33.53, "anees": 5.917, "cost": 4.158, "mean_n_iter": 10.0},
        "myopic": {"policy": "myopic", "rmse": 36.36, "anees": 1.066e5, "cost": 6.497, "mean_n_iter": 2.0},
        "greedy": {"policy": "greedy", "rmse": 32.0, "anees": 2.335e5, "cost": 3.561, "mean_n_iter": 1.813},
        "best fixed (cost)": {"policy": "fixed-n_iter=20", "rmse": 33.17, "anees": 5.764, "cost": 4.024,
                              "mean_n_iter": 20.0},
    },
}

#: Fixed iteration counts of the SIF on CTM before (no integration-error term):
#: ``{n_iter: (RMSE, ANEES, covariance repairs)}``.
SIF_FIXED_BEFORE = {1: (7.836e8, 5.422e14, 583), 2: (36.36, 1.066e5, 68), 3: (35.09, 2.893e4, 20),
                    5: (34.13, 4607.0, 1), 7: (33.67, 578.8, 1), 10: (33.53, 5.917, 0), 15: (33.40, 5.839, 0),
                    20: (33.17, 5.764, 0), 30: (33.05, 5.713, 0)}

#: The CTM UKF before (standard form, grid -1 .. 50): the share of run-steps using each
#: kappa, per policy (single-seed learned policies, fast and paper-faithful training), and
#: RMSE / ANEES / mean NIS cost.
CTM_UKF_BEFORE = {
    "grid": (-1.0, -0.5, 0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0),
    "usage": {
        "adaptive": (0, 0, 0, 0, 0, 0.051, 0.101, 0.008, 0, 0.840),
        "myopic": (0, 0, 0, 0, 0, 0.016, 0.088, 0.003, 0, 0.893),
        "adaptive-faithful": (0, 0, 0, 0, 0, 0, 0, 0.186, 0, 0.814),
        "myopic-faithful": (0, 0, 0, 0, 0, 0, 0.077, 0, 0, 0.923),
        "greedy": (0.398, 0.005, 0.005, 0.005, 0.007, 0.018, 0.033, 0.057, 0.137, 0.336),
        "ml": (0.480, 0.006, 0.006, 0.006, 0.009, 0.027, 0.044, 0.068, 0.104, 0.249),
    },
    "metrics": {  # (RMSE, ANEES, mean NIS cost)
        "adaptive": (43.91, 17.01, 9.51), "myopic": (45.67, 17.93, 12.91), "greedy": (40.98, 12.14, 5.439),
        "ml": (42.62, 15.19, 4.804), "best fixed (RMSE): fixed-kappa=5": (40.31, 9.036, 8.074),
    },
}
