r"""What chapter 18 (Learning the gain instead) builds: KalmanNet (:mod:`adaptfilt.kalmannet`) beside the
Kalman filter on a linear-Gaussian model, over training seeds; the learned gain over time against the
Kalman gain; the Bayesian variant's consistency; and the gain function the chapter's exercise calls.

The linear model is the one ``tests/test_kalmannet.py`` holds KalmanNet to: ``x_{k+1} = 0.9 x_k + w``,
``z_k = x_k + v``, ``Q = R = 1``, ``x_1 ~ N(0, 1)``. Its Kalman filter is the MMSE filter, so the
KF's mean squared error is a floor no gain can pass, and the distance to it in dB (KalmanNet's unit) is
what a trained network has left to learn.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from adaptfilt.course.common import figure_axes
from adaptfilt.models import StateSpaceModel, Trajectory, linear_gaussian

__all__ = ["LINEAR", "TRAIN", "linear_model", "steady_state_gain", "db", "train_seeds", "seed_table",
           "plot_gains", "plot_seed_spread", "gain_function", "kalman_gains",
           "final_table", "verdict_table", "curve_lines", "stored_gain_policies", "is_initial_network",
           "training_lines"]

#: The chapter's linear-Gaussian model (scalar): F, H, Q, R, m0, P0.
LINEAR = dict(F=[[0.9]], H=[[1.0]], Q=[[1.0]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
#: Training on that model: 40 trajectories of 30 steps (40 more to validate), minibatches of 10, Adam at
#: 3e-3, 10 epochs, truncated back-propagation over windows of 10 steps (tests/test_kalmannet.py's sizes).
TRAIN = dict(n_train=40, n_val=40, n_steps=30, batch_size=10, lr=3e-3, epochs=10, tbptt=10, progress=False)


def linear_model() -> StateSpaceModel:
    """The chapter's linear-Gaussian model (:data:`LINEAR`), horizon 30."""
    return linear_gaussian(**LINEAR, name="lin1", n_steps=30)


def steady_state_gain(F: float = 0.9, H: float = 1.0, Q: float = 1.0, R: float = 1.0) -> float:
    """The scalar Kalman filter's steady-state gain, from the Riccati recursion of the predicted variance."""
    P = Q
    for _ in range(500):
        P = F * F * P * R / (H * H * P + R) + Q
    return P * H / (H * H * P + R)


def db(mse: float, reference: float) -> float:
    """``10 log10(mse / reference)``: how many dB an MSE lies above a reference MSE."""
    return float(10 * np.log10(mse / reference))


def train_seeds(model: StateSpaceModel, test: Trajectory, seeds: Sequence[int],
                losses: Sequence[str] = ("supervised", "unsupervised"), progress: bool = True,
                **train) -> dict[tuple[str, int], dict]:
    """Train one KalmanNet per loss and seed (:data:`TRAIN`, overridden by ``train``) and score it on
    ``test``: ``{(loss, seed): {"knet", "mse", "db" (from the KF), "gain" (time-averaged, steps 5 on),
    "cpu_s"}}``. The KF's own MSE on ``test`` is under the key ``("kf", 0)``."""
    from tqdm.auto import tqdm

    from adaptfilt.exact import KalmanFilter
    from adaptfilt.kalmannet import train_kalmannet

    kf = KalmanFilter(model).run(test.z)
    kf_mse = float(((kf.mean - test.x) ** 2).mean())
    out: dict[tuple[str, int], dict] = {("kf", 0): {"mse": kf_mse, "run": kf}}
    kw = {**TRAIN, **train}
    for loss, s in tqdm([(loss, s) for loss in losses for s in seeds], desc="KalmanNet seeds", disable=not progress):
        c0 = time.process_time()
        knet = train_kalmannet(model, loss=loss, seed=int(s), **kw)
        cpu = time.process_time() - c0
        run = knet.run(test.z, keep_gain=True)
        mse = float(((run.mean - test.x) ** 2).mean())
        out[(loss, int(s))] = {"knet": knet, "run": run, "mse": mse, "db": db(mse, kf_mse),
                               "gain": float(run.info["K"][:, 5:].mean()), "cpu_s": cpu}
    return out


