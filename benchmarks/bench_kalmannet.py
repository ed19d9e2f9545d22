"""Cost of training KalmanNet against the kappa learner's fast mode, per trajectory-step, in one run.

Run with ``python benchmarks/bench_kalmannet.py`` (``--quick``: a smoke run of a few seconds, as
``tests/test_kalmannet.py`` runs it). Process CPU seconds (``time.process_time``), torch on one
thread, one training after another in this process:

* **KalmanNet** (:func:`adaptfilt.kalmannet.train_kalmannet`, both architectures), a training of
  ``--knet-steps`` optimiser steps with each model's and architecture's recipe (:data:`adaptfilt.kalmannet.RECIPES`,
  the learned-gain study's): minibatches of ``--batch`` fresh trajectories of the model's horizon, batched as one
  tensor per step, truncated back-propagation over the recipe's windows (``--window`` overrides; one optimiser
  step per window), validation on ``--n-val`` trajectories every ``--val-every`` steps, the state clamped. The
  whole training is timed (set-up, simulation, validation, the forward and backward passes) and
  divided by the trajectory-steps it back-propagated (``history["trajectory_steps"]``).
* **The kappa learner**, the fast mode (SB3 PPO over 256 runs of the UKF) with the learned-gain study's
  recipe for the model (:data:`adaptfilt.experiments.studies.gain.KAPPA_RECIPES`: learning rate and PPO epochs),
  ``--ppo-episodes`` episodes: the whole training
  divided by its transitions (one filter step of one run, with its policy step and its share of the
  updates).

The ratio KalmanNet / PPO is printed per model and architecture: the cost of a trajectory-step of
the learned gain's training in units of a PPO transition of the learned kappa's. UNGM's f and h run
in torch through the model's torch forms (``model_grad="jacobian"``); the row "numpy f, h" takes the
old path (numpy functions, forward-difference Jacobians) for comparison. The filtering speed of the
trained networks (no gradients, ``--runs`` runs batched) is printed next, and last the cost of a training's
checkpoints (``train_kalmannet(checkpoint=...)``, one written at every validation of the last model's architecture-2
training): process CPU per write, the file's size, and its share of a training at the default interval.

Measured (2026-11-29, ``python benchmarks/bench_kalmannet.py``, this 2-core machine beside the learned-gain
study's two training workers; microseconds of process CPU per trajectory-step or transition, ratio to PPO):

======  ============================  =======  ======
model   training                      us       / PPO
======  ============================  =======  ======
UNGM    kappa, PPO (study recipe)     23.9
UNGM    gain, architecture 1          16.4     0.69
UNGM    gain, architecture 2          16.8     0.70
UNGM    gain, arch. 2, numpy f, h     17.5     0.73
CTM     kappa, PPO (study recipe)     35.3
CTM     gain, architecture 1          105.4    2.99
CTM     gain, architecture 2          24.7     0.70
======  ============================  =======  ======

On both models a trajectory-step of the study's KalmanNet (architecture 2 on the CTM, both on UNGM) costs
about 0.7 of a PPO transition of the study's kappa learner (the CTM's PPO runs 10 epochs a rollout). On the
CTM architecture 1 at the paper's sizes (GRUs of ``10 (m^2 + n^2) = 170`` units over an input layer of
400: about 470,000 weights against architecture 2's 20,293) is bound by its matrix products: 3.0
transitions per trajectory-step (the study does not train it: its tuning chose architecture 2). Filtering
(no gradients, 2000 runs batched): 0.50 (architecture 1) and 2.3 (architecture 2) million run-steps per
CPU-s on UNGM.
"""
from __future__ import annotations

import argparse
import platform
import time
import warnings

import numpy as np
import torch

import adaptfilt as af
from adaptfilt.experiments.studies.gain import KAPPA_RECIPES
from adaptfilt.kalmannet import CHECKPOINT_EVERY_S, RECIPES, train_kalmannet
from adaptfilt.trainers import FAST, SB3Config, train_policy, train_sb3

MODELS = {"ungm": ("ungm-ukf", af.models.ungm), "ctm": ("ctm-ukf", af.models.coordinated_turn)}


def knet_cost(key: str, model, arch: int, a, **extra) -> tuple[float, dict, object]:
    """Process CPU-s per back-propagated trajectory-step of one KalmanNet training, its history, the filter."""
    c0 = time.process_time()
    recipe = dict(RECIPES[key][arch], n_train=a.batch, n_val=a.n_val, batch_size=a.batch, val_every=a.val_every,
                  **extra)
    if a.window:
        recipe["tbptt"] = a.window
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a short training may fail or restart: the cost is what counts
        knet = train_kalmannet(model, n_steps=a.steps or model.n_steps, max_steps=a.knet_steps, seed=0, progress=False,
                               **recipe)
    cpu = time.process_time() - c0
    return cpu / knet.history["trajectory_steps"], knet.history, knet


