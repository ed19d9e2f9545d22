r"""The analyses of chapter 9 (UKF on UNGM, experiment ``ungm-ukf``): a metric against a fixed
kappa in both conventions, the NIS gate (what kappa a policy chooses against the NIS that the full
update would give), and RMSE over time beside the Bayes floor per step.

==============================  ================================================================
function                        what
==============================  ================================================================
plot_fixed_conventions          a metric against a fixed kappa, in the update only and in both
                                steps, with the adaptive policies as reference bands
ungm_nis                        the NIS a UKF update with scaling kappa gives on UNGM (closed form)
gate_anatomy, gate_table,       UNGM: a policy's kappa against the NIS that kappa = 0 would give
plot_gate                       (does it update fully only when the measurement agrees?)
plot_rmse_steps,                RMSE_k in colours that can be told apart, with the Bayes floor
ungm_floor_steps                per step (the point-mass filter on the evaluation's first runs)
==============================  ================================================================

What chapters 9-11 share (seed tables, Figure 3): :mod:`adaptfilt.course.paper_common`. Seed groups
are policies named ``<group>-s<seed>``; where a function takes a group name, a single policy name
works as well (:func:`adaptfilt.experiments.claims.members`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from adaptfilt.course.paper_common import short_label, plain_log
from adaptfilt.experiments.claims import members
from adaptfilt.seed_stats import aggregate

__all__ = ["plot_fixed_conventions", "ungm_nis", "GateAnatomy", "gate_anatomy", "gate_table", "plot_gate",
           "plot_rmse_steps", "ungm_floor_steps"]


def _reference_band(ax, res, name: str, metric: str, color, label: str, ls: str = "-") -> None:
    a = aggregate(res, members(res, name), metric)
    ax.axhline(a.iqm, color=color, lw=1.4, ls=ls, label=label)
    ax.axhspan(*a.iqm_ci, color=color, alpha=0.15, lw=0)


def plot_fixed_conventions(res, metric: str = "rmse", refs: Sequence[str] = ("ml", "greedy", "adaptive"),
                           ax=None, unit: str | None = None, floor: float | None = None,
                           zoom: tuple[float, float] | None = None):
    r"""A metric (95 % CIs) against a *fixed* :math:`\kappa` in the two conventions, the update
    only (``fixed-kappa=v``) and predict and update (``fixed-both-kappa=v``), on a symlog axis;
    the policies ``refs`` as horizontal lines with their interval as a band (a seed group: its
    IQM and two-level interval), each in its own line style so that coinciding lines stay visible.

    ``zoom = (lo, hi)`` (only without ``ax``) adds a right panel on :math:`\kappa \in [lo, hi]` with a
    linear axis from the lowest value there to twice the bands' height, where reference lines a few hundredths
    apart can be told apart; the legend then gives each reference's value and interval. The legend
    sits below the axes. Returns the figure."""
    from adaptfilt import style
    from adaptfilt.plots import policy_style

    fixed = [float(n.split("=")[1]) for n in res.names if n.startswith(("fixed-kappa=", "fixed-both-kappa="))]
    if not fixed:
        raise ValueError("these results have no fixed-kappa policies")
    if zoom is not None and ax is not None:
        raise ValueError("zoom draws its own two panels: pass no ax")
    if zoom is None:
        fig, ax = style.figure() if ax is None else (ax.figure, ax)
        axes = [ax]
    else:
        fig, axes = style.figure(1, 2, size=(13, 5.4))
    what = {"rmse": "time-averaged RMSE", "anees": "time-averaged ANEES", "cost": "mean one-step cost"}.get(metric, metric)
    styles = ("-", "--", "-.", ":")
    for j, a in enumerate(axes):
        ys, refs_hi = [], []
        for prefix, label, ls in (("fixed-kappa=", "fixed κ, update only", "-"),
                                  ("fixed-both-kappa=", "fixed κ, predict and update", "--")):
            names = sorted((n for n in res.names if n.startswith(prefix)), key=lambda n: float(n.split("=")[1]))
            if not names:
                continue
            v = np.array([float(n.split("=")[1]) for n in names])
            y = np.array([getattr(res[n], metric) for n in names])
            ci = np.array([getattr(res[n], metric + "_ci") for n in names])
            a.errorbar(v, y, yerr=[y - ci[:, 0], ci[:, 1] - y], fmt="o" + ls, color="0.35" if ls == "-" else "0.6",
                       ms=3.5, lw=1.2, capsize=2, label=label)
            if zoom is not None:
                ys.extend(ci[(v >= zoom[0]) & (v <= zoom[1])].ravel())
        for i, r in enumerate(refs):
            agg = aggregate(res, members(res, r), metric)
            label = style.policy_label(r) + (" (IQM over seeds)" if len(members(res, r)) > 1 else "")
            if zoom is not None:
                label += f": {agg.iqm:.3g} [{agg.iqm_ci[0]:.3g}, {agg.iqm_ci[1]:.3g}]"
            _reference_band(a, res, r, metric, policy_style(res, members(res, r)[0])["color"], label,
                            ls=styles[i % len(styles)])
            ys.extend(agg.iqm_ci)
            refs_hi.append(agg.iqm_ci[1])
        if floor is not None:
            a.axhline(floor, color="0.2", ls=":", lw=1.2, label=f"Bayes floor {floor:.3g}")
        a.set_xscale("symlog", linthresh=1)
        a.set(xlabel=f"fixed {style.param_label('kappa')}", ylabel=what + (f" ({unit})" if unit else ""))
        if j == 0:
            a.set_xlim(left=-0.3 if min(fixed) >= 0 else None)  # no empty negative decades
            plain_log(a)
        else:
            # the bands fill the lower half; fixed values far above them leave the panel at the top
            lo = min(ys)
            hi = max(refs_hi) + (max(refs_hi) - lo) if refs_hi else max(ys)
            a.set(xlim=(zoom[0] / 1.3, zoom[1] * 1.3), ylim=(lo - 0.08 * (hi - lo), hi),
                  title=f"zoom: {style.param_label('kappa')} from {zoom[0]:g} to {zoom[1]:g}")
            # direct labels at the right end; lines that coincide get their labels stacked
            last, off = None, 0.0
            for r in sorted(refs, key=lambda r: aggregate(res, members(res, r), metric).iqm):
                y = aggregate(res, members(res, r), metric).iqm
                off = off + 9.0 if last is not None and abs(y - last) < 0.03 * (hi - lo) else 0.0
                a.annotate(style.policy_label(r), (zoom[1] * 1.25, y), xytext=(0, 2 + off), textcoords="offset points",
                           ha="right", va="bottom", fontsize=8.5,
                           color=policy_style(res, members(res, r)[0])["color"]).set_in_layout(False)
                last = y
    if zoom is None:
        ax.legend(ncol=3, fontsize=8.5, loc="upper center", bbox_to_anchor=(0.5, -0.2))  # below: the curves fill the axes
    else:
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=8.5)
    return fig


# ------------------------------------------------------------------ UNGM: the NIS gate
def ungm_nis(kappa, x_pred, P_pred, z, R: float = 1.0) -> np.ndarray:
    r"""The NIS of a UKF update with scaling :math:`\kappa` on UNGM (:math:`h(x) = x^2/20`,
    scalar state), in closed form (chapter 4):

    .. math::
        \hat z = (m^2 + P)/20 \ \text{(exact for every } \kappa),\qquad
        P^{zz}(\kappa) = \frac{4 m^2 P + \kappa P^2}{400} + R,\qquad
        \mathrm{NIS} = \frac{(z - \hat z)^2}{P^{zz}(\kappa)},

    with the predicted mean :math:`m` and variance :math:`P`. Arrays broadcast.

    >>> float(ungm_nis(0.0, 0.0, 1.0, 1.05, R=1.0))   # z - (0 + 1)/20 = 1
    1.0
    """
    m, P, z = (np.asarray(a, dtype=float) for a in (x_pred, P_pred, z))
    if np.any(P <= 0):
        raise ValueError("P_pred must be positive")
    pzz = (4 * m * m * P + np.asarray(kappa, dtype=float) * P * P) / 400.0 + R
    return (z - (m * m + P) / 20.0) ** 2 / pzz


@dataclass
class GateAnatomy:
    r"""A policy's choices on UNGM against the information state, per (run, step) ``(M, T)``.

    ``kappa``: the chosen update :math:`\kappa`; ``nis0``: the NIS the *smallest* grid value
    (:math:`\kappa_\min`, the full update) would give (:func:`ungm_nis`: a function of the
    information state, so a learned policy can see it too); ``wrong_sign``: the prediction is on
    the other branch than the truth (:math:`\operatorname{sign}\hat x_{k|k-1} \ne \operatorname{sign} x_k`);
    ``sq_err``: the squared filtering error; ``x_pred``, ``P_pred``, ``z`` and ``R``: the predicted
    moments, the measurement and its noise variance at each decision, from which :meth:`nis_at` gives
    the NIS of any other :math:`\kappa` in the same state."""

    name: str
    kappa: np.ndarray
    nis0: np.ndarray
    wrong_sign: np.ndarray
    sq_err: np.ndarray
    x_pred: np.ndarray | None = None
    P_pred: np.ndarray | None = None
    z: np.ndarray | None = None
    R: float = 1.0

    def nis_at(self, kappa) -> np.ndarray:
        r"""The NIS that each value of ``kappa`` would give at every recorded decision
        (:func:`ungm_nis` in the states this policy visited): shape ``kappa.shape + (M, T)``,
        so ``nis_at(grid)`` holds the whole grid, one row per value. ``nis_at(grid[0])`` is ``nis0``."""
        if self.x_pred is None:
            raise ValueError(f"the anatomy of {self.name!r} holds no predicted moments (made without gate_anatomy)")
        k = np.asarray(kappa, dtype=float)
        return ungm_nis(k.reshape(k.shape + (1, 1)), self.x_pred, self.P_pred, self.z, R=self.R)

    @property
    def rmse(self) -> float:
        """Time-averaged RMSE over these runs."""
        return float(np.sqrt(self.sq_err.mean(axis=0)).mean())

    def summary(self, coast: float = 1000.0) -> dict[str, float]:
        """Over all run-steps: ``agrees`` (share of steps with ``nis0 < 1``: the measurement agrees
        with the prediction), ``open_kappa`` (the kappa the policy chooses most often there) and
        ``open_share`` (how often), ``coast_if_surprise`` (share of kappa >= ``coast`` among the
        steps with ``nis0 >= 1``), ``wrong_sign`` and ``rmse``."""
        agree = self.nis0 < 1.0
        vals, counts = np.unique(self.kappa[agree], return_counts=True)
        top = int(np.argmax(counts)) if counts.size else None
        return {"agrees": float(agree.mean()),
                "open_kappa": float(vals[top]) if top is not None else np.nan,
                "open_share": float(counts[top] / counts.sum()) if top is not None else np.nan,
                "coast_if_surprise": float((self.kappa[~agree] >= coast).mean()) if (~agree).any() else np.nan,
                "wrong_sign": float(self.wrong_sign.mean()), "rmse": self.rmse}


def gate_anatomy(env, policy, traj, name: str | None = None) -> GateAnatomy:
    """Roll ``policy`` out through ``env`` (a UNGM environment, e.g.
    ``get_experiment("ungm-ukf").make_env()``) on ``traj`` and record its :class:`GateAnatomy`."""
    from adaptfilt.mdp import rollout

    if env.nx != 1 or env.nz != 1 or getattr(env.filt.model, "name", "") != "ungm":
        raise ValueError(f"gate_anatomy is for the UNGM UKF (h = x^2/20); got model {getattr(env.filt.model, 'name', '?')!r}")
    run, _ = rollout(env, policy, traj=traj, keep_pred=True)
    m, P = run.x_pred[..., 0], run.P_pred[..., 0, 0]
    T = m.shape[1]
    x, z = traj.x[:, :T, 0], traj.z[:, :T, 0]
    R = float(env.filt.model.R[0, 0])
    nis0 = ungm_nis(float(np.min(env.grid)), m, P, z, R=R)
    return GateAnatomy(name or getattr(policy, "name", "policy"), run.params, nis0, np.sign(m) != np.sign(x),
                       (run.mean[..., 0] - x) ** 2, m, P, z, R)


def gate_table(anatomies: Sequence[GateAnatomy], coast: float = 1000.0) -> str:
    """One printed line per anatomy (:meth:`GateAnatomy.summary`): RMSE, the kappa chosen when
    the measurement agrees (NIS0 < 1) and how often, the share coasting (kappa >= ``coast``)
    when it does not, and the share of steps predicted on the wrong branch."""
    w = max(len(a.name) for a in anatomies)
    lines = [f"{'policy':<{w}}  {'RMSE':>5} | NIS0<1: kappa (share) | NIS0>=1: kappa>={coast:g} | wrong sign"]
    for a in anatomies:
        s = a.summary(coast)
        lines.append(f"{a.name:<{w}}  {s['rmse']:5.2f} | {s['open_kappa']:>8g} ({s['open_share']:.2f})       "
                     f"| {s['coast_if_surprise']:17.2f}    | {s['wrong_sign']:.3f}")
    return "\n".join(lines)


def plot_gate(anatomies: Sequence[GateAnatomy], ax=None, bins=None):
    r"""The median :math:`\kappa` chosen against the NIS that the full update (the smallest
    :math:`\kappa` of the grid) would give, in log bins (at least 20 run-steps each), one line per
    anatomy: a gate is a jump from a small to a large :math:`\kappa` near NIS = 1."""
    from adaptfilt import style

    fig, ax = style.figure() if ax is None else (ax.figure, ax)
    bins = np.logspace(-4, 4, 33) if bins is None else np.asarray(bins, dtype=float)
    mid = np.sqrt(bins[:-1] * bins[1:])
    n_other = sum(a.name != "greedy" for a in anatomies)
    # other lines: each its own colour and marker, the earlier ones wider, so coinciding lines stay visible
    looks = iter(zip(style.colors(max(1, n_other)), np.linspace(2.8, 1.2, max(1, n_other)), "osD^v<>ph" * 4))
    for a in anatomies:
        idx = np.digitize(a.nis0.ravel(), bins) - 1
        k = a.kappa.ravel()
        med = np.array([np.median(k[idx == i]) if (idx == i).sum() >= 20 else np.nan for i in range(mid.size)])
        if a.name == "greedy":
            # the reference: thick, dashed and on top, so it stays visible where the other lines follow it
            ax.plot(mid, med, color="black", ls="--", lw=2.2, zorder=5, label="greedy")
        else:
            col, lw, mk = next(looks)
            ax.plot(mid, med, marker=mk, ms=1.5 * lw + 1.5, lw=lw, color=col, zorder=3, label=style.policy_label(a.name))
    ax.axvline(1.0, color="0.6", ls=":", lw=1)
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=1)
    ax.set_ylim(-0.3 if np.nanmin([a.kappa.min() for a in anatomies]) >= 0 else None, None)
    ax.set(xlabel=r"NIS that the full update ($\kappa_\min$) would give", ylabel=r"median $\kappa$ chosen")
    ax.legend(fontsize=8.5, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    return fig


# ------------------------------------------------------------------ UNGM: RMSE over time and the Bayes floor per step
def plot_rmse_steps(res, names: Sequence[str], floor_t: np.ndarray | None = None, floor_label: str = "Bayes floor",
                    ax=None, unit: str | None = None):
    """``RMSE_k`` of ``names`` (a seed group: the mean of its seeds' curves), the adaptive policies in
    their colours of :mod:`adaptfilt.plots` and the fixed ones in colours that tell them apart (the
    viridis map there gives a fixed value in the update and one in both steps neighbouring greens), with a per-step
    reference ``floor_t`` (e.g. :func:`ungm_floor_steps`) dotted, on a log axis; the legend sits
    right of the axes. Returns the figure."""
    from adaptfilt import style

    from adaptfilt.plots import policy_style

    fig, ax = style.figure() if ax is None else (ax.figure, ax)
    palette = iter(("#009E73", "#CC79A7", "#56B4E9", "#D55E00", "#F0E442") * 4)  # none of the adaptive colours
    for n in names:
        y = np.mean([np.asarray(res[m].rmse_t, dtype=float) for m in members(res, n)], axis=0)
        st = policy_style(res, members(res, n)[0])
        c = next(palette) if st["family"] == "fixed" else st["color"]  # adaptive: the colours of every figure
        ax.plot(np.arange(1, y.size + 1), y, color=c, lw=1.1, label=short_label(n))
    if floor_t is not None:
        f = np.asarray(floor_t, dtype=float)
        ax.plot(np.arange(1, f.size + 1), f, color="0.3", ls=":", lw=1.3, label=floor_label)
    plain_log(ax)
    ax.set(xlabel="time step $k$", ylabel="RMSE$_k$" + (f" ({unit})" if unit else ""),
           xlim=(1, max(np.asarray(res[members(res, names[0])[0]].rmse_t).size, 2)))
    ax.legend(fontsize=8.5, loc="center left", bbox_to_anchor=(1.01, 0.5))
    return fig


def ungm_floor_steps(n_runs: int = 200, seed: int = 0, n_steps: int | None = None,
                     eval_runs: int = 10_000, chunk: int = 100) -> np.ndarray:
    """The Bayes floor per step on UNGM, ``RMSE_k (T,)`` of :func:`adaptfilt.exact.bayes_floor` (the
    point-mass filter, grid -45..45, 901 points, as :func:`adaptfilt.experiments.references.ungm_floor`) on
    the first ``n_runs`` trajectories of the UNGM evaluation with ``seed`` (the runs the stored floor and
    the policies are scored on; ``data/`` stores only the floor's time average)."""
    from adaptfilt.exact import UNGM_FLOOR_GRID, bayes_floor
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.runs import EvalRuns

    env = get_experiment("ungm-ukf").make_env(seed=seed, n_steps=n_steps)
    runs = EvalRuns(env.model, max(int(eval_runs), n_runs), seed, env.n_steps)
    return bayes_floor(env.model, runs, n_runs, UNGM_FLOOR_GRID, chunk=chunk).rmse_t