def seed_table(results: Mapping[tuple[str, int], dict]) -> str:
    """One line per loss: each seed's dB above the KF, their median and range, and the time-averaged gain."""
    lines = []
    for loss in dict.fromkeys(k[0] for k in results if k[0] != "kf"):
        rows = [v for k, v in sorted(results.items()) if k[0] == loss]
        d = np.array([r["db"] for r in rows])
        g = np.array([r["gain"] for r in rows])
        lines.append(f"{loss:12s} {len(rows)} seeds: dB above the KF median {np.median(d):+.3f}, "
                     f"range [{d.min():+.3f}, {d.max():+.3f}]; gain {g.min():.3f}-{g.max():.3f}")
    return "\n".join(lines)


def plot_gains(results: Mapping[tuple[str, int], dict], seeds: Sequence[int] = (0, 1, 2), ax=None,
               kalman: Sequence[float] | None = None, title: str | None = None):
    """The gain over time (mean over the test runs) of a few seeds of each loss, beside the Kalman
    filter's gain ``kalman`` (per step; the steady state when None)."""
    _, ax = figure_axes(ax)
    styles = {"supervised": "-", "unsupervised": "--"}
    for (loss, s), r in sorted(results.items()):
        if loss == "kf" or s not in seeds:
            continue
        K = r["run"].info["K"][..., 0, 0].mean(0)
        ax.plot(np.arange(1, K.size + 1), K, ls=styles.get(loss, ":"), label=f"{loss}, seed {s}")
    T = next(r["run"].mean.shape[1] for k, r in results.items() if k[0] != "kf")
    if kalman is None:
        ax.axhline(steady_state_gain(), color="k", lw=2, label="Kalman gain (steady state)")
    else:
        ax.plot(np.arange(1, T + 1), kalman, color="k", lw=2, label="Kalman gain")
    ax.set(xlabel="step $k$", ylabel="gain $K_k$ (mean over runs)", title=title)
    ax.legend(fontsize="small", ncol=2)
    return ax


def plot_seed_spread(results: Mapping[tuple[str, int], dict], ax=None, title: str | None = None):
    """Each seed's MSE above the Kalman filter's (dB), one column per loss."""
    _, ax = figure_axes(ax)
    losses = list(dict.fromkeys(k[0] for k in results if k[0] != "kf"))
    for i, loss in enumerate(losses):
        d = [r["db"] for k, r in sorted(results.items()) if k[0] == loss]
        ax.plot(np.full(len(d), i) + np.linspace(-0.15, 0.15, len(d)), d, "o", label=loss)
    ax.axhline(0.0, color="k", lw=1)
    ax.set(xticks=range(len(losses)), xticklabels=losses, ylabel="MSE above the Kalman filter (dB)",
           title=title, xlim=(-0.6, len(losses) - 0.4))
    return ax


def gain_function(knet, n_runs: int) -> Callable[..., np.ndarray]:
    r"""``gain(F1, F2, F3, F4) -> K (n_runs, nx, nz)``: the trained (or untrained) network of ``knet`` as
    a function of the four features of one step, for ``n_runs`` runs filtered together. It normalises
    each feature as ``knet`` does (``feature_norm``) and keeps the recurrent states between calls, so
    it must be called once per step, in order, from the first step on (as the exercise of chapter 18
    does)."""
    import torch
    from torch import nn

    mode = knet.options["feature_norm"]
    if knet.options["n_samples"] > 1:
        raise ValueError("gain_function takes a plain KalmanNet (n_samples = 1), not the Bayesian variant")
    nx, nz = knet.model.nx, knet.model.nz
    states = list(knet.net.initial_states(int(n_runs)))
    bounds = np.cumsum([0, nz, nz, nx, nx])

    def prepare(F, i):
        F = torch.from_numpy(np.asarray(F, dtype=float).reshape(int(n_runs), -1).copy())
        if mode == "l2":
            return nn.functional.normalize(F, p=2.0, dim=-1, eps=1e-12)
        if mode == "scale":
            return F / torch.from_numpy(knet.scales[bounds[i]:bounds[i + 1]])
        return F

    def gain(F1, F2, F3, F4) -> np.ndarray:
        with torch.no_grad():
            K, *new = knet.net.step(*(prepare(F, i) for i, F in enumerate((F1, F2, F3, F4))), *states)
        states[:] = new
        return K.numpy()

    return gain