def checkpoint_cost(key: str, model, arch: int, a) -> tuple[int, float, float, float]:
    """One KalmanNet training (the recipe, as :func:`knet_cost`) that writes a checkpoint at every validation:
    the writes, process CPU-s per write, the largest file in bytes, and the training's CPU-s per validation."""
    import tempfile
    from pathlib import Path

    from adaptfilt import kalmannet

    write, cpu, size = kalmannet._Training.write_checkpoint, [], [0]

    def timed(self, *args):
        c0 = time.process_time()
        write(self, *args)
        cpu.append(time.process_time() - c0)
        size[0] = max(size[0], self.ckpt.stat().st_size)

    kalmannet._Training.write_checkpoint = timed
    try:
        with tempfile.TemporaryDirectory() as d:
            c0 = time.process_time()
            _, h, _ = knet_cost(key, model, arch, a, checkpoint=Path(d) / "t.ckpt.npz", checkpoint_every=0)
            total = time.process_time() - c0
    finally:
        kalmannet._Training.write_checkpoint = write
    return len(cpu), sum(cpu) / max(1, len(cpu)), size[0], total / len(h["val_steps"])


def ppo_cost(experiment: str, a) -> tuple[float, int]:
    """Process CPU-s per transition of one training of the kappa learner (the study's recipe), and its transitions."""
    r = KAPPA_RECIPES[experiment]
    cfg = SB3Config("ppo", FAST.n_envs, {**FAST.kwargs, "learning_rate": r["lr"], "n_epochs": r["n_epochs"]})
    c0 = time.process_time()
    pol = train_sb3(experiment, 0.5, a.ppo_episodes, 0, cfg, progress=False, n_steps=a.steps)
    cpu = time.process_time() - c0
    n = int(pol.metadata["transitions"])
    return cpu / n, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="ungm,ctm")
    r = RECIPES["ungm"][1]
    ap.add_argument("--knet-steps", type=int, default=500, help="KalmanNet optimiser steps per training")
    ap.add_argument("--batch", type=int, default=r["batch_size"])
    ap.add_argument("--window", type=int, default=None, help="window length (default: each recipe's)")
    ap.add_argument("--n-val", type=int, default=r["n_val"])
    ap.add_argument("--val-every", type=int, default=r["val_every"])
    ap.add_argument("--ppo-episodes", type=int, default=400)
    ap.add_argument("--runs", type=int, default=2000)
    ap.add_argument("--steps", type=int, default=None, help="horizon (default: each model's)")
    ap.add_argument("--quick", action="store_true", help="tiny sizes: a smoke run")
    a = ap.parse_args()
    if a.quick:
        a.knet_steps, a.batch, a.window, a.n_val, a.val_every, a.ppo_episodes, a.runs, a.steps = 4, 8, 10, 4, 2, 2, 20, 20
    torch.set_num_threads(1)
    print(f"{platform.processor() or platform.machine()}, torch {torch.__version__}, one thread; process CPU-s")
    print(f"KalmanNet: {a.knet_steps} optimiser steps, minibatches of {a.batch} fresh trajectories, windows of "
          f"{a.window or 'the recipe'}, validation on {a.n_val} every {a.val_every} steps; PPO fast mode: {a.ppo_episodes} episodes")
    # warm-up (torch's first calls allocate and dispatch-cache; SB3's imports): not timed
    train_kalmannet(af.models.ungm(), n_train=4, n_val=2, n_steps=20, epochs=1, batch_size=4, seed=0, progress=False)
    train_policy("ungm-ukf", "fast", episodes=1, seed=0, progress=False, n_steps=20)
    rows, ratios = [], {}
    for key in a.models.split(","):
        experiment, make = MODELS[key]
        model = make()
        ppo, n_tr = ppo_cost(experiment, a)
        rows.append((key, "kappa, PPO (study recipe)", ppo, n_tr, "", ""))
        cases = [(1, {}, "gain, architecture 1"), (2, {}, "gain, architecture 2")]
        if key == "ungm":
            cases.append((2, {"model_grad": "finite-difference"}, "gain, arch. 2, numpy f, h"))
        for arch, extra, label in cases:
            c, h, knet = knet_cost(key, model, arch, a, **extra)
            ratios[key, label] = c / ppo
            z = model.simulate(a.runs, a.steps or model.n_steps, rng=123).z
            t0 = time.process_time()
            with np.errstate(over="ignore", invalid="ignore"):
                knet.run(z)
            filt = a.runs * z.shape[1] / (time.process_time() - t0)
            rows.append((key, label, c, h["trajectory_steps"], f"{c / ppo:.2f}", f"{filt:,.0f}"))
    print(f"\n{'model':<6} {'training':<28} {'us per traj-step':>16} {'traj-steps':>11} {'/ PPO':>6} "
          f"{'filtering run-steps/CPU-s':>26}")
    for key, label, c, n, r, f in rows:
        print(f"{key:<6} {label:<28} {c * 1e6:>16.1f} {n:>11,d} {r:>6} {f:>26}")
    for (key, label), r in ratios.items():
        if label.endswith("architecture 2") or label.endswith("architecture 1"):
            print(f"{key}: {label}: a trajectory-step of training costs {r:.2f} PPO transitions "
                  f"({'within' if r <= 2 else 'NOT within'} 2x)")
    key = a.models.split(",")[-1]
    n, per, size, per_val = checkpoint_cost(key, MODELS[key][1](), 2, a)
    print(f"{key}: checkpoints (architecture 2, one at each of {n} validations): {per * 1e3:.1f} ms of process CPU "
          f"per write, {size / 1e3:,.0f} kB; {per / per_val:.1%} of the training's CPU between two validations; at "
          f"the default interval ({CHECKPOINT_EVERY_S:g} s of wall time) about {per / CHECKPOINT_EVERY_S:.3%} of a "
          f"training")


if __name__ == "__main__":
    main()
