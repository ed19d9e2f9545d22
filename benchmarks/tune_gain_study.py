"""The learned-gain study's tuning: each learner's small grid, chosen on selection runs only.

Run with ``python benchmarks/tune_gain_study.py --out DIR`` (``--quick``: a smoke run of a few seconds).
Every configuration is one training of seed :data:`SEED` stopped at :data:`BUDGET_CPU_S` process CPU
seconds (set-up, simulation and validation included; torch on one thread), then filtered over the
selection runs (:data:`SELECTION`: 1000 runs of the model's horizon from ``Generator([4848, 1])``, never
a test's or a training's) and scored by the time-averaged RMSE, ``af.metrics.rmse(x, mean).mean()``.
Each result is written to ``DIR/<learner>-<model>-....json`` as it finishes; a rerun skips what is there
(CPU-s budgets are not reproducible to the bit: the numbers move a little between reruns).

* **KalmanNet** on the CTM (UNGM's tuning is :data:`adaptfilt.kalmannet.RECIPE_TUNING` ``["ungm"]``,
  made the same way): architectures 1 and 2, learning rate x window length (8 configurations each,
  the UNGM grid), the rest :data:`adaptfilt.kalmannet._COMMON` (the supervised loss).
* **The kappa learner** (the fast mode, SB3 PPO over 256 runs, rollouts of 64 steps, minibatches of
  2048, gamma 0.5) on UNGM and the CTM: learning rate x PPO epochs per rollout (8 configurations), on
  the squared error (``ungm-ukf-sqerr``, ``ctm-ukf-sqerr``): the same objective as the supervised gain.

The study (:mod:`adaptfilt.experiments.studies.gain`) records what this printed in ``KAPPA_TUNING`` and
:data:`adaptfilt.kalmannet.RECIPE_TUNING` and uses the chosen configurations for both arms of each learner.

``--consistency``: the consistency arm's weight (after the kappa tuning, with UNGM's chosen recipe): the
kappa learner on ``ungm-ukf-sqerr-nll{w}`` for each weight of
:data:`adaptfilt.experiment_registry.NLL_WEIGHTS` and on ``ungm-ukf-sqerr`` (``w = 0``), seed 100,
45 CPU-s each, scored by RMSE and ANEES on the selection runs.

``--calibrate``: each chosen recipe's CPU-s per work unit: one training of seed 0 of about 60 CPU-s kept
at many budgets on the way (snapshots), its process CPU-s at each (the kappa learner's at every rollout;
KalmanNet's at every validation), fitted by a line: set-up CPU-s plus CPU-s per episode or optimiser step.
"""
from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np
import stable_baselines3  # noqa: F401  (imported before any budget's clock starts)
import torch

import adaptfilt as af
from adaptfilt.evaluation import evaluate
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.kalmannet import _COMMON, train_kalmannet
from adaptfilt.trainers import FAST, SB3Config, train_sb3

SEED = 100
BUDGET_CPU_S = 45.0
SELECTION = [4848, 1]
KNET_GRID = {"lr": (3e-4, 1e-3, 3e-3, 1e-2), "tbptt": (20, 50)}
KAPPA_GRID = {"lr": (5e-4, 1e-3, 2e-3, 4e-3), "n_epochs": (5, 10)}
MODELS = {"ungm": "ungm-ukf", "ctm": "ctm-ukf"}


def selection(model: str, n_runs: int, n_steps: int | None):
    exp = get_experiment(MODELS[model])
    m = exp.make_model()
    return m.simulate(n_runs, n_steps or m.n_steps, rng=np.random.default_rng(SELECTION))