def kalman_gains(n_steps: int, F: float = 0.9, H: float = 1.0, Q: float = 1.0, R: float = 1.0,
                 P0: float = 1.0) -> np.ndarray:
    """The scalar Kalman filter's gain at steps 1..``n_steps`` from the prior variance ``P0`` (the library's
    convention: the prior is the first prediction)."""
    K, P = np.empty(n_steps), float(P0)
    for k in range(n_steps):
        K[k] = P * H / (H * H * P + R)
        P = F * F * (1 - K[k] * H) * P + Q
    return K


# ------------------------------------------------------------------ the head-to-head study (data/beyond)
def _end(v) -> float:
    """An interval's end: NaN from percentiles between infinite replicates (seeds with a diverged run) is inf."""
    return np.inf if v is None or np.isnan(v) else float(v)


def _ci(agg: dict | None, fmt: str = ".3g") -> str:
    if agg is None or agg.get("iqm") is None or not np.isfinite(agg["iqm"]):
        return "n/a"
    lo, hi = (_end(v) for v in agg["iqm_ci"])
    return f"{agg['iqm']:{fmt}} [{lo:{fmt}}, {hi:{fmt}}]"


def final_table(g: Mapping, regime: str = "nominal") -> str:
    """The study's final budget under ``regime`` (``summary["gain"]`` of ``data/beyond``), a Markdown table:
    per model every arm (IQM over seeds [two-level 95 % CI]) and the references, with the MSE in dB, the
    mean training CPU-s and the runs whose RMSE passed the divergence bound (per seed for the arms)."""
    lines = ["| model | policy | RMSE | MSE (dB) | training CPU-s | divergent runs |", "|---|---|---|---|---|---|"]
    for e, regimes in g["models"].items():
        m = regimes[regime]
        for a, row in m["final"].items():
            cpu = [c for c in row["train_cpu_s"] if c is not None]
            stop = f" ({row['stopped_trainings']} stopped)" if row.get("stopped_trainings") else ""
            lines.append(f"| {e} | {a}{stop} | {_ci(row['rmse'])} | {row['mse_db']['iqm']:.3g} | "
                         f"{np.mean(cpu):.3g} | {', '.join(map(str, row['divergent_error_rule']))} |")
        for label, ref in m["references"].items():
            name = label if label == ref["policy"] else ref["policy"] if ref["policy"].startswith(label) else \
                f"{label} ({ref['policy']})"
            lines.append(f"| {e} | {name} | {ref['rmse']:.3g} | {ref['mse_db']:.3g} | | "
                         f"{ref['divergent_error_rule']} |")
        if m["floor"]["rmse"] is not None:
            lines.append(f"| {e} | point-mass floor ({m['floor']['runs']} runs) | {m['floor']['rmse']:.3g} | | | |")
    return "\n".join(lines)


