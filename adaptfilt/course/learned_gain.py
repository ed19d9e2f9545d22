r"""What chapter 18 (Learning the gain instead) builds: KalmanNet (:mod:`adaptfilt.kalmannet`) beside the
Kalman filter on a linear-Gaussian model, over training seeds; the learned gain over time against the
Kalman gain; the Bayesian variant's consistency; the gain function the chapter's exercise calls; and what it
shows of the learned-gain study of ``adaptfilt beyond`` (:mod:`adaptfilt.experiments.studies.gain`), each a
call for one cell, from the study's summary ``g = summary["gain"]``:

======================  ==================================================================================
design_lines            what was trained and how: budgets and work units, arms, recipes, tuning, regimes
plot_curves             RMSE against training CPU-s per arm and model, where each arm stops improving
curve_lines             the same curves as numbers; stops_lines: the seed-level steps between budgets
verdict_table           learned gain vs learned kappa at every budget, by the declared margin
training_table          what each learner saw: trajectories or episodes, optimiser steps, CPU-s
restart_table           KalmanNet's restarts and failed trainings per arm
truth_table             trained on the truth's trajectories vs trained on the model (unseen mismatch)
consistency_table       the squared-error kappa with and without the consistency term: RMSE and ANEES
final_table             the top budgets on the final runs beside the references
======================  ==================================================================================

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
           "plot_gains", "plot_seed_spread", "pf_lines", "gain_function", "kalman_gains", "LEARNED_PAIRS", "design_lines",
           "curve_lines", "plot_curves", "stops_lines", "verdict_table", "training_table",
           "restart_table", "truth_table", "consistency_table", "final_table", "stored_gain_policies",
           "initial_attempt", "is_initial_network"]

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


# ------------------------------------------------------------------ the learned-gain study (data/beyond)
# ``g`` below is ``summary["gain"]`` of ``adaptfilt beyond --studies gain`` (``artefacts.load_beyond()["gain"]``,
# the format of :func:`adaptfilt.experiments.studies.gain.rows`). The figures are the study's own
# (``plot_budget_curves``, ``plot_mismatch``); the tables are Markdown of at most seven columns, the course's
# rule (:mod:`adaptfilt.course.tables`).

#: The pairs that answer "learn the parameter or learn the gain": each learned gain against the learned kappa
#: trained on the same kind of signal (the true state's squared error; the measurements only).
LEARNED_PAIRS = (("gain-sup", "kappa-sqerr"), ("gain-unsup", "kappa-nis"))


def _cpu(row: Mapping) -> float:
    """The mean training CPU-s over the seeds that recorded one."""
    cpu = [c for c in row["train_cpu_s"] if c is not None]
    return float(np.mean(cpu)) if cpu else float("nan")


def _ci(agg: Mapping | None) -> str:
    """``IQM [lo, hi]`` (3 significant digits) of an aggregate over seeds; an unbounded end is ``inf``."""
    if agg is None or agg.get("iqm") is None:
        return "n/a"
    lo, hi = (-np.inf if agg["iqm_ci"][0] is None else agg["iqm_ci"][0]), \
        (np.inf if agg["iqm_ci"][1] is None else agg["iqm_ci"][1])
    return f"{agg['iqm']:.3g} [{lo:.3g}, {hi:.3g}]"


def _budget(g: Mapping, e: str, b) -> str:
    """``b3 (45 CPU-s)``: a budget and its target."""
    return f"b{int(b)} ({g['target_cpu_s'][e][int(b) - 1]:g} CPU-s)"


def _spread(values: Sequence) -> str:
    """One value, or ``lo-hi`` over seeds; ``n/a`` when none is known."""
    v = [x for x in values if x is not None]
    if not v:
        return "n/a"
    f = (lambda x: f"{x:.0f}") if all(float(x).is_integer() for x in v) else (lambda x: f"{x:.3g}")
    return f(min(v)) if f(min(v)) == f(max(v)) else f"{f(min(v))}-{f(max(v))}"


def _seeds_of(g: Mapping) -> int:
    m = next(iter(g["models"].values()))["nominal"]
    return max(len(row["names"]) for pts in m["curve"].values() for row in pts.values())


def design_lines(g: Mapping) -> str:
    """What the study trained and how, as text from its summary: seeds and runs; per model the budgets
    (target CPU-s per policy, met in each learner's work units), the arms and the budget each trains to, the
    arms trained on a truth that is not the model, the recipes, the regimes; the tuning and the consistency
    weight."""
    lines = [f"{_seeds_of(g)} training seeds per arm; every policy on the same {g['curve_runs']} runs per "
             f"regime, the top budgets again on {g['eval_runs']} (nominal model)"]
    for e, regimes in g["models"].items():
        u = g["units"][e]
        lines.append(f"{e}: budgets b1-b{len(g['target_cpu_s'][e])} of "
                     f"{', '.join(f'{t:g}' for t in g['target_cpu_s'][e])} CPU-s per policy, met as")
        lines.append(f"  kappa: {', '.join(map(str, u['kappa_episodes']))} episodes")
        lines += [f"  KalmanNet arch. {k[-1]}: {', '.join(map(str, v))} optimiser steps"
                  for k, v in u.items() if k.startswith("knet_steps")]
        arms = g["arms"][e]
        lines.append("  arms (to budget): " + ", ".join(
            f"{a} b{s['top']}" + (f" (arch. {s['arch']})" if s["kind"] == "gain" else "")
            for a, s in arms.items() if s["truth"] is None))
        truth = [f"{a} b{s['top']} (truth {s['truth']})" for a, s in arms.items() if s["truth"]]
        if truth:
            lines.append("  trained on the truth's trajectories: " + ", ".join(truth))
        k, n = g["recipes"]["kappa"][e], g["recipes"]["knet"][e]
        lines.append(f"  kappa recipe: lr {k['lr']:g}, {k['n_epochs']} PPO epochs a rollout")
        lines.append(f"  KalmanNet recipe (arch. {n['arch']}): "
                     f"lr {n['lr']:g}, windows of {n['tbptt']}, minibatches of {n['batch_size']} fresh "
                     f"trajectories, validated every {n['val_every']} steps, clamp {n['clamp']}, clip {n['clip']:g}, "
                     f"at most {n['restarts']} restarts (patience {n['patience']})")
        truths = ", ".join(f"{r} ({m['truth'] or 'the model'})" for r, m in regimes.items())
        lines.append(f"  regimes: {truths}")
    t = g["tuning"]
    knet = ", ".join(f"{m} {sum(len(v) for a, v in t['knet'][m].items() if a.isdigit())}"
                     for m in t["knet"])
    kappa = ", ".join(f"{e} {len(t['kappa'][e])}" for e in g["models"])
    lines.append(f"tuned on selection runs only ({t['kappa']['selection_runs']}), seed {t['kappa']['seed']}, "
                 f"{t['kappa']['budget_cpu_s']:g} CPU-s a configuration: kappa {kappa}; KalmanNet (both "
                 f"architectures) {knet}")
    lines.append(f"consistency weight {t['consistency']['chosen']}")
    return "\n".join(lines)


def curve_lines(g: Mapping, regime: str = "nominal") -> str:
    """The budget curves as text: per model and arm, at each budget the mean training CPU-s over seeds and
    the RMSE (IQM over seeds), with the failed trainings (the network kept is an untrained one) where any."""
    lines = []
    for e, regimes in g["models"].items():
        for a, pts in regimes[regime]["curve"].items():
            cells = []
            for b in sorted(pts, key=int):
                row = pts[b]
                fail = f" ({row['failed']} failed)" if row.get("failed") else ""
                cells.append(f"b{b} {_cpu(row):.3g} CPU-s: {row['rmse']['iqm']:.3g}{fail}")
            lines.append(f"{e:8s} {a:14s} " + "; ".join(cells))
    return "\n".join(lines)


def plot_curves(g: Mapping):
    """The study's budget curves under the nominal model (:func:`~adaptfilt.experiments.studies.gain.
    plot_budget_curves`: RMSE, IQM over seeds with its two-level 95 % interval, against the measured training
    CPU-s, a panel per model, the references as lines) with the budget at which each arm stops improving
    (``stops_improving``: the first budget whose next one is not confirmed lower) ringed, and an arm still
    improving at its top budget marked by an arrow there. Returns the figure."""
    from matplotlib.lines import Line2D

    from adaptfilt.experiments.studies.gain import plot_budget_curves

    fig = plot_budget_curves(g)
    leg = fig.legends[0]
    colors = {t.get_text(): h.get_color() for t, h in zip(leg.get_texts(), leg.legend_handles)
              if hasattr(h, "get_color")}
    ring = arrow = None
    for ax, e in zip(fig.axes, g["models"]):
        m = g["models"][e]["nominal"]
        for a, s in m.get("stops_improving", {}).items():
            b = s["stops_at"] if s["stops_at"] is not None else s["top"]
            row = m["curve"][a][str(b)]
            kw = dict(color=colors.get(a, "k"), ls="none", zorder=5)
            if s["stops_at"] is not None:
                ring = ax.plot([_cpu(row)], [row["rmse"]["iqm"]], marker="o", ms=14, mfc="none", mew=1.6,
                               **kw)[0]
            else:
                arrow = ax.plot([_cpu(row)], [row["rmse"]["iqm"]], marker=">", ms=11, mfc="none", mew=1.6,
                                **kw)[0]
    hs, labels = list(leg.legend_handles), [t.get_text() for t in leg.get_texts()]
    for h, marker, lab in ((ring, "o", "stops improving"), (arrow, ">", "still improving at its top budget")):
        if h is not None:  # a grey stand-in: the marks take each arm's colour
            hs.append(Line2D([], [], marker=marker, ms=9, mfc="none", mew=1.6, color="grey", ls="none"))
            labels.append(lab)
    leg.remove()
    fig.legend(hs, labels, loc="outside lower center", ncol=5, fontsize=8)
    return fig


def stops_lines(g: Mapping) -> str:
    """Where each arm stops improving (nominal model), as text: per model and arm the budget, then each step
    to the next budget, ``b(k+1) - bk`` of the RMSE (IQM over seeds [two-level 95 % CI]) and the verdict on
    "lower" by the one rule (margin 0)."""
    lines = []
    for e, regimes in g["models"].items():
        for a, s in regimes["nominal"].get("stops_improving", {}).items():
            at = (f"stops at {_budget(g, e, s['stops_at'])}" if s["stops_at"] is not None
                  else f"still improving at its top budget, {_budget(g, e, s['top'])}")
            lines.append(f"{e:8s} {a:14s} {at}")
            for x in s["steps"]:
                lines.append(f"    b{x['to']} - b{x['from']}: {_interval(x['diff'])} {x['lower']}")
    return "\n".join(lines)


def _interval(d: Sequence) -> str:
    """``+d [+lo, +hi]`` (3 significant digits) of a difference; ``inf`` for an unbounded end."""
    if d[0] is None:
        return "n/a"
    lo, hi = (-np.inf if d[1] is None else d[1]), (np.inf if d[2] is None else d[2])
    return f"{d[0]:+.3g} [{lo:+.3g}, {hi:+.3g}]"


def verdict_table(g: Mapping, regime: str = "nominal", pairs: Sequence[tuple[str, str]] = LEARNED_PAIRS,
                  final: bool = True) -> str:
    """The seed-level verdicts of ``pairs`` under ``regime`` at every budget both arms have (past b's top budget,
    for a pair of :data:`adaptfilt.experiments.studies.gain.CARRIED`, b at its top, named), per model: ``a - b``
    of the RMSE (IQM over seeds [two-level 95 % CI]), "a lower" (margin 0) and "a not worse" (within the margin
    declared for the learned gain against the learned kappa, :data:`adaptfilt.verdicts.DECLARED_MARGINS`,
    printed beside it); with ``final`` the top budgets' verdicts on the final runs after each model's curve."""
    head = ["model", "budget", "a - b", "RMSE a - b", "a lower", "a not worse (margin)"]
    rows = []
    for e, regimes in g["models"].items():
        m = regimes[regime]
        found = [(v, "") for v in m["verdicts"]]
        if final:
            found += [(v, f", {g['eval_runs']} runs") for v in m.get("final_verdicts", [])]
        for a, b in pairs:
            for v, where in found:
                if (v["a"], v["b"], v["metric"]) == (a, b, "rmse"):
                    nw = "n/a" if v.get("not_worse") is None else f"{v['not_worse']} ({v['margin']:.3g})"
                    bb = v.get("budget_b")  # a carried pair: b at its top budget, named (gain.CARRIED)
                    label = f"{a} - {b}" + (f" {_budget(g, e, bb)}" if bb not in (None, v["budget"]) else "")
                    rows.append([e, _budget(g, e, v["budget"]) + where, label, _interval(v["diff"]),
                                 v["lower"], nw])
    return "\n".join(md_lines(head, rows))


def pf_lines(g: Mapping, regime: str = "nominal") -> str:
    """The supervised gain's top budget against the particle filter under ``regime`` (the final runs under the
    nominal model, else the curve's), per model: ``a - b`` of the RMSE and "a lower" at margin 0 (no margin
    was declared for this pair, :data:`adaptfilt.experiments.studies.gain.PF`)."""
    from adaptfilt.experiments.studies.gain import PF

    out = []
    for e, regimes in g["models"].items():
        m = regimes[regime]
        rows = m.get("final_verdicts", []) if regime == "nominal" else m["verdicts"]
        top = max((v["budget"] for v in rows if v["a"] == "gain-sup" and v["b"].startswith(PF)), default=None)
        for v in rows:
            if v["a"] == "gain-sup" and v["b"].startswith(PF) and v["budget"] == top:
                runs = f", {g['eval_runs']} runs" if regime == "nominal" else ""
                out.append(f"{e}: gain-sup b{top} - {v['b']}{runs}: {_interval(v['diff'])} {v['lower']}")
    return "\n".join(out)


def md_lines(head: Sequence[str], rows: Sequence[Sequence]) -> list[str]:
    """A Markdown table (:func:`adaptfilt.experiments.report.md_table`)."""
    from adaptfilt.experiments.report import md_table

    return md_table(list(head), [list(map(str, r)) for r in rows])


def _trained_rows(g: Mapping):
    """``(model, regime, arm, budget, row)`` of every training the summary reports, once each: the nominal
    curve's arms, and each arm trained on a truth from its regime's curve."""
    for e, regimes in g["models"].items():
        for r, m in regimes.items():
            for a, pts in m["curve"].items():
                if (r == "nominal") == (g["arms"][e][a]["truth"] is None):
                    for b in sorted(pts, key=int):
                        yield e, r, a, b, pts[b]


def training_table(g: Mapping) -> str:
    """What each learner had, per model, arm and budget (ranges over seeds): the target and the measured
    training CPU-s (mean over seeds), the training trajectories it saw (the kappa learner's episodes trained;
    KalmanNet's freshly simulated trajectories, restarts included), its optimiser steps, and KalmanNet's
    restarts and failed trainings (the network kept is an untrained one), as the study records them."""
    head = ["model", "arm, budget", "CPU-s: target, measured", "trajectories seen", "optimiser steps",
            "restarts, failed"]
    rows = []
    for e, r, a, b, row in _trained_rows(g):
        kappa = g["arms"][e][a]["kind"] == "kappa"
        steps = row["optimiser_steps"]
        rf = "n/a" if kappa else f"{sum(row['restarts'])}, {row['failed']}"
        rows.append([e, f"{a}, b{b}", f"{g['target_cpu_s'][e][int(b) - 1]:g}, {_cpu(row):.3g}",
                     _spread(row["trajectories_seen"]), _spread(steps), rf])
    return "\n".join(md_lines(head, rows))


def restart_table(g: Mapping) -> str:
    """KalmanNet's restarts and failed trainings per model and arm: the trainings (one per seed, kept at every
    budget), the restarts the restart rule made (by its top budget: every restart happens on the way) and in
    how many seeds, and at each budget the trainings that failed (the network kept is an untrained one)."""
    head = ["model", "arm", "trainings", "restarts (seeds)", "failed, per budget"]
    rows, by_arm = [], {}
    for e, _, a, b, row in _trained_rows(g):
        if row["restarts"] is not None:
            by_arm.setdefault((e, a), []).append((b, row))
    for (e, a), rs in by_arm.items():
        top = rs[-1][1]["restarts"]
        rows.append([e, a, len(top), f"{sum(top)} ({sum(1 for x in top if x)})",
                     ", ".join(f"b{b} {x['failed']}" for b, x in rs)])
    return "\n".join(md_lines(head, rows))


def truth_table(g: Mapping) -> str:
    """Trained on the truth against trained on the model, under each mismatched truth: per model, truth and
    learner the RMSE (IQM over seeds [two-level 95 % CI]) trained on the model at the budget the truth's arms
    have and at the learner's top budget (an unseen mismatch) and trained on the truth's trajectories (the
    mismatch KalmanNet was made for: its data from the true system, its model ``f``, ``h`` nominal), with the
    seed-level difference truth - model at the same budget and the verdict on "lower"; then each pair of
    learners both trained on the truth. Every filter, reference and learner keeps the nominal model."""
    head = ["model, truth", "learner", "on the model, same budget", "on the model, top budget", "on the truth",
            "truth - model: lower?"]
    rows, pairs = [], []
    for e, regimes in g["models"].items():
        for r, m in regimes.items():
            if r == "nominal":
                continue
            for a, pts in m["curve"].items():
                spec = g["arms"][e][a]
                if spec["truth"] is not None or a not in {x for p in LEARNED_PAIRS for x in p}:
                    continue
                on = f"{a}-on-{r}"
                tb = str(g["arms"][e][on]["top"]) if on in g["arms"][e] else min(pts, key=int)
                top = max(pts, key=int)
                v = next((v for v in m["verdicts"] if v["a"] == on and v["b"] == a and v["budget"] == int(tb)), None)
                truth = _ci(m["curve"][on][tb]["rmse"]) if on in m["curve"] else "not trained"
                rows.append([f"{e}, {r}", a, f"b{tb}: {_ci(pts[tb]['rmse'])}",
                             f"b{top}: {_ci(pts[top]['rmse'])}", truth,
                             "n/a" if v is None else f"{_interval(v['diff'])} {v['lower']}"])
            pairs += [f"* {e}, {r}: {v['a']} - {v['b']} (b{v['budget']}, {v['isolates']}): "
                      f"{_interval(v['diff'])} {v['lower']}" for v in m["verdicts"]
                      if v["b"] in g["arms"][e] and "-on-" in v["a"] and "-on-" in v["b"]]
    return "\n".join(md_lines(head, rows) + ([""] + pairs if pairs else []))


def consistency_table(g: Mapping) -> str:
    """The consistency arm against the squared-error kappa, per model that has one and per budget: RMSE and
    ANEES of each (IQM over seeds [two-level 95 % CI]), and the seed-level difference consistency - squared
    error of each with its verdict (ANEES: "lower"; RMSE: "not worse" within the margin declared for that
    comparison, printed as ``margin m: not worse -> word``, the form the course's verdict check reads)."""
    from adaptfilt.experiments.studies.gain import CONSISTENCY

    head = ["model, budget", "arm", "RMSE", "ANEES", "ANEES: c - sq, lower", "RMSE: c - sq, not worse"]
    rows = []
    for e, arm in CONSISTENCY.items():
        if e not in g["models"]:
            continue
        m = g["models"][e]["nominal"]
        for b in sorted(m["curve"].get(arm, {}), key=int):
            vs = {v["metric"]: v for v in m["verdicts"]
                  if (v["a"], v["b"], v["budget"]) == (arm, "kappa-sqerr", int(b))}
            r, n = vs.get("rmse"), vs.get("anees")
            for i, a in enumerate(("kappa-sqerr", arm)):
                row = m["curve"][a][b]
                rows.append([f"{e}, {_budget(g, e, b)}" if i == 0 else "", a, _ci(row["rmse"]),
                             _ci(row["anees"]),
                             "" if i == 0 or n is None else f"{_interval(n['diff'])} {n['lower']}",
                             "" if i == 0 or r is None else
                             f"{_interval(r['diff'])}, margin {r['margin']:.3g}: not worse -> {r['not_worse']}"])
    return "\n".join(md_lines(head, rows))


def final_table(g: Mapping) -> str:
    """The top budgets under the nominal model on the final runs, a Markdown table: per model every arm
    (IQM over seeds [two-level 95 % CI]) and the references on the same runs, with the MSE in dB (IQM), the
    mean training CPU-s, the runs whose RMSE passed the divergence bound (per seed for the arms) and the
    failed trainings; the point-mass floor where there is one."""
    head = ["model", "policy", "RMSE", "MSE (dB)", "training CPU-s", "divergent runs"]
    rows = []
    for e, regimes in g["models"].items():
        m = regimes["nominal"]
        for a, row in m["final"].items():
            b = row["names"][0].rsplit("-b", 1)[1].split("-s")[0]
            fail = f", {row['failed']} failed" if row.get("failed") else ""
            rows.append([e, f"{a} b{b}{fail}", _ci(row["rmse"]), f"{row['mse_db']['iqm']:.3g}",
                         f"{_cpu(row):.3g}", ", ".join(map(str, row["divergent_error_rule"]))])
        for label, ref in m.get("final_references", m["references"]).items():
            name = label if label == ref["policy"] else ref["policy"] if ref["policy"].startswith(label) else \
                f"{label} ({ref['policy']})"
            rows.append([e, name, f"{ref['rmse']:.3g}", f"{ref['mse_db']:.3g}", "", ref["divergent_error_rule"]])
        floor = m.get("final_floor", m["floor"])
        if floor["rmse"] is not None:
            rows.append([e, f"point-mass floor ({floor['runs']} runs)", f"{floor['rmse']:.3g}", "", "", ""])
    return "\n".join(md_lines(head, rows))


# ------------------------------------------------------- the stored KalmanNets of the study (data/beyond/policies)
def stored_gain_policies(root=None) -> dict[tuple[str, str, int, int], object]:
    """The study's stored KalmanNet files (``beyond/policies/gain-{model}-{arm}-b{budget}-s{seed}.npz`` of
    ``root``, default the repository's ``data/``), every KalmanNet arm of :func:`~adaptfilt.experiments.studies.
    gain.arms_of`, loaded against their experiment's model: ``{(model, arm, budget, seed): KalmanNet}``, the
    training history in ``knet.history``."""
    import re

    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.artefacts import data_dir
    from adaptfilt.experiments.studies.gain import MODELS, NAME, arms_of
    from adaptfilt.kalmannet import load_kalmannet

    d = (data_dir() if root is None else Path(root)) / "beyond" / "policies"
    out = {}
    for e in MODELS:
        arms = [a for a, s in arms_of(e).items() if s["kind"] == "gain"]
        model = None
        for p in sorted(d.glob(f"{NAME}-{e}-*-b*-s*.npz")):
            m = re.fullmatch(rf"{NAME}-{re.escape(e)}-(.+)-b(\d+)-s(\d+)\.npz", p.name)
            if m and m.group(1) in arms:
                model = model or get_experiment(e).make_model()
                out[e, m.group(1), int(m.group(2)), int(m.group(3))] = load_kalmannet(p, model)
    if not out:
        raise FileNotFoundError(f"no KalmanNet files of the gain study in {d}: run `adaptfilt beyond --studies gain`")
    return out


def collapse_table(knets: Mapping[tuple[str, str, int, int], object]) -> str:
    """Where each KalmanNet arm's trainings ended their progress, from the histories of the top budget's files
    (one training per seed: the top budget's history holds the whole of it): per model and arm, the optimiser
    steps trained, the trainings that collapsed (:func:`adaptfilt.kalmannet.collapse_step`: the validation
    loss, after beating the untrained network's, above it from that step to the end) with the steps where
    they did, and the step of the best network kept (median over seeds; in how many seeds it comes from the
    last third of the training), and the returns to the best weights at half the learning rate
    (``history["restores"]``: a non-finite loss or, under ``collapse_after``, a collapse caught; in how many
    trainings)."""
    from adaptfilt.kalmannet import collapse_step

    top: dict[tuple[str, str], int] = {}
    for e, a, b, _ in knets:
        top[e, a] = max(b, top.get((e, a), 0))
    head = ["model", "arm", "top budget (optimiser steps)", "collapsed (from step)", "best network's step (median)",
            "best in the last third", "restores (trainings)"]
    rows = []
    for (e, a), b in top.items():
        hs = [knets[k].history for k in sorted(knets) if k[:3] == (e, a, b)]
        n = hs[0]["max_steps"]
        ups = sorted(x for x in (collapse_step(h) for h in hs) if x is not None)
        best = [h["best_step"] for h in hs]
        rest = [len(h.get("restores", [])) for h in hs]
        rows.append([e, a, f"b{b} ({n})", f"{len(ups)} of {len(hs)}" + (f" ({', '.join(map(str, ups))})" if ups else ""),
                     f"{float(np.median(best)):g}", f"{sum(x > 2 * n / 3 for x in best)} of {len(hs)}",
                     f"{sum(rest)} ({sum(r > 0 for r in rest)})"])
    return "\n".join(md_lines(head, rows))


def initial_attempt(knet) -> int | None:
    """The seed of the training attempt whose untrained initial network ``knet`` holds (compared weight for
    weight with a fresh network of that seed and the same options), or None for a trained network. The
    attempts are those of ``knet.history`` (the restart rule's seeds), or the file's seed alone."""
    import torch

    from adaptfilt.kalmannet import KalmanNet

    seeds = [a["seed"] for a in (getattr(knet, "history", None) or {}).get("attempts", [])] or [knet.seed]
    mine = knet.net.state_dict()
    for s in seeds:
        theirs = KalmanNet(knet.model, seed=s, scales=knet.scales, bounds=knet.bounds, **knet.options).net.state_dict()
        if mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine):
            return int(s)
    return None


def is_initial_network(knet) -> bool:
    """Whether ``knet`` holds the weights one of its training attempts started from (:func:`initial_attempt`):
    a training that never improved on an untrained network on validation and kept it."""
    return initial_attempt(knet) is not None
