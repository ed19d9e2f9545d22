r"""KalmanNet: a filter whose Kalman gain is computed by a recurrent network.

Written from the paper (Revach, Shlezinger, Ni, López Escoriza, van Sloun, Eldar, "KalmanNet:
Neural network aided Kalman filtering for partially known dynamics", IEEE Trans. Signal Processing
70, 2022, architectures 1 and 2); no code of the authors' (unlicensed) repository is used or loaded.

The filter keeps the model's prediction and learns the gain:

.. math::
    \hat x_{t|t-1} = f(\hat x_{t-1|t-1}),\qquad \hat z_{t|t-1} = h(\hat x_{t|t-1}),\qquad
    \Delta z_t = z_t - \hat z_{t|t-1},

.. math::
    K_t = \mathrm{GainNet}(F_1, F_2, F_3, F_4;\ \text{GRU states}),\qquad
    \hat x_{t|t} = \hat x_{t|t-1} + K_t\, \Delta z_t,

with the four input features of the paper

* F1, observation difference   :math:`z_t - z_{t-1}`,
* F2, innovation               :math:`z_t - \hat z_{t|t-1}`,
* F3, forward evolution difference :math:`\hat x_{t-1|t-1} - \hat x_{t-2|t-2}`,
* F4, forward update difference    :math:`\hat x_{t-1|t-1} - \hat x_{t-1|t-2}`.

**The gain network** (``arch``, :mod:`adaptfilt.gainnets`): architecture 2 (default, :class:`GainNet`:
three GRUs Q, Sigma, S with hidden sizes ``m^2``, ``m^2``, ``n^2``, input multiplier ``in_mult = 5``,
FC2's hidden layer ``(m^2 + n^2) out_mult`` with ``out_mult = 40``, the backward flow; 472 weights for
``m = n = 1``) or architecture 1 (:class:`~adaptfilt.gainnets.GainNet1`: an input FC layer, a
2-layer GRU of ``10 (m^2 + n^2)`` units over [F1, F3, F4], an output FC layer; 14,101 weights for
``m = n = 1``). Both share this module's recursion, training and files.

Choices where the paper is silent, or where this module departs from it (all options are recorded
in saved files):

* **Time convention** of the library: the prior ``N(m0, P0)`` is the prediction of the first state,
  so at ``t = 0`` ``x_{0|-1} = m0`` with no ``f``; the missing past is ``z_{-1} = h(m0)`` and
  ``x_{-1|-1} = x_{-2|-2} = x_{-1|-2} = m0`` (F3 = F4 = 0 at the first step).
* **Input normalisation** ``feature_norm``: ``"l2"`` (default, the public code's: each feature vector
  divided by its Euclidean norm per sample; in one dimension only its sign is left),
  ``"none"`` (raw features) or ``"scale"`` (each component divided by a fixed scale: F1 and F2 by the
  standard deviation of ``z_t - z_{t-1}``, F3 and F4 by that of ``x_t - x_{t-1}``, both from a pilot
  simulation of the model seeded by the training seed, never from the training labels).
* **Gradients through f and h** (``model_grad``). With ``"jacobian"`` (default) back-propagation
  through time follows the state path ``x_{t|t} -> f -> x_{t+1|t}`` as in the paper, exactly where
  the model allows it: a linear ``f``/``h`` (``F``/``H`` declared) runs as a matrix product in torch,
  a model that declares torch forms (``f_torch``, ``h_torch``, ``residual_torch``; the library's UNGM
  and CTM do) runs them under autograd, and any other model's numpy function is applied per step and
  back-propagated with a forward-difference Jacobian (``nx`` extra evaluations per step, only while
  training). ``"finite-difference"`` takes the numpy path even where a torch form exists (how
  files made before the torch forms were trained). ``"detach"`` cuts the path through ``f`` (gradients
  flow through the network's own inputs and states only); it cannot train the unsupervised loss,
  whose only path to the weights is through ``f`` and ``h``. Measurement differences use the model's
  ``residual`` (bearings wrapped); the wrap is a constant offset of ``2 pi``, so its derivative is
  that of the plain difference.
* **A bounded state** (``clamp``, a departure, off by default): ``"auto"`` or explicit bounds keep
  every component of the estimate ``x_{t|t}`` inside ``[lo, hi]`` (``torch.clamp``; no gradient
  through a clamped component), in training and when filtering. ``"auto"``: the range of the states
  of a pilot simulation of the model (200 runs of its horizon, seeded by the filter's seed, its own
  stream), widened by a quarter of its width on each side (UNGM: about [-40, 40]). On UNGM an
  unbounded learned gain can drive the estimate to overflow within a window (the measurement
  ``x^2/20`` grows quadratically), and training then keeps its initialisation; the clamp removes
  that failure. The bounds are recorded in the file (``bounds``).
* Everything runs in float64 (the library's precision; the public code's float32 NaNs are a
  reported issue).

**Bayesian variant** (``n_samples = J > 1``, ``dropout = p > 0``; Dahan, Revach, Duník, Shlezinger,
"Bayesian KalmanNet: Quantifying Uncertainty in Deep Learning Augmented Kalman Filter", IEEE Trans. Signal
Processing 73, 2025, doi 10.1109/TSP.2025.3581703, arXiv 2309.03058; parts presented at ICASSP 2024. Another
construction, not implemented here, computes KalmanNet's error covariance from its internal features given
``H``: Klein, Revach, Shlezinger et al., "Uncertainty in data-driven Kalman filtering for partially known
state-space models", ICASSP 2022, arXiv 2110.04738): Monte-Carlo dropout on the hidden layer of
the gain head FC2 (architecture 1: on the top GRU's output), kept on when filtering. Each run is
filtered by ``J`` copies of the filter, each with its own dropout mask (drawn once per sequence: one
sample of the weights, as a Bayesian network's), its own estimate and GRU states; the estimate is the
copies' mean and its covariance their sample covariance (``1/(J-1)``),

.. math::
    \hat x_{t|t} = \tfrac1J \sum_j \hat x^{(j)}_{t|t},\qquad
    P_{t|t} = \tfrac{1}{J-1} \sum_j (\hat x^{(j)}_{t|t} - \hat x_{t|t})(\hat x^{(j)}_{t|t} - \hat x_{t|t})^T .

The copies start from ``J`` draws of the prior ``N(m0, P0)``, centred on ``m0`` (without them the
first covariance would be the gains' spread alone, ``Var(K) (z - h(m0))^2``). Training adds to the
MSE of the mean the calibration term ``lambda mean_t |diag(P_{t|t}) - e_t^2|`` (``e`` the error of
the mean; ``calibration = lambda``), as we read the paper; the fixed dropout rate stands for its
Bayesian weight posterior. Between steps the copies' spread grows by ``(K^{(j)} - K) Delta z_t``:
it is proportional to the current innovation, so the NEES has a heavy tail where an innovation is
near zero (on the linear test model the time-averaged ANEES of a CI-trained filter is about 30-60,
ideal 1: overconfident).

**Training** (:func:`train_kalmannet`): trajectories from the model's simulator (seeded; a fixed
set, or ``fresh`` ones every epoch or every minibatch), Adam, minibatches of whole trajectories
batched as one tensor per step, back-propagation through the whole sequence or truncated to windows
(``tbptt``: the estimate and GRU states carry over, detached, one optimiser step per window),
optional gradient-norm clipping (``clip``), the network with the best validation loss kept
(validated once per epoch, or every ``val_every`` optimiser steps, on trajectories of their own
stream, distinct from the training ones and from any evaluation's). Losses: ``"supervised"`` (the
paper: MSE of ``x_{t|t}`` against the true state) or ``"unsupervised"`` (Revach et al.,
"Unsupervised learned Kalman filtering", arXiv 2110.09005, EUSIPCO 2022: the squared error of the
predicted measurement, ``|z_t - h(x_{t|t-1})|^2``, no true state used). A non-finite loss or
gradient stops training with :class:`TrainingDiverged` naming the epoch and step, unless
``on_diverged`` says otherwise.

**The restart rule** (``on_diverged="restart"``, ``restarts``, ``patience``): a training *attempt*
is abandoned when it diverges (a non-finite loss, gradient or validation loss before it has beaten
its initial network; after that, first up to ``max_restores`` returns to its best weights at half
the learning rate) or when no validation within its first ``patience`` optimiser steps beats its
initial network (the last attempt allowed trains on instead: it may still improve). The next
attempt starts from new weights, minibatch order and dropout draws of the seed
:func:`restart_seed` ``(seed, a) = seed + 1000 a`` (``a = 1, 2, ...``; the validation set and a
fixed training set stay), at most ``restarts`` times; every attempt's optimiser steps and CPU
seconds count against the training's budget (``max_steps``, ``max_cpu_s``: totals over attempts).
The result is the network with the best validation loss over all attempts. A training whose kept
network is an *initial* (untrained) one, of any attempt, has **failed**: ``history["failed"]`` says
why (also in the file), with a warning; it is never returned as a trained filter silently.
``history["attempts"]`` lists each attempt's seed, steps, initial and best validation loss and why
it ended; ``history["n_restarts"]`` counts the restarts.

**Snapshots** (``snapshots``: epochs; ``snapshot_steps``: optimiser steps, multiples of
``val_every``): one training keeps the network a training stopped there would have returned (the
best on validation so far), so one training serves a budget curve. Training is deterministic for a
seed on one machine (one torch thread, seeded streams, a validation schedule that does not depend
on the snapshots asked for), so a snapshot is bit for bit the filter of ``epochs=e`` or
``max_steps=S``, and a saved file is reproduced byte for byte by rerunning its training on the same
machine (``tests/test_kalmannet.py``). Across CPUs the floating-point kernels round differently and
training amplifies that: equality across machines is not claimed. A budget in CPU seconds is met by
a step count calibrated on the machine (:data:`RECIPE_TUNING` records CPU-s per step); ``max_cpu_s`` stops
on the clock itself, which is not reproducible.

**Checkpoints** (``checkpoint=PATH``): a training of hours can be stopped and resumed. At a validation,
at most every :data:`CHECKPOINT_EVERY_S` seconds of wall time (with validation once per epoch: at the end of
an epoch), the whole state of the loop goes to ``PATH``, a ``.npz`` without pickles written atomically like
every file of the library (:func:`adaptfilt.files.write_npz`): the weights, Adam's moments and learning rate,
torch's random state, the minibatch order's generator, where in the epoch, minibatch and back-propagation
window the next step starts (with the estimate and GRU states carried into it), the history, the best
weights, the attempt's and every snapshot kept so far, and the CPU seconds spent. About ``5 +`` (snapshots)
copies of the weights: 1 MB on the CTM's architecture 2, tens of MB for its architecture 1. A call that finds
the file goes on from there (the simulated minibatches are drawn again from their own seeds), bit for bit the
training that was never stopped; ``knet.resumed_at`` lists the steps it resumed at (kept out of the saved
filter, whose file is byte for byte the uninterrupted training's). The file is left in place when the call
returns or raises: the caller deletes it once the results are safe (a stale one only replays the last steps
to the same result). A checkpoint records the call's arguments and the package version, as the journal of a
long run does (:mod:`adaptfilt.experiments.journal`); one written by another training is a ``ValueError``
that names what differs. Like the journal it does not see an edit of the training code between two
sittings: delete the file after one. ``adaptfilt train-gain`` and the pipeline keep it beside the training's
last file, ``OUT.ckpt.npz``, as ``adaptfilt train`` does
(:attr:`adaptfilt.experiments.jobs.GainSpec.checkpoint`), and delete it once their files are written.

**Recipes** (:data:`RECIPES`): on UNGM both architectures train at learning rate 3e-3 over windows of
20 steps, on minibatches of 100 freshly simulated trajectories, validated every 25 steps, the state
clamped, under the restart rule; chosen on selection runs only from 8 learning rates x window lengths
per architecture (:data:`RECIPE_TUNING`). On 2000 fresh test runs (:data:`RECIPE_RESULTS`, seeds 0-2)
architecture 1 reached an RMSE of 2.18-2.51 at about 45 CPU-s and 1.26-1.54 at 200 CPU-s (about
20,000 trajectories seen, no restart), architecture 2 (472 weights) 2.61-3.02 and 2.51-2.79 (one
restart in three trainings): architecture 1 was ahead in every seed at both budgets (one recipe
each, three seeds; the study's eight will say more). The CTM's recipes also count a collapse of the validation
loss as a divergence (``collapse_after=4``), added after the tuning when longer trainings showed it.

Files (:meth:`KalmanNet.save`, :func:`load_kalmannet`): one ``.npz`` without pickles
(:func:`adaptfilt.files.write_npz`, as a policy's) holding the weights and a JSON record of the model's
name and dimensions, the options, the seed, the scales and bounds, the training summary (with
``failed``) and the package version; loading it for another model is a ``ValueError`` naming both.

Example
-------
>>> import numpy as np, adaptfilt as af
>>> from adaptfilt.kalmannet import train_kalmannet
>>> model = af.models.linear_gaussian(F=[[0.9]], H=[[1.0]], Q=[[1.0]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
>>> knet = train_kalmannet(model, n_train=20, n_val=10, n_steps=10, epochs=2, seed=0, progress=False)
>>> traj = model.simulate(n_runs=5, n_steps=10, rng=1)
>>> run = knet.run(traj.z)                      # an adaptfilt FilterRun: the metrics work unchanged
>>> af.metrics.rmse(traj.x, run.mean).shape
(10,)
>>> arch1 = train_kalmannet(model, arch=1, n_train=20, n_val=10, n_steps=10, max_steps=4, epochs=None,
...                         val_every=2, seed=0, progress=False)
>>> arch1.history["optimiser_steps"], arch1.history["val_steps"]
(4, [0, 2, 4])
"""
from __future__ import annotations