def verdict_table(g: Mapping, budget: int | None = None, pairs: Sequence[tuple[str, str]] | None = None) -> str:
    """The study's seed-level verdicts on RMSE at ``budget`` (default: the last) for ``pairs`` (default: the
    four of the 2 x 2 design), every model and regime: ``a - b`` (IQM over seeds [two-level 95 % CI]), "a lower"
    and "a not worse" (within the project's margin)."""
    budget = budget or len(g["target_cpu_s"])
    pairs = pairs or (("gain-sup", "kappa-sqerr"), ("gain-unsup", "kappa-nis"), ("kappa-sqerr", "kappa-nis"),
                      ("gain-sup", "gain-unsup"))
    lines = ["| model, regime | a - b | RMSE a - b | a lower | a not worse |", "|---|---|---|---|---|"]
    for e, regimes in g["models"].items():
        for r, m in regimes.items():
            for v in m["verdicts"]:
                if v["budget"] == budget and (v["a"], v["b"].split(" (")[0]) in pairs:
                    d = v["rmse_diff"]
                    ds = "n/a" if d[0] is None or d[1] is None else \
                        f"{d[0]:+.3g} [{d[1]:+.3g}, {_end(d[2]):+.3g}]"
                    nw = v["not_worse"] or "n/a (no margin)"
                    lines.append(f"| {e}, {r} | {v['a']} - {v['b']} | {ds} | {v['lower']} | {nw} |")
    return "\n".join(lines)


def curve_lines(g: Mapping, regime: str = "nominal") -> str:
    """The budget curves of the stored study as text: per model and arm, at each budget the mean training
    CPU-s over seeds and the RMSE (IQM over seeds), and how many KalmanNet trainings divergence stopped."""
    lines = []
    for e, regimes in g["models"].items():
        for a, pts in regimes[regime]["curve"].items():
            cells = []
            for b in sorted(pts, key=int):
                row = pts[b]
                cpu = np.mean([c for c in row["train_cpu_s"] if c is not None])
                stop = f", {row['stopped_trainings']} stopped" if row.get("stopped_trainings") else ""
                cells.append(f"{cpu:4.1f} CPU-s: {row['rmse']['iqm']:.3g}{stop}")
            lines.append(f"{e:8s} {regime:7s} {a:11s} " + "; ".join(cells))
    return "\n".join(lines)


# ------------------------------------------------------- the stored KalmanNets of the study (data/beyond/policies)
def stored_gain_policies(root=None) -> dict[tuple[str, str, int, int], object]:
    """The study's stored KalmanNet files, ``beyond/policies/{model}-{arm}-b{budget}-s{seed}.npz`` of ``root``
    (default: the repository's ``data/``), loaded against their experiment's model:
    ``{(model, arm, budget, seed): KalmanNet}``, the training history in ``knet.history``."""
    import re

    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.artefacts import data_dir
    from adaptfilt.kalmannet import load_kalmannet

    d = (data_dir() if root is None else Path(root)) / "beyond" / "policies"
    out, models = {}, {}
    for p in sorted(d.glob("*-gain-*-b*-s*.npz")):
        e, arm, b, s = re.fullmatch(r"(.+)-(gain-\w+)-b(\d+)-s(\d+)\.npz", p.name).groups()
        model = models.setdefault(e, get_experiment(e).make_model())
        out[e, arm, int(b), int(s)] = load_kalmannet(p, model)
    if not out:
        raise FileNotFoundError(f"no KalmanNet files of the gain study in {d}: run `adaptfilt beyond --studies gain`")
    return out


def is_initial_network(knet) -> bool:
    """Whether ``knet`` holds the weights its seed and options start from: a training that never improved
    on its untrained network on validation and kept it (compared weight for weight with a fresh network)."""
    import torch

    from adaptfilt.kalmannet import KalmanNet

    fresh = KalmanNet(knet.model, seed=knet.seed, scales=knet.scales, bounds=knet.bounds, **knet.options)
    mine, theirs = knet.net.state_dict(), fresh.net.state_dict()
    return mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine)


def _seeds(seeds: Sequence[int]) -> str:
    return f" (seed{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))})" if len(seeds) else ""


