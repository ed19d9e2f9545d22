"""Cost of KalmanNet (adaptfilt.kalmannet) on UNGM: training CPU-s per epoch, filtering speed.

Run with ``python benchmarks/bench_kalmannet.py`` (``--quick`` for a smoke run). It sizes the
budgets of the learned-gain study (``adaptfilt beyond --studies gain``).

* Training: one epoch = ``--n-train`` trajectories of UNGM's full horizon (T = 500), minibatches of
  ``--batch`` whole trajectories, back-propagation through the whole sequence (or ``--tbptt``
  windows), plus one validation pass over ``--n-val`` trajectories (the trainer validates once per
  epoch). Reported: process CPU seconds per epoch (torch on one thread, as the trainer runs it),
  per optimiser step and per trajectory-step (forward + backward).
* Filtering: ``--runs`` runs x 500 steps with the trained network, no gradients; reported as
  run-steps per second (one filter step of one Monte-Carlo run), CPU time, and the RMSE over the
  runs whose estimate stayed finite, with the number of diverged runs (a short training on UNGM
  leaves an unstable gain on some runs).

Both for the plain filter and the Bayesian variant (J = ``--samples`` dropout copies, which costs
about J times more per run-step). UNGM's f and h are numpy: training back-propagates through them
with forward-difference Jacobians (``model_grad="jacobian"``).
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np
import torch

import adaptfilt as af
from adaptfilt.kalmannet import train_kalmannet


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-train", type=int, default=60)
    ap.add_argument("--n-val", type=int, default=20)
    ap.add_argument("--batch", type=int, default=20)
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--tbptt", type=int, default=None)
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--samples", type=int, default=10)
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--quick", action="store_true", help="20 trajectories of 50 steps, 100 runs")
    a = ap.parse_args()
    if a.quick:
        a.n_train, a.n_val, a.batch, a.epochs, a.runs, a.steps = 20, 10, 10, 1, 100, 50
    torch.set_num_threads(1)
    model = af.models.ungm()
    print(f"KalmanNet on UNGM, T = {a.steps}; {platform.processor() or platform.machine()}, torch {torch.__version__}, "
          f"one thread")
    print(f"training: {a.n_train} trajectories/epoch, batch {a.batch}, validation {a.n_val}, "
          f"tbptt {a.tbptt or 'off (whole sequences)'}; filtering: {a.runs} runs")
    test = model.simulate(a.runs, a.steps, rng=123)
    # warm-up (torch's first calls allocate and dispatch-cache): not timed
    train_kalmannet(model, n_train=4, n_val=2, n_steps=20, epochs=1, batch_size=4, seed=0, progress=False)
    rows = []
    for name, opts in (("KalmanNet", {}), (f"Bayesian J={a.samples}", dict(dropout=0.2, n_samples=a.samples))):
        c0 = time.process_time()
        knet = train_kalmannet(model, n_train=a.n_train, n_val=a.n_val, n_steps=a.steps, epochs=a.epochs,
                               batch_size=a.batch, tbptt=a.tbptt, clip=10.0, seed=0, progress=False,
                               on_diverged="restore", **opts)
        train_cpu = time.process_time() - c0
        h = knet.history
        per_epoch = train_cpu / a.epochs
        per_step = train_cpu / h["optimiser_steps"]
        per_traj_step = train_cpu / (a.epochs * (a.n_train + a.n_val) * a.steps)
        c0, w0 = time.process_time(), time.perf_counter()
        with np.errstate(over="ignore", invalid="ignore"):  # diverged runs are counted below
            run = knet.run(test.z)
        run_cpu, run_wall = time.process_time() - c0, time.perf_counter() - w0
        ok = np.isfinite(run.mean).all(axis=(1, 2))
        rmse = af.metrics.rmse_time_average(af.metrics.squared_error(test.x[ok], run.mean[ok]))
        rows.append((name, knet.n_parameters(), per_epoch, per_step, per_traj_step * 1e6, a.runs * a.steps / run_cpu,
                     a.runs * a.steps / run_wall, rmse, h["val_loss"][0], h["best_val_loss"], len(h["restores"]), int((~ok).sum())))
    print(f"{'filter':<16} {'params':>6} {'CPU-s/epoch':>11} {'CPU-s/opt step':>14} {'us/traj-step':>12} "
          f"{'run-steps/s cpu':>15} {'(wall)':>9} {'RMSE':>7} {'val MSE 0 -> best':>18} restores  diverged runs")
    for r in rows:
        print(f"{r[0]:<16} {r[1]:>6d} {r[2]:>11.2f} {r[3]:>14.3f} {r[4]:>12.1f} {r[5]:>15.0f} {r[6]:>9.0f} {r[7]:>7.2f} "
              f"{r[8]:>8.3g} -> {r[9]:<8.3g} {r[10]:>8d}  {r[11]}")


if __name__ == "__main__":
    main()