import copy
import json
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence

import numpy as np
import torch
from torch import nn

from adaptfilt._version import __version__
from adaptfilt.files import read_npz, write_npz
from adaptfilt.filters import FilterRun
from adaptfilt.gainnets import GainNet, GainNet1, make_gain_net
from adaptfilt.models import StateSpaceModel, Trajectory
from adaptfilt.nets import adam_to_arrays, arrays_to_adam, arrays_to_state, one_torch_thread, state_to_arrays

__all__ = ["GainNet", "GainNet1", "KalmanNet", "train_kalmannet", "load_kalmannet", "TrainingDiverged",
           "KALMANNET_FORMAT", "RECIPES", "RECIPE_TUNING", "RECIPE_RESULTS", "restart_seed", "collapse_step"]

KALMANNET_FORMAT = "adaptfilt-kalmannet/1"
#: The format of a training's checkpoint (``train_kalmannet(checkpoint=...)``).
CHECKPOINT_FORMAT = "adaptfilt-kalmannet-checkpoint/1"
#: Seconds of wall time between a training's checkpoints (a validation falls every few seconds; writing one
#: costs milliseconds): what a stop loses at most, besides the validation interval.
CHECKPOINT_EVERY_S = 60.0
FEATURE_NORMS = ("l2", "none", "scale")
MODEL_GRADS = ("jacobian", "finite-difference", "detach")
LOSSES = ("supervised", "unsupervised")
FRESH = (None, "epoch", "batch")
#: How far ``clamp="auto"`` widens the pilot simulation's state range on each side (fraction of its width).
CLAMP_MARGIN = 0.25
#: A restart's seed is the training's seed plus this times the restart's number (:func:`restart_seed`).
RESTART_SEED_STRIDE = 1000
_DT = torch.float64

#: What the recipes share (chosen before tuning, from the outside measurement that the learned-gain study
#: cites and the public code's sizes): minibatches of 100 trajectories, each freshly simulated (``n_train`` is
#: then the trajectories per epoch: one minibatch), validation on 100 trajectories of their own stream every
#: 25 optimiser steps, scaled features, the clamped state, gradient norm clipped at 10, weight decay 1e-4, the
#: restart rule with at most 2 restarts and a patience of 200 optimiser steps; the budget decides the length.
_COMMON = dict(n_train=100, n_val=100, batch_size=100, fresh="batch", val_every=25, feature_norm="scale",
               clamp="auto", clip=10.0, weight_decay=1e-4, on_diverged="restart", restarts=2, patience=200,
               epochs=None, loss="supervised")

#: Training recipes per model and architecture, for ``train_kalmannet(model, **RECIPES[name][arch], seed=s,
#: max_steps=S)``, each chosen by the tuning recorded beside it (:data:`RECIPE_TUNING`).
RECIPES: dict = {
    "ungm": {1: dict(_COMMON, arch=1, lr=3e-3, tbptt=20), 2: dict(_COMMON, arch=2, lr=3e-3, tbptt=20)},
    "ctm": {1: dict(_COMMON, arch=1, lr=3e-3, tbptt=50, collapse_after=4),
            2: dict(_COMMON, arch=2, lr=1e-2, tbptt=50, collapse_after=4)},
}
#: Why the CTM's recipes count a collapse (``collapse_after=4``) and UNGM's do not: every CTM supervised training
#: of the study's 1200 CPU-s run collapsed (finite validation loss above the untrained network's to the end, from
#: optimiser steps 1225-7950 of 8100; :func:`collapse_step`), which the 45 CPU-s tuning (about 300 steps) could
#: not see; no UNGM training did. Added after the tuning, which is unchanged.

#: The tuning that chose :data:`RECIPES` (validation runs only): per model, the grid (learning rate x window
#: length, :data:`_COMMON` otherwise), the training seed, the budget (process CPU-s, ``max_cpu_s``, this
#: 2-core machine shared with other work), the selection runs (never a test's), and per architecture and
#: configuration ``(lr, tbptt): (RMSE on the selection runs, optimiser steps, restarts)``; the RMSE is
#: ``af.metrics.rmse(x, mean).mean()`` (over runs per step, then over time). ``cpu_s_per_step``: measured in
#: the chosen configuration, to turn a CPU-s budget into optimiser steps.
RECIPE_TUNING: dict = {
    "ungm": {
        "grid": {"lr": [3e-4, 1e-3, 3e-3, 1e-2], "tbptt": [20, 50]},
        "seed": 100, "budget_cpu_s": 45.0,
        "selection_runs": "1000 runs of T = 500 from numpy Generator([4848, 1])",
        "note": "the grid's lr 1e-2 was added after 3e-3 came out best at the edge of the first grid",
        1: {(3e-4, 20): (3.019, 1221, 0), (3e-4, 50): (3.598, 578, 1), (1e-3, 20): (2.586, 1204, 1),
            (1e-3, 50): (2.398, 578, 0), (3e-3, 20): (1.925, 1225, 0), (3e-3, 50): (2.557, 570, 0),
            (1e-2, 20): (3.067, 1255, 0), (1e-2, 50): (2.724, 547, 0)},
        2: {(3e-4, 20): (2.779, 1200, 1), (3e-4, 50): (2.927, 513, 2), (1e-3, 20): (2.647, 1250, 1),
            (1e-3, 50): (2.927, 525, 2), (3e-3, 20): (2.569, 1212, 0), (3e-3, 50): (2.927, 550, 2),
            (1e-2, 20): (2.733, 1050, 1), (1e-2, 50): (2.927, 481, 2)},
        "failed": "architecture 2 with windows of 50: every configuration kept an initial network (that of "
                  "restart 1, seed 1100: RMSE 2.927 with the clamp)",
        "cpu_s_per_step": {1: 45.1 / 1225, 2: 45.2 / 1212},
    },
    "ctm": {
        "grid": {"lr": [3e-4, 1e-3, 3e-3, 1e-2, 3e-2], "tbptt": [20, 50]},
        "seed": 100, "budget_cpu_s": 45.0,
        "selection_runs": "1000 runs of T = 150 from numpy Generator([4848, 1])",
        "note": "UNGM's grid of 8; lr 3e-2 added after 1e-2 came out best at the grid's edge (architecture 2), the "
                "rule the kappa learner's tuning followed too (10 configurations each); architecture 2 chosen "
                "(36.03 against architecture 1's best 43.72); RMSE in the CTM's position units",
        1: {(3e-4, 20): (45.83, 197, 0), (3e-4, 50): (48.77, 74, 0), (1e-3, 20): (45.43, 175, 0),
            (1e-3, 50): (46.69, 76, 0), (3e-3, 20): (53.71, 181, 0), (3e-3, 50): (43.72, 68, 0),
            (1e-2, 20): (56.10, 182, 0), (1e-2, 50): (46.10, 76, 0), (3e-2, 20): (70.27, 203, 1),
            (3e-2, 50): (72.69, 75, 0)},
        2: {(3e-4, 20): (47.35, 870, 0), (3e-4, 50): (49.94, 233, 0), (1e-3, 20): (41.45, 629, 0),
            (1e-3, 50): (43.97, 254, 0), (3e-3, 20): (39.37, 830, 0), (3e-3, 50): (36.59, 314, 0),
            (1e-2, 20): (40.66, 783, 0), (1e-2, 50): (36.03, 262, 0), (3e-2, 20): (50.78, 812, 0),
            (3e-2, 50): (41.91, 338, 0)},
        "failed": "architecture 1 at lr 3e-2: no attempt beat its initial network on validation (windows of 20: "
                  "one restart; of 50: none, the budget spent)",
    },
}

#: What the recipes reached (measured after they were chosen): per model and architecture, per training seed,
#: ``(optimiser steps, training CPU-s, RMSE)`` of the step snapshot with the most CPU-s up to about 45 and of
#: the training stopped at 200 CPU-s (``max_cpu_s``), the restarts, and the distinct training trajectories
#: seen; RMSE as in :data:`RECIPE_TUNING` on 2000 fresh test runs of T = 500 (``Generator([4848, 2])``: neither
#: training, validation nor selection runs). The machine: 2 cores shared with other work (load about 10),
#: one torch thread; a step cost 37-45 ms of CPU there. Architecture 2 with GRUs 8 times wider
#: (``hidden_mult=8``, 3,363 weights), seed 0 only: 2.329 at 44.4 CPU-s (1000 steps).
RECIPE_RESULTS: dict = {
    "ungm": {
        1: {0: {"45": (1150, 44.3, 2.236), "200": (5225, 200.3, 1.381), "restarts": 0, "trajectories": 20900},
            1: {"45": (1050, 43.6, 2.178), "200": (4750, 200.4, 1.260), "restarts": 0, "trajectories": 19000},
            2: {"45": (1100, 44.7, 2.513), "200": (4996, 200.3, 1.542), "restarts": 0, "trajectories": 20000}},
        2: {0: {"45": (1100, 44.3, 3.023), "200": (4969, 200.6, 2.530), "restarts": 0, "trajectories": 19900},
            1: {"45": (1000, 44.4, 2.606), "200": (4414, 200.5, 2.513), "restarts": 0, "trajectories": 17700},
            2: {"45": (950, 44.8, 2.952), "200": (4424, 200.7, 2.786), "restarts": 1, "trajectories": 17700}},
    },
}