def training_lines(knets: Mapping[tuple[str, str, int, int], object], curve: tuple[str, str] = ("ctm-ukf", "gain-sup"),
                   every: int = 5, order: Sequence[str] = ("ungm-ukf", "ctm-ukf", "gain-unsup", "gain-sup")) -> str:
    """What the stored KalmanNets' training histories show, as text: the data and optimiser steps they had,
    per model, arm and budget how many are their untrained initial network (:func:`is_initial_network`),
    which seeds' last-budget files are one network in both arms, and for ``curve`` (model, arm) at its last
    budget the epoch of the best validation per seed and the best validation loss so far (median over
    seeds) every ``every`` epochs. Models and arms are listed in ``order`` (others after them)."""
    rank = {name: i for i, name in enumerate(order)}
    keys = sorted(knets, key=lambda k: (rank.get(k[0], len(rank)), k[0], rank.get(k[1], len(rank)), k[1], k[2], k[3]))
    models = list(dict.fromkeys(k[0] for k in keys))
    hist = {k: knets[k].history for k in keys}
    sizes = lambda name: "/".join(map(str, sorted({h[name] for h in hist.values()})))  # noqa: E731
    lines = [f"every file: {sizes('n_train')} training trajectories per seed (the same at every budget), "
             f"minibatches of {sizes('batch_size')}"]
    for e in models:
        budgets = sorted({k[2] for k in keys if k[0] == e})
        epochs = [next(hist[k]["epochs"] for k in keys if k[0] == e and k[2] == b) for b in budgets]
        top = [max(hist[k]["optimiser_steps"] for k in keys if k[0] == e and k[2] == b) for b in budgets]
        lines.append(f"{e:8s} budgets of {'/'.join(map(str, epochs))} epochs: at most "
                     f"{'/'.join(map(str, top))} optimiser steps")
    lines.append("the kept network is its untrained initial one (the same weights), per arm and budget:")
    for e in models:
        for arm in dict.fromkeys(k[1] for k in keys if k[0] == e):
            cells = []
            for b in dict.fromkeys(k[2] for k in keys if k[:2] == (e, arm)):
                ks = [k for k in keys if k[:3] == (e, arm, b)]
                init = [k[3] for k in ks if is_initial_network(knets[k])]
                cells.append(f"{hist[ks[0]]['epochs']} ep. {len(init)} of {len(ks)}{_seeds(init)}")
            lines.append(f"  {e:8s} {arm:10s} " + "; ".join(cells))
        arms = list(dict.fromkeys(k[1] for k in keys if k[0] == e))
        b = max(k[2] for k in keys if k[0] == e)
        same = [s for s in sorted({k[3] for k in keys if k[0] == e}) if len(arms) == 2
                and all((e, a, b, s) in knets for a in arms) and _same_weights(knets[e, arms[0], b, s], knets[e, arms[1], b, s])]
        if same:
            lines.append(f"  {e:8s} last budget: one and the same network in both arms{_seeds(same)}")
    e, arm = curve
    b = max(k[2] for k in keys if k[:2] == curve)
    hs = [hist[k] for k in keys if k[:3] == (e, arm, b)]
    last = sum(h["best_epoch"] == len(h["val_loss"]) - 1 for h in hs)
    run_min = np.median([np.minimum.accumulate(h["val_loss"]) for h in hs], axis=0)
    marks = list(range(0, len(run_min), every)) + ([len(run_min) - 1] if (len(run_min) - 1) % every else [])
    lines.append(f"{e} {arm}, {hs[0]['epochs']} epochs: best validation at epoch "
                 f"{', '.join(str(h['best_epoch']) for h in hs)} (seeds in order; the last epoch in {last} of "
                 f"{len(hs)});\n  best validation loss so far (median over seeds) at epoch "
                 + ", ".join(f"{m}: {run_min[m]:.0f}" for m in marks))
    return "\n".join(lines)


def _same_weights(a, b) -> bool:
    import torch

    sa, sb = a.net.state_dict(), b.net.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
