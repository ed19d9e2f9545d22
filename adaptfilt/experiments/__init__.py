"""The experiment pipeline, one job per module.

* :mod:`~adaptfilt.experiments.registry` -- the paper's experiments by name
  (``adaptfilt experiments``): model, filter, grid, cost, baselines;
* :mod:`~adaptfilt.experiments.seeds` -- results over training seeds: IQM and
  mean with bootstrap intervals over seeds and Monte-Carlo runs;
* :mod:`~adaptfilt.experiments.sweep` -- independent jobs (seeds x experiments
  x gamma, evaluations) on a local process pool or a Dask cluster.

``from adaptfilt.experiments import get_experiment`` keeps working: the
registry's names are re-exported here.
"""
from adaptfilt.experiments.registry import (CTM_KAPPA_GRID, EXPERIMENTS, SIF_FORMS, SIF_ITER_GRID, UNGM_KAPPA_GRID,
                                            VARIANTS, Experiment, describe_experiments, get_experiment)

__all__ = ["Experiment", "EXPERIMENTS", "VARIANTS", "SIF_FORMS", "get_experiment", "describe_experiments",
           "UNGM_KAPPA_GRID", "CTM_KAPPA_GRID", "SIF_ITER_GRID"]