class TrainingDiverged(FloatingPointError):
    """Training produced a non-finite loss or gradient (named by epoch and optimiser step)."""


def _warn(msg: str) -> None:
    """A RuntimeWarning attributed to the first caller outside this module (the user's training call)."""
    f, level = sys._getframe(1), 2
    while f is not None and f.f_code.co_filename == __file__:
        f, level = f.f_back, level + 1
    warnings.warn(msg, RuntimeWarning, stacklevel=level)


def restart_seed(seed: int, attempt: int) -> int:
    """The seed of attempt ``attempt`` of a training seeded ``seed`` (0: the training's own seed)."""
    return int(seed) + RESTART_SEED_STRIDE * int(attempt)


def collapse_step(history: dict, min_validations: int = 4) -> int | None:
    """The optimiser step from which a training's validation loss, finite, stayed above its attempt's initial
    (untrained) network's to the end of that attempt, after the attempt had beaten it, over at least
    ``min_validations`` validations (a shorter tail cannot be told from a spike that recovers): a collapse
    the restart rule does not act on (it acts on non-finite losses only). Read from ``history``
    (``val_steps``, ``val_loss``, ``attempts``); None when no attempt collapsed. The network kept is the best
    on validation, from before the collapse, so a collapse ends a training's progress without showing in its
    filter: a budget curve flattens there.

    >>> h = {"val_steps": [0, 25, 50, 75, 100, 125, 150], "val_loss": [10.0, 4.0, 30.0, 3.0, 300.0, 90.0, 200.0],
    ...      "attempts": [{"first_step": 0, "init_val": 10.0}]}
    >>> collapse_step(h, min_validations=3)
    100
    """
    steps, vals, attempts = list(history["val_steps"]), list(history["val_loss"]), list(history["attempts"])
    if len(steps) != len(vals):
        raise ValueError(f"history: {len(steps)} val_steps against {len(vals)} val_loss")
    if int(min_validations) < 1:
        raise ValueError(f"min_validations must be at least 1, got {min_validations}")
    # each attempt's entries start at its own initial validation (step first_step, loss init_val); an attempt
    # that follows another starts on the step where the last one ended, so the step alone does not split them
    starts, i = [], 0
    for k, a in enumerate(attempts):
        while i < len(steps) and not (steps[i] == a["first_step"] and (k == 0 or vals[i] == a["init_val"])):
            i += 1
        if i == len(steps):
            raise ValueError(f"history: attempt {k}'s initial validation (step {a['first_step']}) is not in val_steps")
        starts.append(i)
        i += 1
    for k, a in enumerate(attempts):
        part = slice(starts[k] + 1, starts[k + 1] if k + 1 < len(starts) else None)
        s_k, v_k = steps[part], vals[part]
        if not all(math.isfinite(v) for v in v_k):
            continue  # a non-finite loss is the restart rule's divergence, not a collapse
        first_better = next((n for n, v in enumerate(v_k) if v < a["init_val"]), None)
        if first_better is None:
            continue
        tail = len(v_k)
        while tail > first_better and v_k[tail - 1] > a["init_val"]:
            tail -= 1
        if len(v_k) - tail >= int(min_validations):
            return int(s_k[tail])
    return None


# ------------------------------------------------------------- model functions in torch
class _NumpyFn(torch.autograd.Function):
    """``y = fn(x, k)`` of a numpy model function, differentiated by forward differences."""

    @staticmethod
    def forward(ctx, x, fn, k):
        xn = x.detach().numpy()
        y = np.asarray(fn(xn, k), dtype=float)
        if ctx.needs_input_grad[0]:
            d = xn.shape[-1]
            eps = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(xn))  # (B, d)
            J = np.empty(y.shape + (d,))
            for j in range(d):
                xj = xn.copy()
                xj[:, j] += eps[:, j]
                J[..., j] = (np.asarray(fn(xj, k), dtype=float) - y) / eps[:, j:j + 1]
            ctx.save_for_backward(torch.from_numpy(J))
        return torch.from_numpy(y)

    @staticmethod
    def backward(ctx, gy):
        (J,) = ctx.saved_tensors
        return (gy.unsqueeze(-2) @ J).squeeze(-2), None, None


def _check_torch_forms(model: StateSpaceModel) -> None:
    """The model's torch forms give its numpy functions' values on a probe batch (ValueError naming the form)."""
    rng = np.random.default_rng(0)
    x = model.m0 + rng.standard_normal((16, model.nx)) @ np.linalg.cholesky(model.P0).T
    for name, fn, tfn in (("f_torch", model.f, model.f_torch), ("h_torch", model.h, model.h_torch)):
        if tfn is None:
            continue
        for k in (1, 7):
            want = np.asarray(fn(x, k), dtype=float)
            got = tfn(torch.from_numpy(x.copy()), k)
            if not isinstance(got, torch.Tensor) or tuple(got.shape) != want.shape or not np.allclose(
                    got.detach().numpy(), want, rtol=1e-9, atol=1e-9 * max(1.0, float(np.abs(want).max()))):
                raise ValueError(f"model {model.name!r}: {name} does not equal its numpy form {name[:-6]} on a "
                                 f"probe batch (k = {k})")
    if model.residual_torch is not None:
        a, b = rng.uniform(-10, 10, (16, model.nz)), rng.uniform(-10, 10, (16, model.nz))
        got = model.residual_torch(torch.from_numpy(a), torch.from_numpy(b))
        if not np.allclose(got.numpy(), model.residual(a, b), rtol=1e-9, atol=1e-9):
            raise ValueError(f"model {model.name!r}: residual_torch does not equal residual on a probe batch")


def _pilot(model: StateSpaceModel, seed: int, n_steps: int, key: int) -> Trajectory:
    return model.simulate(200, max(2, n_steps), rng=np.random.default_rng([int(seed), key]))


def _pilot_scales(model: StateSpaceModel, seed: int, n_steps: int) -> np.ndarray:
    """``feature_norm="scale"``: per-component scales of [F1, F2, F3, F4] from a pilot simulation."""
    traj = _pilot(model, seed, n_steps, 7)
    dz = model.diff_z(traj.z[:, 1:], traj.z[:, :-1]).reshape(-1, model.nz).std(0)
    dx = np.diff(traj.x, axis=1).reshape(-1, model.nx).std(0)
    s = np.concatenate([dz, dz, dx, dx])
    return np.where(s > 0, s, 1.0)


def _pilot_bounds(model: StateSpaceModel, seed: int, n_steps: int) -> np.ndarray:
    """``clamp="auto"``: ``[lo, hi]`` per state component, the pilot's range widened by :data:`CLAMP_MARGIN`."""
    x = _pilot(model, seed, n_steps, 8).x.reshape(-1, model.nx)
    lo, hi = x.min(0), x.max(0)
    w = np.maximum(hi - lo, 1e-6)
    return np.stack([lo - CLAMP_MARGIN * w, hi + CLAMP_MARGIN * w])


@dataclass
class _Carry:
    """What one step passes to the next (kept across truncated back-propagation windows)."""

    x_filt: torch.Tensor       # x_{t-1|t-1}
    x_filt_prev: torch.Tensor  # x_{t-2|t-2}
    x_pred: torch.Tensor       # x_{t-1|t-2}
    h: tuple
    mask: torch.Tensor | None = None  # the Bayesian variant's dropout mask, fixed over a sequence

    def detach(self) -> "_Carry":
        return _Carry(self.x_filt.detach(), self.x_filt_prev.detach(), self.x_pred.detach(),
                      tuple(h.detach() for h in self.h), self.mask)