def tune_knet(model: str, arch: int, lr: float, tbptt: int, budget: float, quick: bool) -> dict:
    m = get_experiment(MODELS[model]).make_model()
    n_steps = 20 if quick else None
    opts = dict(_COMMON, arch=arch, lr=lr, tbptt=min(tbptt, n_steps or tbptt))
    if quick:
        opts.update(n_train=8, n_val=4, batch_size=8, val_every=2, patience=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # restarts and failures are counted below
        knet = train_kalmannet(m, seed=SEED, max_cpu_s=budget, progress=False, n_steps=n_steps, **opts)
    h = knet.history
    sel = selection(model, 50 if quick else 1000, n_steps)
    rmse = float(af.metrics.rmse(sel.x, knet.run(sel.z).mean).mean())
    return {"rmse": rmse, "optimiser_steps": int(h["optimiser_steps"]), "restarts": int(h["n_restarts"]),
            "cpu_s": float(h["cpu_s"]), "failed": h["failed"], "trajectories": int(h["trajectories_seen"])}


def tune_kappa(model: str, lr: float, n_epochs: int, budget: float, quick: bool) -> dict:
    exp = f"{MODELS[model]}-sqerr"
    n_steps = 20 if quick else None
    cfg = SB3Config("ppo", FAST.n_envs, {**FAST.kwargs, "learning_rate": lr, "n_epochs": n_epochs})
    pol = train_sb3(exp, 0.5, 10 ** 7, SEED, cfg, n_steps=n_steps, progress=False, max_cpu_s=budget)
    meta = pol.metadata
    rollouts = meta["transitions"] // (cfg.n_envs * cfg.kwargs["n_steps"])
    sel = selection(model, 50 if quick else 1000, n_steps)
    env = get_experiment(exp).make_env(n_steps=n_steps)
    res = evaluate(env, [pol], traj=sel, progress=False, n_boot=10)
    per_rollout = n_epochs * (cfg.n_envs * cfg.kwargs["n_steps"]) // cfg.kwargs["batch_size"]
    return {"rmse": float(res[pol.name].rmse), "optimiser_steps": int(rollouts * per_rollout),
            "episodes": int(meta["transitions"] // meta["n_steps"]), "cpu_s": float(pol.cpu_s)}


def consistency(weight: float, lr: float, n_epochs: int, budget: float, quick: bool) -> dict:
    exp = "ungm-ukf-sqerr" if weight == 0 else f"ungm-ukf-sqerr-nll{weight:g}"
    n_steps = 20 if quick else None
    cfg = SB3Config("ppo", FAST.n_envs, {**FAST.kwargs, "learning_rate": lr, "n_epochs": n_epochs})
    pol = train_sb3(exp, 0.5, 10 ** 7, SEED, cfg, n_steps=n_steps, progress=False, max_cpu_s=budget)
    sel = selection("ungm", 50 if quick else 1000, n_steps)
    res = evaluate(get_experiment(exp).make_env(n_steps=n_steps), [pol], traj=sel, progress=False, n_boot=10)
    return {"rmse": float(res[pol.name].rmse), "anees": float(res[pol.name].anees),
            "episodes": int(pol.metadata["transitions"] // pol.metadata["n_steps"]), "cpu_s": float(pol.cpu_s)}


def _line(units, cpu) -> dict:
    """Least squares ``cpu = a + b units``: set-up ``a`` and ``b`` per unit."""
    b, a = np.polyfit(np.asarray(units, float), np.asarray(cpu, float), 1)
    return {"setup_cpu_s": float(a), "cpu_s_per_unit": float(b), "points": [[int(u), float(c)] for u, c in zip(units, cpu)]}


def calibrate_kappa(model: str, lr: float, n_epochs: int, budget: float, quick: bool) -> dict:
    exp = f"{MODELS[model]}-sqerr"
    n_steps = 20 if quick else get_experiment(exp).make_model().n_steps
    cfg = SB3Config("ppo", FAST.n_envs, {**FAST.kwargs, "learning_rate": lr, "n_epochs": n_epochs})
    per_rollout = cfg.n_envs * cfg.kwargs["n_steps"] / n_steps  # episodes per rollout
    snaps = [int(np.ceil(r * per_rollout)) for r in range(1, 400)]
    pol = train_sb3(exp, 0.5, snaps[-1], 0, cfg, n_steps=20 if quick else None, progress=False, max_cpu_s=budget,
                    snapshots=snaps)
    kept = sorted(pol.snapshots.items())
    return _line([e for e, _ in kept], [p.cpu_s for _, p in kept])


def calibrate_knet(model: str, arch: int, lr: float, tbptt: int, budget: float, quick: bool) -> dict:
    m = get_experiment(MODELS[model]).make_model()
    n_steps = 20 if quick else None
    opts = dict(_COMMON, arch=arch, lr=lr, tbptt=min(tbptt, n_steps or tbptt))
    if quick:
        opts.update(n_train=8, n_val=4, batch_size=8, val_every=2, patience=4)
    steps = list(range(opts["val_every"], 3001, opts["val_every"]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        knet = train_kalmannet(m, seed=0, max_cpu_s=budget, progress=False, n_steps=n_steps, snapshot_steps=steps,
                               **opts)
    kept = [(s, knet.snapshot(step=s).history["cpu_s"]) for s in steps if s <= knet.history["optimiser_steps"]]
    return _line([s for s, _ in kept], [c for _, c in kept])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the per-configuration results (resumable)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: tiny budgets and selection sets")
    ap.add_argument("--only", choices=("knet", "kappa"), default=None)
    ap.add_argument("--extend", action="append", default=[], metavar="LEARNER:MODEL:LR",
                    help="a learning rate beyond the grid's edge where the best configuration lies at it (the "
                         "rule both learners' tunings follow), e.g. kappa:ungm:0.00025 or knet:ctm:0.03")
    ap.add_argument("--consistency", default=None, metavar="LR,N_EPOCHS",
                    help="choose the consistency weight with this kappa recipe (UNGM's chosen one)")
    ap.add_argument("--calibrate", default=None, metavar="JSON",
                    help='calibrate the chosen recipes: {"kappa": {"ungm": [lr, n_epochs], ...}, "knet": '
                         '{"ungm": [[arch, lr, tbptt], ...], ...}}')
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = []  # (name, function, arguments, CPU-s budget)
    small = 2.0 if args.quick else BUDGET_CPU_S
    if args.consistency:
        from adaptfilt.experiment_registry import NLL_WEIGHTS

        lr, ne = (float(v) for v in args.consistency.split(","))
        jobs += [(f"consistency-w{w:g}", consistency, (w, lr, int(ne)), small) for w in (0.0, *NLL_WEIGHTS)]
    if args.calibrate:
        cal, big = json.loads(args.calibrate), 4.0 if args.quick else 60.0
        jobs += [(f"calibrate-kappa-{m}", calibrate_kappa, (m, lr, int(ne)), big) for m, (lr, ne) in cal["kappa"].items()]
        jobs += [(f"calibrate-knet-{m}-arch{a}", calibrate_knet, (m, int(a), lr, int(w)), big)
                 for m, confs in cal["knet"].items() for a, lr, w in confs]
    if not (args.consistency or args.calibrate or args.extend):
        if args.only in (None, "kappa"):
            jobs += [(f"kappa-{m}-lr{lr:g}-ep{ne}", tune_kappa, (m, lr, ne), small)
                     for m in MODELS for lr in KAPPA_GRID["lr"] for ne in KAPPA_GRID["n_epochs"]]
        if args.only in (None, "knet"):
            jobs += [(f"knet-ctm-arch{a}-lr{lr:g}-w{w}", tune_knet, ("ctm", a, lr, w), small)
                     for a in (2, 1) for lr in KNET_GRID["lr"] for w in KNET_GRID["tbptt"]]
    for ext in args.extend:
        learner, m, lr = ext.split(":")
        if learner == "kappa":
            jobs += [(f"kappa-{m}-lr{float(lr):g}-ep{ne}", tune_kappa, (m, float(lr), ne), small)
                     for ne in KAPPA_GRID["n_epochs"]]
        else:
            jobs += [(f"knet-{m}-arch{a}-lr{float(lr):g}-w{w}", tune_knet, (m, a, float(lr), w), small)
                     for a in (2, 1) for w in KNET_GRID["tbptt"]]
    for name, fn, a, budget in jobs:
        path = out / f"{name}.json"
        if path.exists():
            print(name, json.loads(path.read_text()), "(done before)", flush=True)
            continue
        t0 = time.time()
        r = fn(*a, budget=budget, quick=args.quick)
        r["wall_s"] = time.time() - t0
        path.write_text(json.dumps(r) + "\n")
        print(name, r, flush=True)


if __name__ == "__main__":
    main()