# --------------------------------------------------------------------- the filter
class KalmanNet:
    """KalmanNet (architecture 1 or 2) over a library model, batched over runs (module docstring).

    Parameters
    ----------
    model : StateSpaceModel
        Gives ``f``, ``h``, ``residual`` (and their torch forms when declared), ``m0`` and the
        dimensions (``Q``, ``R``, ``P0`` are not used by the filter; ``feature_norm="scale"`` and
        ``clamp="auto"`` simulate the model once).
    arch : 1 or 2
        The paper's architecture (:mod:`adaptfilt.gainnets`); 2 is the default.
    feature_norm : "l2", "none" or "scale"
        Input normalisation (module docstring); ``"l2"`` is the public code's.
    in_mult, out_mult, hidden_mult : int
        Architecture 2: width multipliers of the input FC layers, of FC2's hidden layer (paper: 5 and
        40) and of the three GRUs (1: the paper's ``m^2``, ``m^2``, ``n^2`` units).
    gru_hidden, gru_layers, in_width, inputs
        Architecture 1: GRU units (default ``10 (m^2 + n^2)``), GRU layers (2), input layer width
        (default ``80 (m + n)``) and the features fed in (``"134"``: F1, F3, F4).
    dropout, n_samples : float, int
        The Bayesian variant: Monte-Carlo dropout rate and the number ``J`` of samples per step
        (``n_samples > 1`` needs ``dropout > 0``); it returns covariances.
    model_grad : "jacobian", "finite-difference" or "detach"
        How training back-propagates through ``f`` and ``h`` (module docstring).
    clamp : None, "auto" or (lo, hi)
        Keep the estimate inside bounds (module docstring; a departure from the paper, off by default).
    seed : int
        Initialises the weights (and draws the dropout masks when filtering, unless ``run`` gets one).
    """

    def __init__(self, model: StateSpaceModel, *, arch: int = 2, feature_norm: Literal["l2", "none", "scale"] = "l2",
                 in_mult: int = 5, out_mult: int = 40, hidden_mult: int = 1, gru_hidden: int | None = None,
                 gru_layers: int = 2, in_width: int | None = None, inputs: str = "134", dropout: float = 0.0,
                 n_samples: int = 1, model_grad: Literal["jacobian", "finite-difference", "detach"] = "jacobian",
                 clamp=None, seed: int = 0, scales: np.ndarray | None = None, bounds: np.ndarray | None = None):
        if not isinstance(model, StateSpaceModel):
            raise TypeError(f"model must be an adaptfilt StateSpaceModel, got {type(model).__name__}")
        if feature_norm not in FEATURE_NORMS:
            raise ValueError(f"feature_norm must be one of {FEATURE_NORMS}, got {feature_norm!r}")
        if model_grad not in MODEL_GRADS:
            raise ValueError(f"model_grad must be one of {MODEL_GRADS}, got {model_grad!r}")
        if int(in_mult) < 1 or int(out_mult) < 1 or int(hidden_mult) < 1:
            raise ValueError(f"in_mult, out_mult and hidden_mult must be positive integers, got {in_mult}, "
                             f"{out_mult}, {hidden_mult}")
        if not 0.0 <= float(dropout) < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        if int(n_samples) < 1 or (int(n_samples) > 1) != (float(dropout) > 0.0):
            raise ValueError(f"the Bayesian variant needs both n_samples > 1 and dropout > 0, the plain KalmanNet "
                             f"n_samples = 1 and dropout = 0 (got n_samples={n_samples}, dropout={dropout})")
        auto = isinstance(clamp, str)
        if (auto and clamp != "auto") or not (clamp is None or auto or np.shape(clamp) == (2, model.nx)):
            raise ValueError(f"clamp must be None, 'auto' or bounds [lo, hi] of {model.nx} components each, got {clamp!r}")
        self.model = model
        self.options = dict(feature_norm=feature_norm, in_mult=int(in_mult), out_mult=int(out_mult),
                            dropout=float(dropout), n_samples=int(n_samples), model_grad=model_grad, arch=int(arch),
                            hidden_mult=int(hidden_mult), gru_hidden=None if gru_hidden is None else int(gru_hidden),
                            gru_layers=int(gru_layers), in_width=None if in_width is None else int(in_width),
                            inputs=str(inputs),
                            clamp=clamp if clamp is None or auto else np.asarray(clamp, float).tolist())
        self.seed = int(seed)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            self.net = make_gain_net(int(arch), model.nx, model.nz, in_mult=int(in_mult), out_mult=int(out_mult),
                                     hidden_mult=int(hidden_mult), gru_hidden=gru_hidden, gru_layers=int(gru_layers),
                                     in_width=in_width, inputs=str(inputs), dropout=float(dropout))
        if feature_norm == "scale":
            s = _pilot_scales(model, self.seed, model.n_steps or 100) if scales is None else np.asarray(scales, float)
            if s.shape != (2 * model.nz + 2 * model.nx,) or not (np.isfinite(s).all() and (s > 0).all()):
                raise ValueError(f"scales must be {2 * model.nz + 2 * model.nx} positive finite numbers, got {s}")
            self.scales = s
        else:
            self.scales = None
        if clamp is None:
            self.bounds = None
        else:
            if not auto:
                b = np.asarray(clamp, float)
            else:
                b = _pilot_bounds(model, self.seed, model.n_steps or 100) if bounds is None else np.asarray(bounds, float)
            if b.shape != (2, model.nx) or not (np.isfinite(b).all() and (b[0] < b[1]).all()):
                raise ValueError(f"clamp bounds must be [lo, hi] with lo < hi, {model.nx} finite components each, got {b}")
            self.bounds = b
        self.history: dict = {}
        # exact torch versions of linear f and h (no finite differences), and the model's torch forms
        self._F = None if model.F is None else torch.from_numpy(np.ascontiguousarray(model.F.T))
        self._H = None if model.H is None else torch.from_numpy(np.ascontiguousarray(model.H.T))
        numpy_path = model_grad == "finite-difference"
        self._f_torch = None if numpy_path else model.f_torch
        self._h_torch = None if numpy_path else model.h_torch
        self._res_torch = None if numpy_path else model.residual_torch
        if not numpy_path:
            _check_torch_forms(model)
        self._m0 = torch.from_numpy(model.m0.copy())
        self._scales_t = None if self.scales is None else torch.from_numpy(self.scales)
        self._lo_hi = None if self.bounds is None else (torch.from_numpy(self.bounds[0].copy()),
                                                        torch.from_numpy(self.bounds[1].copy()))

    @property
    def bayesian(self) -> bool:
        return self.options["n_samples"] > 1

    @property
    def failed(self) -> str | None:
        """Why training failed (the network kept is an untrained one), or None (module docstring)."""
        return self.history.get("failed")

    def __repr__(self) -> str:
        o = self.options
        arch = f", arch={o['arch']}" if o["arch"] != 2 else ""
        extra = f", dropout={o['dropout']:g}, J={o['n_samples']}" if self.bayesian else ""
        return f"KalmanNet(model={self.model.name!r}{arch}, feature_norm={o['feature_norm']!r}{extra})"

    # -------------------------------------------------------------- checks
    def check_z(self, z) -> np.ndarray:
        """Measurements as ``(M, T, nz)``; ValueError naming what is wrong."""
        z = np.asarray(z, dtype=float)
        nz = self.model.nz
        if z.ndim == 2 and nz == 1:
            z = z[:, :, None]
        if z.ndim != 3 or z.shape[2] != nz or z.shape[0] < 1 or z.shape[1] < 1:
            raise ValueError(f"z must have shape (M, T, nz={nz}) (or (M, T) when nz = 1) for model "
                             f"{self.model.name!r}, got {z.shape}")
        if not np.isfinite(z).all():
            bad = np.argwhere(~np.isfinite(z).all(axis=2))[0]
            raise ValueError(f"z has non-finite values (first at run {bad[0]}, step {bad[1]})")
        return z

    # -------------------------------------------------------------- the recursion
    def _f(self, x: torch.Tensor, k: int) -> torch.Tensor:
        if self.options["model_grad"] == "detach":
            x = x.detach()
        if self._F is not None:
            return x @ self._F
        if self._f_torch is not None:
            return self._f_torch(x, k)
        return _NumpyFn.apply(x, self.model.f, k)

    def _h(self, x: torch.Tensor, k: int) -> torch.Tensor:
        if self._H is not None:
            return x @ self._H
        if self._h_torch is not None:
            return self._h_torch(x, k)
        return _NumpyFn.apply(x, self.model.h, k)

    def _dz(self, z: torch.Tensor, z_pred: torch.Tensor) -> torch.Tensor:
        """``z - z_pred`` through the model's residual; the wrap is added as a constant."""
        d = z - z_pred
        if self.model.residual is None:
            return d
        if self._res_torch is not None:
            return self._res_torch(z, z_pred)
        dn = d.detach().numpy()
        return d + torch.from_numpy(self.model.residual(z.detach().numpy(), z_pred.detach().numpy()) - dn)

    def _norm(self, F: torch.Tensor, which: slice) -> torch.Tensor:
        mode = self.options["feature_norm"]
        if mode == "l2":
            return nn.functional.normalize(F, p=2.0, dim=-1, eps=1e-12)
        if mode == "scale":
            return F / self._scales_t[which]
        return F

    def _start(self, B: int) -> _Carry:
        """The carry before the first step for ``B`` runs (``J B`` filter copies in the Bayesian variant)."""
        J = self.options["n_samples"]
        x0 = self._m0.expand(J * B, -1)
        if J > 1:
            # the J copies start from J draws of the prior N(m0, P0), centred so that their mean is m0:
            # without them every copy starts at m0 and the first covariance is only the gains' spread
            d = torch.randn(J, B, self.model.nx, dtype=_DT) @ torch.from_numpy(np.linalg.cholesky(self.model.P0).T)
            x0 = x0 + (d - d.mean(0)).reshape(J * B, -1)
        return _Carry(x0, x0, x0, self.net.initial_states(J * B), self.net.dropout_mask(J * B))

    def _window(self, z: np.ndarray, z_prev: np.ndarray, t0: int, carry: _Carry):
        """Steps ``t0 .. t0 + len(z) - 1`` from ``carry``: per-step tensors and the final carry.

        ``z``, ``z_prev`` ``(B, L, nz)`` numpy (``z_prev`` the measurement of the step before). The
        Bayesian variant runs ``J`` copies of the filter per run (sample ``j`` of run ``b`` at
        ``j B + b``), each with its own dropout mask, estimate and GRU states; the outputs are their
        mean and sample covariance. Every operation of a step acts on all ``B`` runs at once.
        """
        nx, nz = self.model.nx, self.model.nz
        J = self.options["n_samples"]
        if J > 1:
            z, z_prev = np.tile(z, (J, 1, 1)), np.tile(z_prev, (J, 1, 1))
        B, L = z.shape[:2]
        F1_all = torch.from_numpy(np.ascontiguousarray(self.model.diff_z(z, z_prev)))
        zt_all = torch.from_numpy(np.ascontiguousarray(z))
        s_z1, s_z2 = slice(0, nz), slice(nz, 2 * nz)
        s_x3, s_x4 = slice(2 * nz, 2 * nz + nx), slice(2 * nz + nx, 2 * nz + 2 * nx)
        means, preds, innovs, gains = [], [], [], []
        c = carry
        for i in range(L):
            t = t0 + i
            x_pred = c.x_pred if t == 0 else self._f(c.x_filt, t)  # f(x_k, k), k = t; x_{0|-1} = m0
            z_pred = self._h(x_pred, t + 1)
            innov = self._dz(zt_all[:, i], z_pred)
            F1 = self._norm(F1_all[:, i], s_z1)
            F2 = self._norm(innov, s_z2)
            F3 = self._norm(c.x_filt - c.x_filt_prev, s_x3)
            F4 = self._norm(c.x_filt - c.x_pred, s_x4)
            K, *h = self.net.step(F1, F2, F3, F4, *c.h, mask=c.mask)
            x_filt = x_pred + (K @ innov.unsqueeze(-1)).squeeze(-1)
            if self._lo_hi is not None:
                x_filt = torch.clamp(x_filt, *self._lo_hi)
            means.append(x_filt)
            preds.append(x_pred)
            innovs.append(innov)
            gains.append(K)
            c = _Carry(x_filt, c.x_filt, x_pred, tuple(h), c.mask)
        out = dict(mean=torch.stack(means, 1), x_pred=torch.stack(preds, 1), innov=torch.stack(innovs, 1),
                   K=torch.stack(gains, 1), cov=None)
        if J > 1:  # (J B, L, ...) -> the mean over the J copies and their sample covariance
            x_j = out["mean"].reshape(J, B // J, L, nx)
            out["mean"] = x_j.mean(0)
            e = x_j - out["mean"]
            out["cov"] = torch.einsum("jbti,jbtk->btik", e, e) / (J - 1)
            out["x_pred"] = out["x_pred"].reshape(J, B // J, L, nx).mean(0)
            out["K"] = out["K"].reshape(J, B // J, L, nx, nz).mean(0)
        return out, c

    def _z_prev(self, z: np.ndarray) -> np.ndarray:
        """``z_{t-1}`` per step; before the first, the predicted measurement of the prior ``h(m0)``."""
        z0 = np.asarray(self.model.h(np.broadcast_to(self.model.m0, (z.shape[0], self.model.nx)).copy(), 1), float)
        return np.concatenate([z0[:, None, :], z[:, :-1]], axis=1)

    def run(self, z, *, keep_gain: bool = False, seed: int | None = None, chunk: int = 4096) -> FilterRun:
        """Filter measurements ``z (M, T, nz)``; a :class:`~adaptfilt.filters.FilterRun`.

        ``mean`` and ``x_pred`` are the estimates; ``cov`` is the sample covariance of the
        Bayesian variant, else NaN (no covariance: :func:`adaptfilt.metrics.nees` raises on it);
        ``nis``, ``loglik`` and ``params`` are NaN (read-only broadcasts). ``info["K"] (M, T, nx,
        nz)`` holds the gains when ``keep_gain``. ``seed`` draws the dropout masks of the
        Bayesian variant (default: the filter's seed), in the order of the runs and chunks, so a
        run's masks depend on its place in ``z``. Runs are filtered in chunks of ``chunk``. A run
        whose estimate overflows (a learned gain can make the recursion unstable, e.g. on UNGM,
        unless ``clamp`` bounds it) keeps its non-finite values, with numpy's overflow warning:
        count it with :func:`adaptfilt.metrics.divergent` (``mean=``) or ``~np.isfinite(run.mean)``.
        """
        z = self.check_z(z)
        M, T, _ = z.shape
        nx, nz = self.model.nx, self.model.nz
        J = self.options["n_samples"]
        mean, x_pred = np.empty((M, T, nx)), np.empty((M, T, nx))
        cov = np.empty((M, T, nx, nx)) if J > 1 else np.broadcast_to(np.float64(np.nan), (M, T, nx, nx))
        K = np.empty((M, T, nx, nz)) if keep_gain else None
        z_prev = self._z_prev(z)
        was_training = self.net.training
        self.net.eval()
        try:
            with one_torch_thread(), torch.no_grad(), torch.random.fork_rng(devices=[]):
                torch.manual_seed(self.seed if seed is None else int(seed))
                for a in range(0, M, int(chunk)):
                    b = min(M, a + int(chunk))
                    out, _ = self._window(z[a:b], z_prev[a:b], 0, self._start(b - a))
                    mean[a:b], x_pred[a:b] = out["mean"].numpy(), out["x_pred"].numpy()
                    if J > 1:
                        cov[a:b] = out["cov"].numpy()
                    if keep_gain:
                        K[a:b] = out["K"].numpy()
        finally:
            self.net.train(was_training)
        nan = np.broadcast_to(np.float64(np.nan), (M, T))
        info = {"filter": repr(self)}
        if keep_gain:
            info["K"] = K
        return FilterRun(mean=mean, cov=cov, nis=nan, loglik=nan, params=nan, x_pred=x_pred, info=info)

    def snapshot(self, epoch: int | None = None, *, step: int | None = None) -> "KalmanNet":
        """The filter as a training of ``epoch`` epochs (``train_kalmannet(snapshots=...)``) or of ``step``
        optimiser steps (``snapshot_steps=...``, i.e. ``max_steps=step``) returned it: a copy with those
        weights and that history. ValueError naming the snapshots kept otherwise."""
        if (epoch is None) == (step is None):
            raise ValueError("give either an epoch or step=...")
        key = ("epoch", int(epoch)) if step is None else ("step", int(step))
        kept = getattr(self, "_snapshots", {})
        if key not in kept:
            have = sorted(f"{k} {v}" for k, v in kept) or ["none (train with snapshots=... or snapshot_steps=...)"]
            raise ValueError(f"no snapshot at {key[0]} {key[1]}; kept: {', '.join(have)}")
        state, hist, source = kept[key]
        other = copy.copy(source)
        other.net = copy.deepcopy(source.net)
        other.net.load_state_dict(state)
        other.net.eval()
        other.history, other._snapshots = copy.deepcopy(hist), {}
        return other

    # -------------------------------------------------------------- files
    def n_parameters(self) -> int:
        return sum(p.numel() for p in self.net.parameters())

    def metadata(self) -> dict:
        return {"format": KALMANNET_FORMAT, "model": self.model.name, "nx": self.model.nx, "nz": self.model.nz,
                "options": dict(self.options), "seed": self.seed, "version": __version__,
                "scales": None if self.scales is None else [float(s) for s in self.scales],
                "bounds": None if self.bounds is None else self.bounds.tolist(),
                "n_parameters": self.n_parameters(), "failed": self.failed,
                # the training's CPU seconds vary between reruns: they live in memory (and a study's manifest),
                # not in the file, which a rerun of its training reproduces byte for byte
                "history": {k: v for k, v in self.history.items() if k != "cpu_s"}}

    def save(self, path: str | os.PathLike) -> Path:
        """Write the weights and :meth:`metadata` to one ``.npz`` (no pickles, byte-reproducible)."""
        return write_npz(path, state_to_arrays("net", self.net), self.metadata())

    @classmethod
    def load(cls, path: str | os.PathLike, model: StateSpaceModel) -> "KalmanNet":
        return load_kalmannet(path, model)


def load_kalmannet(path: str | os.PathLike, model: StateSpaceModel) -> KalmanNet:
    """A :class:`KalmanNet` saved by :meth:`KalmanNet.save`, for ``model``.

    ``ValueError`` if the file is not a KalmanNet file or was made for another model (its name or
    dimensions differ: the message names both). Files made before an option existed load with its
    default (architecture 2, no clamp, ...).
    """
    if not isinstance(model, StateSpaceModel):
        raise TypeError(f"model must be an adaptfilt StateSpaceModel, got {type(model).__name__}")
    arrays, meta = read_npz(path, what="adaptfilt KalmanNet file")
    if meta.get("format") != KALMANNET_FORMAT:
        raise ValueError(f"{path}: not an adaptfilt KalmanNet file (format {meta.get('format')!r}, "
                         f"expected {KALMANNET_FORMAT!r})")
    have = (meta.get("model"), meta.get("nx"), meta.get("nz"))
    want = (model.name, model.nx, model.nz)
    if have != want:
        raise ValueError(f"{path}: KalmanNet file made for model {have[0]!r} (nx={have[1]}, nz={have[2]}), "
                         f"not for model {want[0]!r} (nx={want[1]}, nz={want[2]})")
    missing = [k for k in ("options", "seed") if k not in meta]
    if missing or not isinstance(meta.get("options"), dict):
        raise ValueError(f"{path}: not an adaptfilt KalmanNet file (missing or malformed {', '.join(missing) or 'options'})")
    scales, bounds = meta.get("scales"), meta.get("bounds")
    knet = KalmanNet(model, seed=meta["seed"], scales=None if scales is None else np.asarray(scales),
                     bounds=None if bounds is None else np.asarray(bounds), **meta["options"])
    try:
        knet.net.load_state_dict(arrays_to_state("net", arrays))
    except RuntimeError as e:
        raise ValueError(f"{path}: its weights do not fit a KalmanNet with options {meta['options']}: {e}") from None
    knet.history = meta.get("history", {})
    return knet


# --------------------------------------------------------------------- training
def _check_traj(traj: Trajectory, model: StateSpaceModel, what: str) -> Trajectory:
    if not isinstance(traj, Trajectory):
        raise TypeError(f"{what} must be an adaptfilt Trajectory, got {type(traj).__name__}")
    x, z = np.asarray(traj.x, float), np.asarray(traj.z, float)
    if x.ndim != 3 or z.ndim != 3 or x.shape[:2] != z.shape[:2] or x.shape[2] != model.nx or z.shape[2] != model.nz:
        raise ValueError(f"{what}: states {x.shape} and measurements {z.shape} must be (M, T, nx={model.nx}) and "
                         f"(M, T, nz={model.nz}) for model {model.name!r}")
    if not (np.isfinite(x).all() and np.isfinite(z).all()):
        raise ValueError(f"{what} has non-finite states or measurements")
    return Trajectory(x, z)


def _loss(knet: KalmanNet, out: dict, x: torch.Tensor | None, kind: str, calibration: float) -> torch.Tensor:
    if kind == "unsupervised":
        return (out["innov"] ** 2).mean()  # |z_t - h(x_{t|t-1})|^2: no true state
    e = out["mean"] - x
    loss = (e ** 2).mean()
    if out["cov"] is not None and calibration > 0.0:
        loss = loss + calibration * (torch.diagonal(out["cov"], dim1=-2, dim2=-1) - e ** 2).abs().mean()
    return loss


def _evaluate(knet: KalmanNet, traj: Trajectory, kind: str, calibration: float) -> float:
    """Validation loss, the training loss on the validation set with the filter's own dropout masks."""
    was_training = knet.net.training
    knet.net.eval()
    try:
        # the same dropout masks at every validation: epochs are compared on the same copies
        with torch.no_grad(), torch.random.fork_rng(devices=[]):
            torch.manual_seed(knet.seed)
            out, _ = knet._window(traj.z, knet._z_prev(traj.z), 0, knet._start(traj.n_runs))
            return float(_loss(knet, out, torch.from_numpy(traj.x), kind, calibration))
    finally:
        knet.net.train(was_training)


def train_kalmannet(model: StateSpaceModel, *, n_train: int = 100, n_val: int = 50, n_steps: int | None = None,
                    epochs: int | None = 30, batch_size: int = 20, lr: float = 1e-3, weight_decay: float = 1e-4,
                    loss: Literal["supervised", "unsupervised"] = "supervised", tbptt: int | None = None,
                    clip: float | None = None, seed: int = 0, data_seed: int | None = None,
                    train: Trajectory | None = None, val: Trajectory | None = None, progress: bool = True,
                    calibration: float = 1.0, init: KalmanNet | None = None,
                    on_diverged: Literal["raise", "restore", "stop", "restart"] = "raise", max_restores: int = 5,
                    max_cpu_s: float | None = None, snapshots: Sequence[int] = (),
                    fresh: Literal["epoch", "batch"] | None = None, val_every: int | None = None,
                    max_steps: int | None = None, snapshot_steps: Sequence[int] = (), restarts: int = 0,
                    patience: int | None = None, truth: StateSpaceModel | None = None,
                    collapse_after: int | None = None, checkpoint: str | os.PathLike | None = None,
                    checkpoint_every: float | None = None, **options) -> KalmanNet:
    """Train a :class:`KalmanNet` on simulated trajectories of ``model`` (module docstring).

    Parameters
    ----------
    n_train, n_val, n_steps : int
        Trajectories simulated for training (per epoch) and validation (``n_steps`` defaults to the
        model's horizon); with ``train``/``val`` given (Trajectories) those are used instead.
    epochs, batch_size, lr, weight_decay
        Passes over ``n_train`` trajectories per attempt (None: until the budget, ``max_steps`` or
        ``max_cpu_s``, ends training), trajectories per minibatch, Adam's settings.
    loss : "supervised" or "unsupervised"
        MSE against the true states (the paper), or the squared error of the predicted measurement
        (unsupervised KalmanNet); validation uses the same criterion.
    tbptt : int, optional
        Truncated back-propagation through time: one optimiser step per window of ``tbptt`` steps,
        the estimate and GRU states carried over (detached). Default: whole sequences.
    clip : float, optional
        Clip the gradient's global norm to ``clip`` (not in the paper; against exploding gradients).
    seed : int
        Weights, minibatch order and dropout masks; ``data_seed`` (default ``seed``) the trajectories:
        simulated from ``Generator([data_seed, 0])`` (a fixed training set), ``[data_seed, 3, a, e]``
        (``fresh="epoch"``: a new set of ``n_train`` in epoch ``e`` of attempt ``a``) or ``[data_seed, 4,
        a, e, b]`` (``fresh="batch"``: a new minibatch each time), and ``[data_seed, 1]`` (validation,
        the same for every attempt). ``history["trajectories_seen"]`` counts the distinct training
        trajectories, ``history["trajectory_steps"]`` the trajectory-steps back-propagated.
    fresh : None, "epoch" or "batch"
        Draw new training trajectories every epoch or every minibatch (the simulator is free; its
        CPU time counts in the budget). Not with ``train``.
    truth : StateSpaceModel, optional
        Simulate the training and validation trajectories from this model instead of ``model`` (same
        dimensions): a truth that differs from the model the filter keeps (other noise levels or
        dynamics), the setting in which KalmanNet's authors train it; the filter's ``f``, ``h``, ``m0``,
        scales and bounds stay ``model``'s. Recorded as ``history["truth"]`` (its description).
    val_every : int, optional
        Validate after every ``val_every``-th optimiser step (counted over attempts) instead of once
        per epoch; ``history["val_steps"]`` holds the step of each validation (0: the initial network).
    max_steps : int, optional
        A budget in optimiser steps, all attempts together: training stops after that step,
        validates once more if it has not just done so, and keeps the best network.
    max_cpu_s : float, optional
        A budget in process CPU seconds (everything since the call: simulation, validation, every
        attempt), checked after each optimiser step; it depends on the machine and its load, so a
        training stopped by it is not reproducible (``max_steps`` is).
    snapshots : sequence of int
        Epochs after which to keep the network a training of that many epochs would have returned (the
        best on validation so far, its history cut there): ``knet.snapshot(e)``. Epoch snapshots need
        per-epoch validation and no restarts. ValueError for an epoch outside ``1..epochs``.
    snapshot_steps : sequence of int
        Optimiser steps (multiples of ``val_every``) at which to keep the network ``max_steps=S``
        would have returned: ``knet.snapshot(step=S)``; bit for bit that training's weights (the
        CPU seconds are those spent up to it). One training serves a budget curve.
    on_diverged : "raise", "restore", "stop" or "restart"
        What a non-finite training loss, gradient or validation loss does: ``"raise"`` (default)
        :class:`TrainingDiverged` naming the epoch and optimiser step; ``"restore"`` (a documented
        fallback, never silent) warns, goes back to the best weights so far, halves the learning
        rate with a fresh Adam state, skips the rest of that minibatch and records the event in
        ``history["restores"]``; more than ``max_restores`` such events raise. ``"stop"``: as
        ``"restore"``, but the event after ``max_restores`` ends the training with the best weights so
        far instead of raising, recorded in ``history["stopped_by_divergence"]``. ``"restart"``: the
        restart rule (module docstring): restore while the attempt has improved (up to
        ``max_restores``), else abandon the attempt and restart from :func:`restart_seed`
        (the last attempt allowed is not abandoned for ``patience``: it trains on to the budget).
    restarts, patience : int
        The restart rule (``on_diverged="restart"`` only): at most ``restarts`` restarts; an attempt
        none of whose validations in its first ``patience`` optimiser steps beats its initial network
        is abandoned (None: only divergence abandons).
    collapse_after : int, optional
        Also count as a divergence (``on_diverged``) a *finite* validation loss above the attempt's initial
        network's for ``collapse_after`` validations in a row after the attempt had beaten it: a collapse
        (:func:`collapse_step` finds one in a history) that otherwise ends a training's progress unseen.
        None (default): only non-finite losses diverge, as in the files made before the option existed.
    calibration : float
        Weight of the covariance calibration term of the Bayesian variant (supervised only).
    init : KalmanNet, optional
        Continue from these weights (options then come from it; no restarts).
    checkpoint : path, optional
        A file through which the training can be stopped and resumed (module docstring, *Checkpoints*):
        the whole state of the loop is written there at a validation at most every ``checkpoint_every``
        seconds of wall time (default :data:`CHECKPOINT_EVERY_S`; 0: at every validation); a call with the
        same arguments that finds it goes on from there, bit for bit the training that was never stopped.
        The file stays when the call returns (delete it once the results are saved); one written by another
        training is a ``ValueError`` naming what differs. Only for a training that simulates its own data
        (no ``train``, ``val`` or ``init``).
    **options
        :class:`KalmanNet`'s options (``arch``, ``feature_norm``, ``clamp``, the widths, ``dropout``,
        ``n_samples``, ``model_grad``).

    Returns the filter with the best validation loss; ``knet.history`` holds the per-epoch training
    losses, every validation loss and its step, the best epoch and step, the attempts, whether and why
    training failed (``failed``: the network kept is an untrained one), the optimiser steps and the
    training CPU seconds.
    """
    if not isinstance(model, StateSpaceModel):
        raise TypeError(f"model must be an adaptfilt StateSpaceModel, got {type(model).__name__}")
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    for name, v in (("n_train", n_train), ("n_val", n_val), ("batch_size", batch_size)):
        if int(v) < 1:
            raise ValueError(f"{name} must be a positive integer, got {v}")
    for name, v in (("epochs", epochs), ("val_every", val_every), ("max_steps", max_steps), ("tbptt", tbptt),
                    ("patience", patience), ("collapse_after", collapse_after)):
        if v is not None and (int(v) != v or int(v) < 1):
            raise ValueError(f"{name} must be a positive integer or None, got {v}")
    if clip is not None and not float(clip) > 0:
        raise ValueError(f"clip must be a positive gradient norm or None, got {clip}")
    if max_cpu_s is not None and not float(max_cpu_s) > 0:
        raise ValueError(f"max_cpu_s must be a positive number of CPU seconds or None, got {max_cpu_s}")
    if epochs is None and max_steps is None and max_cpu_s is None:
        raise ValueError("epochs=None trains until a budget: give max_steps or max_cpu_s")
    if on_diverged not in ("raise", "restore", "stop", "restart"):
        raise ValueError(f"on_diverged must be 'raise', 'restore', 'stop' or 'restart', got {on_diverged!r}")
    if (int(restarts) != 0 or patience is not None) and on_diverged != "restart":
        raise ValueError("restarts and patience belong to the restart rule: give on_diverged='restart'")
    if int(restarts) < 0:
        raise ValueError(f"restarts must be >= 0, got {restarts}")
    if fresh not in FRESH:
        raise ValueError(f"fresh must be one of {FRESH}, got {fresh!r}")
    if fresh is not None and train is not None:
        raise ValueError("fresh draws new training trajectories: give no train set")
    if truth is not None and (not isinstance(truth, StateSpaceModel) or (truth.nx, truth.nz) != (model.nx, model.nz)):
        raise ValueError(f"truth must be a StateSpaceModel with the model's dimensions (nx={model.nx}, nz={model.nz}), "
                         f"got {truth!r}"[:300])
    if truth is not None and (train is not None or val is not None):
        raise ValueError("truth simulates the training and validation trajectories: give no train or val set")
    if not (math.isfinite(lr) and lr > 0):
        raise ValueError(f"lr must be positive, got {lr}")
    snaps = sorted({int(e) for e in snapshots})
    if snaps and (any(e < 1 or (epochs is not None and e > int(epochs)) for e in snaps)
                  or any(int(e) != e for e in snapshots)):
        raise ValueError(f"snapshots must be epochs in 1..epochs={epochs}, got {list(snapshots)}")
    if snaps and (val_every is not None or on_diverged == "restart"):
        raise ValueError("epoch snapshots need per-epoch validation and no restarts: use snapshot_steps")
    snap_steps = sorted({int(s) for s in snapshot_steps})
    if snap_steps and (val_every is None or any(s < 1 or s % int(val_every) for s in snap_steps)
                       or any(int(s) != s for s in snapshot_steps)):
        raise ValueError(f"snapshot_steps must be positive multiples of val_every={val_every}, got {list(snapshot_steps)}")
    if init is not None and options:
        raise ValueError(f"give either init or KalmanNet options ({', '.join(options)}), not both")
    if init is not None and int(restarts):
        raise ValueError("init continues one training: it cannot be restarted from new weights (restarts=0)")
    if init is not None and (init.model.name, init.model.nx, init.model.nz) != (model.name, model.nx, model.nz):
        raise ValueError(f"init is a KalmanNet for model {init.model.name!r}, not for {model.name!r}")
    if checkpoint is not None and (train is not None or val is not None or init is not None):
        raise ValueError("a checkpoint resumes a training that simulates its own data: give no train, val or init")
    if checkpoint_every is None:
        checkpoint_every = CHECKPOINT_EVERY_S
    if not (math.isfinite(checkpoint_every) and checkpoint_every >= 0):
        raise ValueError(f"checkpoint_every must be a number of seconds >= 0, got {checkpoint_every}")
    grad = (init.options if init is not None else options).get("model_grad", "jacobian")
    if loss == "unsupervised" and grad == "detach":
        raise ValueError("the unsupervised loss reaches the weights only through f and h: use model_grad='jacobian'")
    args = dict(locals(), snaps=snaps, snap_steps=snap_steps)
    return _Training(model, args).run()


class _Training:
    """The state of one :func:`train_kalmannet` call: attempts, budget, best network, snapshots.

    The loop reads top to bottom in :meth:`attempt`: per epoch, per minibatch, per window one
    optimiser step, then the validation schedule, the restart rule and the budget.
    """

    def __init__(self, model: StateSpaceModel, a: dict):
        self.cpu0 = time.process_time()
        self.cpu_before = 0.0         # CPU seconds of the sittings before a resume (a checkpoint's)
        self.resumed_at: list[int] = []
        self.model, self.a = model, a
        self.ds = int(a["seed"] if a["data_seed"] is None else a["data_seed"])
        self.sim = model if a["truth"] is None else a["truth"]  # what the trajectories are simulated from
        train, val = a["train"], a["val"]
        T = a["n_steps"] or (train.n_steps if train is not None else model.n_steps)
        if (train is None or val is None) and T is None:
            raise ValueError(f"model {model.name!r} has no horizon: give n_steps")
        self.train = None
        if a["fresh"] is None:
            self.train = _check_traj(train, model, "train") if train is not None else self.sim.simulate(
                int(a["n_train"]), T, rng=np.random.default_rng([self.ds, 0]))
            T = self.train.n_steps
        self.val = _check_traj(val, model, "val") if val is not None else self.sim.simulate(
            int(a["n_val"]), T, rng=np.random.default_rng([self.ds, 1]))
        self.T = T
        self.n_train = self.train.n_runs if self.train is not None else int(a["n_train"])
        self.window = T if a["tbptt"] is None else int(a["tbptt"])
        self.per_epoch = a["val_every"] is None
        self.step = 0                 # optimiser steps, all attempts together
        self.best = math.inf          # best validation loss over all attempts
        self.best_state = None
        self.best_knet = None         # the attempt's filter the best weights belong to
        self.best_trained = False     # whether the best is a trained network (not an initial one)
        self.kept: dict = {}          # ("epoch", e) / ("step", S) -> (weights, history, filter)
        self.hist = {
            "train_loss": [], "val_loss": [], "best_epoch": 0, "loss": a["loss"], "epochs": _int(a["epochs"]),
            "batch_size": int(a["batch_size"]), "lr": float(a["lr"]), "weight_decay": float(a["weight_decay"]),
            "tbptt": _int(a["tbptt"]), "clip": _float(a["clip"]), "n_train": self.n_train, "n_val": self.val.n_runs,
            "n_steps": int(T), "data_seed": self.ds, "calibration": float(a["calibration"]),
            "on_diverged": a["on_diverged"], "restores": [], "max_cpu_s": _float(a["max_cpu_s"]),
            "stopped_by_budget": False, "stopped_by_divergence": None, "seed": int(a["seed"]), "fresh": a["fresh"],
            "val_every": _int(a["val_every"]), "max_steps": _int(a["max_steps"]), "restarts": int(a["restarts"]),
            "patience": _int(a["patience"]), "val_steps": [], "best_step": 0, "best_attempt": 0, "attempts": [],
            "n_restarts": 0, "failed": None, "trajectories_seen": self.n_train if self.train is not None else 0,
            "trajectory_steps": 0}
        if a["truth"] is not None:  # recorded only when set: files made before the option existed stay reproducible
            self.hist["truth"] = a["truth"].description
        if a["collapse_after"] is not None:  # the same
            self.hist["collapse_after"] = int(a["collapse_after"])
        self.ckpt = None if a["checkpoint"] is None else Path(a["checkpoint"])
        self.ckpt_time = time.monotonic()
        self.resume = self.read_checkpoint() if self.ckpt is not None else None

    def cpu(self) -> float:
        """Process CPU seconds of the training, every sitting together."""
        return self.cpu_before + time.process_time() - self.cpu0

    # ------------------------------------------------------------------ the whole training
    def run(self) -> KalmanNet:
        a = self.a
        self.bar = None
        if a["progress"]:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=a["max_steps"], desc=f"train KalmanNet ({self.model.name})", unit="step", leave=False,
                            initial=0 if self.resume is None else self.resume[1]["step"])
        try:
            with one_torch_thread(), torch.random.fork_rng(devices=[]), np.errstate(over="ignore", invalid="ignore"):
                # numpy's overflow warnings of a diverging estimate are replaced by the check of the loss
                attempt = 0 if self.resume is None else self.resume[1]["attempt"]
                while True:
                    end = self.attempt(attempt, self.resume)
                    self.resume = None
                    if end in ("diverged", "no progress") and attempt < int(a["restarts"]) and not self.spent():
                        attempt += 1
                        continue
                    break
        finally:
            if self.bar is not None:
                self.bar.close()
        return self.finish()

    def spent(self) -> bool:
        a = self.a
        return ((a["max_steps"] is not None and self.step >= int(a["max_steps"]))
                or (a["max_cpu_s"] is not None and self.cpu() >= float(a["max_cpu_s"])))

    # ------------------------------------------------------------------ one attempt
    def attempt(self, n: int, resume: tuple[dict, dict] | None = None) -> str:
        """Train attempt ``n`` until its end: "epochs", "budget", "diverged", "no progress" or "stopped"; from
        where a checkpoint left it with ``resume`` (:meth:`read_checkpoint`)."""
        a = self.a
        seed = restart_seed(a["seed"], n)
        self.knet = knet = self.attempt_filter(n)
        self.opt = torch.optim.Adam(knet.net.parameters(), lr=a["lr"], weight_decay=a["weight_decay"])
        order_rng = np.random.default_rng([seed, 2])
        torch.manual_seed(seed + 1)
        z_prev_fixed = knet._z_prev(self.train.z) if self.train is not None else None
        if resume is None:
            self.att = {"seed": seed, "first_step": self.step, "last_step": self.step, "epochs": 0, "init_val": None,
                        "best_val": None, "best_step": self.step, "restores": 0, "end": None}
            self.hist["attempts"].append(self.att)
            self.hist["n_restarts"] = n
            self.n = n
            self.improved = False
            self.above = 0  # validations in a row above the attempt's initial loss (collapse_after)
            v = _evaluate(knet, self.val, a["loss"], a["calibration"])
            # an untrained filter that diverges on validation: any finite network beats it
            self.att_best = self.att["init_val"] = v if math.isfinite(v) else math.inf
            self.record_val(self.att_best)
            self.att_state = copy.deepcopy(knet.net.state_dict())
            self.consider(self.att_best, epoch=0, trained=False)
            epoch, b0, t00, carry0, losses0 = 1, 0, 0, None, []
        else:
            epoch, b0, t00, carry0, losses0 = self.load_state(resume, order_rng)
        end = None
        while end is None:
            if a["epochs"] is not None and epoch > int(a["epochs"]):
                end = "epochs"
                break
            knet.net.train()
            losses = losses0
            self.order_state = copy.deepcopy(order_rng.bit_generator.state)  # where this epoch's order is drawn from
            for b, (z, zp, x) in self.minibatches(n, epoch, order_rng, z_prev_fixed, b0, t00 > 0):
                carry = carry0 if (b == b0 and t00 > 0) else knet._start(len(z))
                x = torch.from_numpy(x)
                for t0 in range(t00 if b == b0 else 0, self.T, self.window):
                    t1 = min(self.T, t0 + self.window)
                    out, carry = knet._window(z[:, t0:t1], zp[:, t0:t1], t0, carry)
                    ell = _loss(knet, out, x[:, t0:t1], a["loss"], a["calibration"])
                    self.step += 1
                    where = f"epoch {epoch}, optimiser step {self.step} (steps {t0}..{t1 - 1})"
                    broke = False
                    if not torch.isfinite(ell):
                        end, broke = self.diverged(f"non-finite loss at {where}", epoch), True
                    else:
                        self.opt.zero_grad()
                        ell.backward()
                        params = knet.net.parameters()
                        if a["clip"] is not None:
                            gnorm = nn.utils.clip_grad_norm_(params, float(a["clip"]))
                        else:
                            gnorm = torch.sqrt(sum((p.grad ** 2).sum() for p in params if p.grad is not None))
                        if not torch.isfinite(gnorm):
                            end, broke = self.diverged(f"non-finite gradient at {where}", epoch), True
                        else:
                            self.opt.step()
                            carry = carry.detach()
                            losses.append(float(ell.detach()))
                            self.hist["trajectory_steps"] += len(z) * (t1 - t0)
                    end = end or self.after_step(epoch)
                    if self.bar is not None:
                        self.bar.update(1)
                    if end is not None or broke:  # a diverged step skips the rest of its minibatch
                        break
                    if not self.per_epoch and self.step % int(a["val_every"]) == 0:
                        # just validated: the loop's state is whole here, and the next step comes from it
                        go_on = t1 < self.T
                        self.write_checkpoint(epoch, b if go_on else b + 1, t1 if go_on else 0,
                                              carry if go_on else None, losses)
                if end is not None:
                    break
            b0, t00, carry0, losses0 = 0, 0, None, []
            self.att["epochs"] = epoch
            if end == "stopped":
                break
            self.hist["train_loss"].append(float(np.mean(losses)) if losses else math.nan)
            if self.per_epoch and end in (None, "budget"):
                end = self.validate_epoch(epoch) or end
                if end is None and (a["epochs"] is None or epoch < int(a["epochs"])):  # else the last epoch ended
                    self.order_state = copy.deepcopy(order_rng.bit_generator.state)
                    self.write_checkpoint(epoch + 1, 0, 0, None, [])
            epoch += 1
        self.att["end"], self.att["last_step"] = end, self.step
        self.keep_step_snapshot()  # a snapshot step at which the attempt ended
        return end

    def attempt_filter(self, n: int) -> KalmanNet:
        """Attempt ``n``'s filter before training: its weights from :func:`restart_seed` (or ``init``)."""
        a = self.a
        if a["init"] is not None:
            return copy.deepcopy(a["init"])
        return KalmanNet(self.model, seed=restart_seed(a["seed"], n), **a["options"])

    def minibatches(self, n: int, epoch: int, order_rng: np.random.Generator, z_prev_fixed, start: int = 0,
                    counted: bool = False):
        """``(b, (z, z_prev, x))`` of each minibatch ``b`` of an epoch: from the fixed set in a seeded order, or
        simulated; from minibatch ``start`` on (a resumed epoch: ``counted`` when minibatch ``start`` was begun,
        its trajectories already counted in ``trajectories_seen``)."""
        a, bs = self.a, int(self.a["batch_size"])
        if a["fresh"] == "batch":
            for b, i in enumerate(range(0, self.n_train, bs)):
                if b < start:
                    continue
                tr = self.sim.simulate(min(bs, self.n_train - i), self.T,
                                         rng=np.random.default_rng([self.ds, 4, n, epoch, b]))
                if not (counted and b == start):
                    self.hist["trajectories_seen"] += tr.n_runs
                yield b, (tr.z, self.knet._z_prev(tr.z), tr.x)
            return
        if a["fresh"] == "epoch":
            tr = self.sim.simulate(self.n_train, self.T, rng=np.random.default_rng([self.ds, 3, n, epoch]))
            if start == 0 and not counted:
                self.hist["trajectories_seen"] += tr.n_runs
            z_all, zp_all, x_all = tr.z, self.knet._z_prev(tr.z), tr.x
        else:
            z_all, zp_all, x_all = self.train.z, z_prev_fixed, self.train.x
        perm = order_rng.permutation(self.n_train)
        for b, i in enumerate(range(0, self.n_train, bs)):
            if b >= start:
                idx = np.sort(perm[i:i + bs])
                yield b, (z_all[idx], zp_all[idx], x_all[idx])

    # ------------------------------------------------------------------ after each optimiser step
    def after_step(self, epoch: int) -> str | None:
        """The validation schedule, the snapshots and the budget, after an optimiser step."""
        end = None
        if not self.per_epoch and self.step % int(self.a["val_every"]) == 0:
            end = self.validate_step(epoch)
        if end is None and self.spent():
            self.hist["stopped_by_budget"] = True
            end = "budget"
            if not self.per_epoch and self.hist["val_steps"][-1] != self.step:
                end = self.validate_step(epoch, final=True) or end
        self.keep_step_snapshot()
        return end

    def record_val(self, v: float) -> None:
        self.hist["val_loss"].append(v)
        self.hist["val_steps"].append(self.step)
        if self.bar is not None:
            self.bar.set_postfix(val=f"{v:.4g}", attempt=self.n)

    def consider(self, v: float, epoch: int, trained: bool) -> None:
        """Keep the attempt's current network if ``v`` is the best validation loss over all attempts."""
        if v < self.best or self.best_state is None:
            self.best, self.best_state, self.best_knet = v, copy.deepcopy(self.knet.net.state_dict()), self.knet
            self.best_trained = trained
            self.hist.update(best_epoch=epoch, best_step=self.step, best_attempt=self.n)

    def improve(self, v: float, epoch: int) -> None:
        """A finite validation loss ``v`` of the attempt's network after training."""
        if v < self.att_best:
            self.att_best, self.att_state, self.improved = v, copy.deepcopy(self.knet.net.state_dict()), True
            self.att.update(best_val=v, best_step=self.step)
            self.consider(v, epoch, trained=True)

    def validate_epoch(self, epoch: int) -> str | None:
        v = _evaluate(self.knet, self.val, self.a["loss"], self.a["calibration"])
        self.record_val(v)
        if not math.isfinite(v):
            return self.diverged(f"non-finite validation loss after epoch {epoch}", epoch)
        self.improve(v, epoch)
        if (end := self.collapsed(v, epoch)) is not None:
            return end
        if epoch in self.a["snaps"]:
            self.keep(("epoch", epoch), epochs=epoch)
        return self.no_progress()

    def validate_step(self, epoch: int, final: bool = False) -> str | None:
        v = _evaluate(self.knet, self.val, self.a["loss"], self.a["calibration"])
        self.record_val(v)
        if not math.isfinite(v):
            return self.diverged(f"non-finite validation loss after optimiser step {self.step}", epoch)
        self.improve(v, epoch)
        if (end := self.collapsed(v, epoch)) is not None:
            return end
        return None if final else self.no_progress()

    def collapsed(self, v: float, epoch: int) -> str | None:
        """``collapse_after``: a finite validation loss above the attempt's initial network's for that many
        validations in a row, after the attempt had beaten it, is a divergence (:meth:`diverged`: under the
        restart rule the best weights at half the learning rate); None otherwise or when it restores."""
        n = self.a["collapse_after"]
        if n is None:
            return None
        self.above = self.above + 1 if self.improved and v > self.att["init_val"] else 0
        if self.above < int(n):
            return None
        self.above = 0
        return self.diverged(f"validation loss above the untrained network's ({self.att['init_val']:.4g}) for {n} "
                             f"validations in a row, to optimiser step {self.step}", epoch)

    def no_progress(self) -> str | None:
        """The restart rule's patience: "no progress" when the attempt has not beaten its initial network."""
        patience, steps = self.a["patience"], self.step - self.att["first_step"]
        if patience is None or self.improved or steps < int(patience) or self.n >= int(self.a["restarts"]):
            return None  # the last attempt allowed trains on to the budget: it may still improve
        _warn(f"KalmanNet training: attempt {self.n} (seed {self.att['seed']}) has not beaten its initial "
              f"network in {steps} optimiser steps; abandoned")
        return "no progress"

    def diverged(self, what: str, epoch: int) -> str | None:
        """A non-finite loss, gradient or validation loss: restore (None: training goes on), or end the attempt
        ("diverged", "stopped"), or raise (``on_diverged``)."""
        a, msg = self.a, f"KalmanNet training: {what}"
        mode, n_restores = a["on_diverged"], len(self.hist["restores"])
        if mode == "restart":
            if self.improved and self.att["restores"] < int(a["max_restores"]):
                return self.restore(msg, epoch)
            _warn(msg + f"; attempt {self.n} (seed {self.att['seed']}) abandoned")
            self.att["diverged"] = {"epoch": epoch, "step": self.step, "what": what}
            return "diverged"
        if mode == "raise" or n_restores >= int(a["max_restores"]):
            extra = f" after {n_restores} restores" if mode != "raise" else ""
            if mode == "stop":
                _warn(msg + extra + "; training stopped with the best weights so far")
                self.hist["stopped_by_divergence"] = {"epoch": epoch, "step": self.step, "what": what}
                self.knet.net.load_state_dict(self.att_state)
                return "stopped"
            raise TrainingDiverged(msg + extra + "; try clip=..., a smaller lr, tbptt=..., clamp=... or another "
                                   "feature_norm")
        return self.restore(msg, epoch)

    def restore(self, msg: str, epoch: int) -> None:
        lr_now = self.opt.param_groups[0]["lr"] * 0.5
        _warn(msg + f"; restored the best weights so far, learning rate halved to {lr_now:.3g}")
        self.hist["restores"].append({"epoch": epoch, "step": self.step, "what": msg.split(": ", 1)[1],
                                      "lr": lr_now})
        self.att["restores"] += 1
        self.knet.net.load_state_dict(self.att_state)
        self.opt = torch.optim.Adam(self.knet.net.parameters(), lr=lr_now, weight_decay=self.a["weight_decay"])
        return None

    # ------------------------------------------------------------------ snapshots and the result
    def history_now(self, **update) -> dict:
        h = copy.deepcopy(self.hist)
        h.update(best_val_loss=self.best, optimiser_steps=self.step, cpu_s=self.cpu(),
                 failed=None if self.best_trained else self.failure(), **update)
        return h

    def keep(self, key: tuple, **update) -> None:
        self.kept[key] = (copy.deepcopy(self.best_state), self.history_now(**update), self.best_knet)

    def keep_step_snapshot(self) -> None:
        if self.step in self.a["snap_steps"] and ("step", self.step) not in self.kept:
            self.keep(("step", self.step), max_steps=self.step)

    def failure(self) -> str:
        n = len(self.hist["attempts"])
        return (f"no attempt beat its initial network on validation ({n} attempt{'s' * (n > 1)}, "
                f"{self.step} optimiser steps): the network kept is untrained")

    def finish(self) -> KalmanNet:
        a = self.a
        for e in a["snaps"]:  # epochs after a divergence that stopped training: the filter a longer training returns
            if ("epoch", e) not in self.kept and self.hist["stopped_by_divergence"]:
                self.keep(("epoch", e), epochs=e)
        for s in a["snap_steps"]:  # steps after the end of training: a longer budget returns the same filter
            if ("step", s) not in self.kept:
                self.keep(("step", s), max_steps=s)
        knet = self.best_knet
        knet.net.load_state_dict(self.best_state)
        knet.net.eval()
        self.hist.update(best_val_loss=self.best, optimiser_steps=self.step, cpu_s=self.cpu())
        if not self.best_trained:
            self.hist["failed"] = self.failure()
            _warn(f"KalmanNet training failed: {self.hist['failed']}")
        knet.history = self.hist
        knet._snapshots = self.kept
        knet.resumed_at = list(self.resumed_at)
        return knet

    # ------------------------------------------------------------------ checkpoints
    def fingerprint(self) -> dict:
        """What a checkpoint must have been made by: this call's arguments (the models by their name, description,
        horizon and matrices) and the package version, as the journal identifies a job (JSON's own types)."""
        a = self.a
        skip = {"model", "truth", "train", "val", "init", "progress", "checkpoint", "checkpoint_every", "options",
                "snaps", "snap_steps"}

        def words(m: StateSpaceModel | None):  # f and h are functions: their name and the description stand for them
            return None if m is None else [m.name, m.description, m.n_steps, list(m.circular_z)] + [
                None if v is None else np.asarray(v).tolist() for v in (m.Q, m.R, m.m0, m.P0, m.F, m.H)]

        args = {k: v for k, v in a.items() if k not in skip}
        args.update(model=words(self.model), truth=words(a["truth"]), options=a["options"], snapshots=a["snaps"],
                    snapshot_steps=a["snap_steps"], version=__version__)
        return json.loads(json.dumps(args, sort_keys=True, default=_plain))

    def write_checkpoint(self, epoch: int, b: int, t0: int, carry: "_Carry | None", losses: list) -> None:
        """The loop's whole state after the validation just made, where the next optimiser step is minibatch ``b``
        of ``epoch`` from window start ``t0`` (``carry``: the estimate and GRU states at ``t0``)."""
        if self.ckpt is None or time.monotonic() - self.ckpt_time < float(self.a["checkpoint_every"]):
            return
        arrays = {**state_to_arrays("net", self.knet.net), **state_to_arrays("best", self.best_state),
                  **state_to_arrays("attempt", self.att_state), **adam_to_arrays("adam", self.opt),
                  "torch_rng": torch.get_rng_state().numpy().copy()}
        kept = []
        for i, ((kind, at), (weights, hist, _)) in enumerate(self.kept.items()):
            arrays.update(state_to_arrays(f"kept{i}", weights))
            kept.append([kind, at, hist])
        if carry is not None:
            parts = {"x_filt": carry.x_filt, "x_filt_prev": carry.x_filt_prev, "x_pred": carry.x_pred,
                     **{f"h{j}": h for j, h in enumerate(carry.h)}, **({} if carry.mask is None else {"mask": carry.mask})}
            arrays.update({f"carry/{k}": v.detach().numpy().copy() for k, v in parts.items()})
        meta = {"format": CHECKPOINT_FORMAT, "fingerprint": self.fingerprint(), "attempt": self.n, "step": self.step,
                "position": [epoch, b, t0], "losses": losses, "hist": self.hist, "best": self.best,
                "best_trained": self.best_trained, "attempt_best": self.att_best, "improved": self.improved,
                "above": self.above, "lr": self.opt.param_groups[0]["lr"], "order_state": self.order_state,
                "cpu_s": self.cpu(), "resumed_at": self.resumed_at, "kept": kept}
        write_npz(self.ckpt, arrays, meta)
        self.ckpt_time = time.monotonic()

    def read_checkpoint(self) -> tuple[dict, dict] | None:
        """The arrays and record of the checkpoint this call resumes from; None if there is none. ValueError for a
        file that is not one or that another training wrote, naming what differs."""
        if not self.ckpt.is_file():
            return None
        arrays, meta = read_npz(self.ckpt, "adaptfilt KalmanNet checkpoint")
        if meta.get("format") != CHECKPOINT_FORMAT:
            raise ValueError(f"{self.ckpt}: not an adaptfilt KalmanNet checkpoint (format {meta.get('format')!r})")
        mine, theirs = self.fingerprint(), meta.get("fingerprint", {})
        diff = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
        if diff:
            def short(v) -> str:
                r = repr(v)
                return r if len(r) <= 40 else r[:37] + "..."

            said = "; ".join(f"{k} {short(theirs.get(k))} there, {short(mine.get(k))} here" for k in diff[:3])
            raise ValueError(f"checkpoint {self.ckpt} was written by a different training ({said}); delete it to "
                             f"train from the start")
        print(f"adaptfilt: KalmanNet training resumed at optimiser step {meta['step']} from {self.ckpt}",
              file=sys.stderr)
        return arrays, meta

    def load_state(self, resume: tuple[dict, dict], order_rng: np.random.Generator):
        """Put the loop back where :meth:`write_checkpoint` left it; its position ``(epoch, b, t0, carry,
        losses)``."""
        arrays, r = resume
        self.hist, self.step, self.n = r["hist"], int(r["step"]), int(r["attempt"])
        self.att = self.hist["attempts"][-1]  # the attempt's record is the history's last one, not a copy of it
        self.best, self.best_trained = r["best"], r["best_trained"]
        self.best_state, self.att_state = arrays_to_state("best", arrays), arrays_to_state("attempt", arrays)
        self.att_best, self.improved, self.above = r["attempt_best"], r["improved"], int(r["above"])
        self.cpu_before, self.cpu0 = float(r["cpu_s"]), time.process_time()
        self.resumed_at = list(r["resumed_at"]) + [self.step]
        filters = {self.n: self.knet}  # the filters the best and the kept weights belong to, rebuilt by attempt
        for k in {int(self.hist["best_attempt"])} | {int(h["best_attempt"]) for _, _, h in r["kept"]}:
            if k not in filters:
                filters[k] = self.attempt_filter(k)
        self.best_knet = filters[int(self.hist["best_attempt"])]
        self.kept = {(kind, int(at)): (arrays_to_state(f"kept{i}", arrays), h, filters[int(h["best_attempt"])])
                     for i, (kind, at, h) in enumerate(r["kept"])}
        self.knet.net.load_state_dict(arrays_to_state("net", arrays))
        arrays_to_adam("adam", self.opt, arrays)
        self.opt.param_groups[0]["lr"] = r["lr"]  # halved by each restore
        torch.set_rng_state(torch.from_numpy(arrays["torch_rng"].copy()))
        order_rng.bit_generator.state = r["order_state"]
        epoch, b, t0 = (int(v) for v in r["position"])
        carry = None
        if "carry/x_filt" in arrays:
            c = arrays_to_state("carry", arrays)
            h = tuple(c[f"h{j}"] for j in range(sum(k.startswith("h") for k in c)))
            carry = _Carry(c["x_filt"], c["x_filt_prev"], c["x_pred"], h, c.get("mask"))
        return epoch, b, t0, carry, list(r["losses"])


def _int(x) -> int | None:
    return None if x is None else int(x)


def _float(x) -> float | None:
    return None if x is None else float(x)


def _plain(x):
    """JSON for what json cannot write itself: numpy numbers as Python's, anything else by its repr."""
    return x.item() if isinstance(x, np.generic) else repr(x)
