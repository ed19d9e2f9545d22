r"""Analyses behind the experiment chapters of the course (8: UKF on UNGM, 9: UKF on CTM,
10: SIF on CTM): what a stored evaluation says at the seed level, and what the rule-based
and learned policies choose, and why.

==============================  ================================================================
function                        what
==============================  ================================================================
seed_table_md                   per-seed values of seed groups beside their IQM and interval
differences_md                  seed-level differences ``a - b`` (paired over runs) as a table
usage_md                        how often each grid value is used, per policy or training seed
plain_log                       a log axis labelled with plain numbers
plot_fixed_conventions          a metric against a fixed kappa, in the update only and in both
                                steps, with the adaptive policies as reference bands
ungm_nis                        the NIS a UKF update with scaling kappa gives on UNGM (closed form)
gate_anatomy, gate_table,       UNGM: a policy's kappa against the NIS that kappa = 0 would give
plot_gate                       (does it update fully only when the measurement agrees?)
plot_cost_time                  mean one-step cost over time (windowed), per policy
reach_anatomy, reach_table      what the grid can do to the predicted measurement variance against
                                the squared innovation, and which value a policy chooses
line_of_sight,                  CTM: position errors and claimed standard deviations along and
line_of_sight_table,            across the line of sight from the sensor (range is what a single
plot_line_of_sight              bearing sensor cannot see), per filter
sif_spread                      the SIF's integration noise: spread of estimates on identical data
place_labels                    point labels that overlap neither each other nor the markers
plot_tradeoff_panels            Figures 3 and 6: every policy, and a zoom on the ones a chapter
                                discusses, labelled without overlaps
plot_rmse_steps,                RMSE_k in colours that can be told apart, with the Bayes floor
ungm_floor_steps                per step (the point-mass filter on the evaluation's first runs)
position_velocity_rmse,         CTM: the error of the position (m) and of the velocity (m/s)
position_velocity_md,           apart, per policy (the full-state RMSE mixes the two; the table can
plot_position_velocity          set the stored evaluation's full-state RMSE beside it)
innovation_response,            SIF: the iterations a policy chooses early and late in the run and
innovation_responses,           by quartile of the one-iteration innovation it saw, per training
innovation_response_md          seed, and summarised over the seeds of each group
==============================  ================================================================

Seed groups are policies named ``<group>-s<seed>``
(:func:`adaptfilt.seed_stats.seed_groups`); where a function takes a group name, a
single policy name works as well (:func:`adaptfilt.experiments.claims.members`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from adaptfilt.experiments.claims import compare, members
from adaptfilt.experiments.report import fmt
from adaptfilt.seed_stats import aggregate

__all__ = ["seed_table_md", "differences_md", "usage_shares", "usage_md", "plain_log", "plot_fixed_conventions",
           "ungm_nis", "GateAnatomy", "gate_anatomy", "gate_table", "plot_gate", "plot_cost_time", "ReachAnatomy",
           "reach_anatomy", "reach_table", "LineOfSight",
           "line_of_sight", "line_of_sight_table", "plot_line_of_sight", "sif_spread",
           "place_labels", "plot_tradeoff_panels", "plot_rmse_steps", "ungm_floor_steps", "position_velocity_rmse",
           "position_velocity_md", "plot_position_velocity", "innovation_response", "innovation_responses",
           "innovation_response_md"]


def _md(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows]) + "\n"


def seed_table_md(res, groups: Sequence[str] = ("adaptive", "myopic"),
                  metrics: Sequence[str] = ("rmse", "anees", "cost", "objective")) -> str:
    """One row per (seed group, metric): the IQM over seeds with its two-level 95 % interval,
    the mean over seeds, and every seed's own value (columns ``s0``, ``s1``, ...).

    A learned result is a distribution over training seeds; this is that distribution
    next to its summary. Groups missing from ``res`` are skipped (e.g. faithful policies
    that are not evaluated yet); none present raises ``ValueError``.
    """
    present = []
    for g in groups:
        try:
            present.append((g, members(res, g)))
        except KeyError:
            continue
    if not present:
        raise ValueError(f"none of the groups {list(groups)} is in these results")
    n = max(len(m) for _, m in present)
    rows = []
    for g, names in present:
        for m in metrics:
            a = aggregate(res, names, m)
            vals = [f"{v:.3g}" for v in a.values] + [""] * (n - len(names))
            rows.append([g, m, fmt(a.iqm, a.iqm_ci, 3), f"{a.mean:.3g}", *vals])
    return _md(["group", "metric", "IQM [95 % CI]", "mean", *[f"s{i}" for i in range(n)]], rows)


def differences_md(res, pairs: Sequence[tuple[str, str]], metrics: Sequence[str] = ("rmse", "anees")) -> str:
    """Seed-level differences ``a - b`` of every pair on every metric
    (:func:`adaptfilt.experiments.claims.compare`: seeds resampled per group, runs paired), with
    the interval and whether it excludes zero (``a < b``, ``a > b`` or ``n.s.``)."""
    rows = []
    for a, b in pairs:
        for m in metrics:
            c = compare(res, a, b, m)
            lo, hi = c["ci"]
            sign = "a < b" if hi < 0 else "a > b" if lo > 0 else "n.s."
            rows.append([f"{a} - {b}", m, f"{c['a_value']:.4g}", f"{c['b_value']:.4g}",
                         f"{c['diff']:+.3g} [{lo:+.3g}, {hi:+.3g}]", sign])
    return _md(["a - b", "metric", "a (IQM)", "b (IQM)", "a - b [95 % CI]", "interval"], rows)


def usage_shares(res, names: Sequence[str]) -> dict[str, np.ndarray]:
    """``{name: (G,) fraction of all run-steps using each grid value}``; a seed group is
    expanded into its seeds."""
    out = {}
    for n in names:
        for m in members(res, n):
            u = np.asarray(res[m].usage, dtype=float)
            out[m] = u / max(u.sum(), 1.0)
    return out


def usage_md(res, names: Sequence[str], min_share: float = 0.01) -> str:
    """How often each grid value is used (percent of run-steps), one row per policy or seed;
    only the grid values some row uses at least ``min_share`` of the time get a column."""
    shares = usage_shares(res, names)
    grid = res.grid
    keep = np.max(np.stack(list(shares.values())), axis=0) >= min_share
    pname = res.config.get("param_name", "param")
    from adaptfilt.style import param_label

    head = ["policy"] + [param_label(pname, g) for g, k in zip(grid, keep) if k]
    rows = [[n] + [f"{100 * s:.0f} %" if s >= 0.005 else "." for s, k in zip(u, keep) if k] for n, u in shares.items()]
    return _md(head, rows)


def plain_log(ax, axis: str = "y") -> None:
    """Make ``axis`` (``"x"``, ``"y"`` or ``"both"``) of ``ax`` logarithmic and label it with plain
    numbers at 1, 2, 3 and 5 times the powers of ten (not ``2 x 10^0``)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    if axis not in ("x", "y", "both"):
        raise ValueError(f"axis must be 'x', 'y' or 'both', got {axis!r}")
    for name in ("x", "y") if axis == "both" else (axis,):
        getattr(ax, f"set_{name}scale")("log")
        a = getattr(ax, f"{name}axis")
        a.set_major_locator(LogLocator(subs=(1.0, 2.0, 3.0, 5.0)))
        a.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        a.set_minor_formatter(NullFormatter())


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
    ``sq_err``: the squared filtering error."""

    name: str
    kappa: np.ndarray
    nis0: np.ndarray
    wrong_sign: np.ndarray
    sq_err: np.ndarray

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
    nis0 = ungm_nis(float(np.min(env.grid)), m, P, z, R=float(env.filt.model.R[0, 0]))
    return GateAnatomy(name or getattr(policy, "name", "policy"), run.params, nis0, np.sign(m) != np.sign(x),
                       (run.mean[..., 0] - x) ** 2)


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


# ------------------------------------------------------------------ costs over time
def plot_cost_time(res, names: Sequence[str], window: int = 10, ax=None):
    """Mean one-step cost over runs (``cost_t``), averaged over windows of ``window`` steps, per
    policy (a seed group: the mean of its seeds' curves), on a log axis."""
    from adaptfilt import style
    from adaptfilt.plots import policy_style

    fig, ax = style.figure() if ax is None else (ax.figure, ax)
    for n in names:
        c = np.mean([np.asarray(res[m].cost_t, dtype=float) for m in members(res, n)], axis=0)
        T = c.size // window * window
        k = np.arange(T).reshape(-1, window).mean(axis=1) + 1
        ax.plot(k, c[:T].reshape(-1, window).mean(axis=1), "o-", ms=3,
                color=policy_style(res, members(res, n)[0])["color"], label=style.policy_label(n))
    plain_log(ax)
    ax.set(xlabel="time step $k$", ylabel=f"mean one-step cost ({window}-step windows)")
    ax.legend(fontsize=8.5)
    return fig


# ------------------------------------------------------------------ what the grid can reach
@dataclass
class ReachAnatomy:
    r"""Per (run, step) ``(M, T)`` of a policy's own run, for a scalar measurement: ``choice`` (the
    grid value chosen), ``nis_default`` (the NIS of the default parameter's update), ``pzz_lo`` and
    ``pzz_hi`` (the smallest and largest :math:`P^{zz}` any grid value gives) and ``nu2`` (the squared
    innovation of the default update). The NIS cost :math:`(\nu^2/P^{zz} - 1)^2` wants
    :math:`P^{zz} = \nu^2`; when :math:`\nu^2` is outside ``[pzz_lo, pzz_hi]`` the grid cannot reach it."""

    name: str
    grid: np.ndarray
    choice: np.ndarray
    nis_default: np.ndarray
    pzz_lo: np.ndarray
    pzz_hi: np.ndarray
    nu2: np.ndarray

    @property
    def inside(self) -> np.ndarray:
        """``(M, T)``: the squared innovation is within the reachable range of :math:`P^{zz}`."""
        return (self.nu2 >= self.pzz_lo) & (self.nu2 <= self.pzz_hi)


def reach_anatomy(env, policy, traj, name: str | None = None) -> ReachAnatomy:
    """Roll ``policy`` through ``env`` (scalar measurement) on ``traj``, computing at every step the
    update for every grid value (``Decision.candidates``) to record a :class:`ReachAnatomy`."""
    if env.nz != 1:
        raise ValueError(f"reach_anatomy needs a scalar measurement (nz = 1), got nz = {env.nz}")
    G = env.grid.size
    d = env.reset(traj=traj)
    rows = {k: [] for k in ("choice", "nis_default", "pzz_lo", "pzz_hi", "nu2")}
    while d is not None:
        c = d.candidates()
        pzz = np.asarray(c["update"].Pzz)[0, 0].reshape(G, -1)  # candidates are grid-major
        nu = np.asarray(c["update"].innovation)[0].reshape(G, -1)[env.default_index]
        a = np.asarray(policy.act(d))
        rows["choice"].append(env.grid[a])
        rows["nis_default"].append(c["nis"][env.default_index])
        rows["pzz_lo"].append(pzz.min(axis=0))
        rows["pzz_hi"].append(pzz.max(axis=0))
        rows["nu2"].append(nu * nu)
        d, _, done, _ = env.step(a)
        if done:
            break
    arr = {k: np.stack(v, axis=1) for k, v in rows.items()}  # (M, T)
    return ReachAnatomy(name or getattr(policy, "name", "policy"), np.asarray(env.grid), **arr)


def reach_table(anatomies: Sequence[ReachAnatomy], edges: Sequence[float] = (0.5, 1.0, 3.0, 10.0)) -> str:
    """Printed summary per anatomy: the median ratio of the largest to the smallest reachable
    :math:`P^{zz}`, the share of steps whose squared innovation is reachable, and, per bin of the
    default update's NIS, the share of steps and how often the smallest, the largest or an inner grid
    value is chosen."""
    lines = []
    bins = [-np.inf, *edges, np.inf]
    for a in anatomies:
        lo, hi = a.grid.min(), a.grid.max()
        lines.append(f"{a.name}: largest / smallest reachable Pzz, median {np.median(a.pzz_hi / a.pzz_lo):.2f}; "
                     f"squared innovation reachable at {a.inside.mean():.0%} of the steps")
        lines.append(f"   NIS of the default update   steps   chooses {lo:g}   {hi:g}   in between")
        for b0, b1 in zip(bins[:-1], bins[1:]):
            m = (a.nis_default >= b0) & (a.nis_default < b1)
            if not m.any():
                continue
            ch = a.choice[m]
            what = f"< {b1:g}" if b0 == -np.inf else f">= {b0:g}" if b1 == np.inf else f"{b0:g} .. {b1:g}"
            lines.append(f"   {what:>26}   {m.mean():5.0%}   {(ch == lo).mean():10.0%}   {(ch == hi).mean():4.0%}   "
                         f"{((ch > lo) & (ch < hi)).mean():10.0%}")
    return "\n".join(lines)


# ------------------------------------------------------------------ CTM: range and cross-range
@dataclass
class LineOfSight:
    r"""Position errors and claimed standard deviations along the true line of sight from the
    sensor at the origin, :math:`\mathbf u = \mathbf p/\|\mathbf p\|` (range), and across it,
    :math:`\mathbf v = [-u_2, u_1]` (cross-range), per (run, step) ``(M, T)``:
    ``err_range`` :math:`= \tilde{\mathbf p}^T\mathbf u`, ``sd_range`` :math:`= \sqrt{\mathbf u^T\mathbf P^{pp}\mathbf u}`,
    and the same across. For a consistent filter each normalised squared error
    ``(err / sd)^2`` is :math:`\chi^2_1`: mean 1, median 0.455."""

    err_range: np.ndarray
    err_cross: np.ndarray
    sd_range: np.ndarray
    sd_cross: np.ndarray


def line_of_sight(x: np.ndarray, run, pos: Sequence[int] = (0, 2)) -> LineOfSight:
    """:class:`LineOfSight` of a filter ``run`` (``mean (M, T, nx)``, ``cov (M, T, nx, nx)``) against
    the true states ``x (M, T, nx)``; ``pos`` are the indices of the two position coordinates."""
    from adaptfilt.course.moments import line_of_sight_errors

    pos = list(pos)
    err_r, err_c = line_of_sight_errors(x, run.mean, pos)
    p = np.asarray(x, dtype=float)[..., pos]
    u = p / np.linalg.norm(p, axis=-1, keepdims=True)
    v = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    Ppp = np.asarray(run.cov)[..., pos, :][..., pos]
    sd = lambda a: np.sqrt(np.einsum("...i,...ij,...j->...", a, Ppp, a))
    return LineOfSight(err_r, err_c, sd(u), sd(v))


def line_of_sight_table(x: np.ndarray, runs: dict, pos: Sequence[int] = (0, 2)) -> str:
    """One printed line per filter of ``runs`` (``{name: FilterRun}``): time-averaged RMSE of the full
    state and of the position (``pos``) alone, RMS error
    and RMS claimed standard deviation in range and cross-range, the median normalised squared
    error in each direction (0.455 for a consistent filter) and the median NEES
    (the chi-square median for ``nx`` degrees of freedom). The chi-square medians of the header are the
    yardstick for a Gaussian posterior; where the exact posterior is not Gaussian, even its own mean
    and covariance give normalised errors of mean 1 (per direction) whose median differs from 0.455."""
    from scipy import stats

    nx = np.asarray(x).shape[-1]
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))
    w = max(len(n) for n in runs)
    lines = [f"Gaussian and consistent: median (e/sd)^2 = {stats.chi2.median(1):.3f} (chi2_1), "
             f"median NEES = {stats.chi2.median(nx):.2f} (chi2_{nx})",
             f"{'filter':<{w}}   RMSE   pos RMSE | range: error  claimed sd  median (e/sd)^2 | cross: error  claimed sd  "
             f"median (e/sd)^2 | median NEES"]
    for n, run in runs.items():
        los = line_of_sight(x, run, pos)
        e = np.asarray(x) - run.mean
        nees = np.einsum("...i,...i->...", e, np.linalg.solve(run.cov, e[..., None])[..., 0])
        rmse = float(np.sqrt((e ** 2).sum(-1).mean(axis=0)).mean())
        prmse = float(np.sqrt((e[..., list(pos)] ** 2).sum(-1).mean(axis=0)).mean())
        lines.append(f"{n:<{w}}  {rmse:5.1f}  {prmse:9.1f} | {rms(los.err_range):12.1f}  {rms(los.sd_range):10.1f}  "
                     f"{np.median((los.err_range / los.sd_range) ** 2):15.2f} | {rms(los.err_cross):12.1f}  "
                     f"{rms(los.sd_cross):10.1f}  {np.median((los.err_cross / los.sd_cross) ** 2):15.2f} | "
                     f"{np.median(nees):.2f}")
    return "\n".join(lines)


def plot_line_of_sight(x: np.ndarray, runs: dict, pos: Sequence[int] = (0, 2), unit: str = "m"):
    """Two panels (range, cross-range): for each filter the RMS error over runs against time (solid)
    and the RMS standard deviation it claims (dashed). Returns the figure."""
    from adaptfilt import style

    fig, axes = style.figure(1, 2, sharey=True, size=(11, 3.8))
    k = None
    for (n, run), color in zip(runs.items(), style.colors(len(runs))):
        los = line_of_sight(x, run, pos)
        k = np.arange(1, los.err_range.shape[1] + 1)
        for ax, e, s in ((axes[0], los.err_range, los.sd_range), (axes[1], los.err_cross, los.sd_cross)):
            ax.plot(k, np.sqrt((e ** 2).mean(axis=0)), color=color, label=f"{n}: RMS error")
            ax.plot(k, np.sqrt((s ** 2).mean(axis=0)), color=color, ls="--", label=f"{n}: claimed sd")
    for ax, what in zip(axes, ("along the line of sight (range)", "across the line of sight")):
        ax.set(xlabel="time step $k$", title=what, ylim=(0, None))
    axes[0].set_ylabel(f"position error ({unit})")
    axes[1].legend(fontsize=8.5)
    return fig


# ------------------------------------------------------------------ SIF integration noise
def sif_spread(filt_factory, n_iters: Sequence[int], traj, n_filters: int = 500, pos=(0, 2)) -> dict[str, np.ndarray]:
    """The integration noise of a stochastic filter: the first run of ``traj`` filtered
    ``n_filters`` times (identical data, so all spread is the rule's randomness) with
    ``filt_factory(n_iter)`` for each ``n_iter``. Returns ``{"n_iter", "spread", "claimed"}``:
    the standard deviation over the filters of the final position estimate, and the
    position standard deviation the filters claim (root mean of the diagonal of ``P``),
    both averaged over the ``pos`` coordinates."""
    pos = list(pos)
    z = np.repeat(np.asarray(traj.z)[:1], n_filters, axis=0)
    spread, claimed = [], []
    for n in n_iters:
        run = filt_factory(int(n)).run(z)
        spread.append(run.mean[:, -1, pos].std(axis=0).mean())
        claimed.append(np.sqrt(np.diagonal(run.cov[:, -1], axis1=-2, axis2=-1)[:, pos].mean()))
    return {"n_iter": np.asarray(n_iters, dtype=float), "spread": np.array(spread), "claimed": np.array(claimed)}


# ------------------------------------------------------------------ labels that keep clear of each other
def place_labels(ax, points: dict, colors: dict | None = None, fontsize: float = 8, avoid=(), segments=(),
                 max_dist: float = 42.0) -> dict:
    """Label data points of ``ax`` with texts that overlap neither each other nor the markers.

    ``points``: ``{label: (x, y)}`` in data coordinates, in priority order (the first label gets the
    best place). ``avoid``: more ``(x, y)`` data points to keep clear of (unlabelled markers);
    ``segments``: ``((x0, y0), (x1, y1))`` axis-parallel data segments to keep clear of (error bars).
    Each label tries offsets in 16 directions at growing distances (up to ``max_dist`` points) and
    takes the one with the least overlap (measured on the rendered text) with the markers, the
    labels already placed and the outside of the axes; a label set away from its point gets a thin
    leader line. Call it after the axes limits are final. Returns ``{label: Annotation}``."""
    fig = ax.figure
    fig.canvas.draw()  # settle the layout, so that the data-to-display transform is the final one
    r = fig.canvas.get_renderer()
    pt = fig.dpi / 72.0
    disp = lambda xy: ax.transData.transform(np.asarray(xy, dtype=float))
    a = ax.get_window_extent(r)
    taken = [(x - 5 * pt, y - 5 * pt, x + 5 * pt, y + 5 * pt)
             for x, y in (disp(xy) for xy in [*points.values(), *avoid])]
    for p0, p1 in segments:
        (u0, v0), (u1, v1) = disp(p0), disp(p1)
        taken.append((min(u0, u1) - 2 * pt, min(v0, v1) - 2 * pt, max(u0, u1) + 2 * pt, max(v0, v1) + 2 * pt))

    def cost(b):
        inter = sum(max(0.0, min(b[2], o[2]) - max(b[0], o[0])) * max(0.0, min(b[3], o[3]) - max(b[1], o[1]))
                    for o in taken)
        inside = max(0.0, min(b[2], a.x1) - max(b[0], a.x0)) * max(0.0, min(b[3], a.y1) - max(b[1], a.y0))
        return inter + 4.0 * ((b[2] - b[0]) * (b[3] - b[1]) - inside)

    out = {}
    for label, xy in points.items():
        t = ax.text(0, 0, label, fontsize=fontsize)
        bb = t.get_window_extent(r)
        t.remove()
        w, h = bb.width + 2 * pt, bb.height + 1 * pt
        x0, y0 = disp(xy)
        best = None
        for d in np.arange(5.0, max_dist + 1e-9, 5.0):
            for ang in np.deg2rad(np.arange(0, 360, 22.5)):
                c, s = np.cos(ang), np.sin(ang)
                cx, cy = x0 + d * pt * c + c * w / 2, y0 + d * pt * s + s * h / 2  # the box's near side at d
                b = (cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)
                score = cost(b) + 0.4 * d * pt * h  # prefer near places among free ones
                if best is None or score < best[0]:
                    best = (score, b, cx, cy, d)
        _, b, cx, cy, d = best
        taken.append(b)
        color = (colors or {}).get(label, "0.2")
        ann = ax.annotate(label, xy, xytext=((cx - x0) / pt, (cy - y0) / pt), textcoords="offset points",
                          ha="center", va="center", fontsize=fontsize, color=color, zorder=5,
                          arrowprops=dict(arrowstyle="-", lw=0.5, color=color, shrinkA=0, shrinkB=3) if d > 12 else None)
        ann.set_in_layout(False)
        out[label] = ann
    return out


def _short(name: str) -> str:
    from adaptfilt.style import policy_label

    return policy_label(name[len("fixed-"):] if name.startswith("fixed-") else name)


def plot_tradeoff_panels(res, names: Sequence[str], zoom: Sequence[str], floor: float | None = None,
                         unit: str | None = None, label: Sequence[str] | None = None,
                         size: tuple[float, float] = (13, 6.4)):
    r"""Figures 3 and 6: time-averaged RMSE (across) against ANEES (up), every policy of ``names`` on
    the left, and on the right a zoom on the policies ``zoom`` (chosen by the chapter: the ones it
    discusses), whose box is drawn dashed on the left. Seed groups (``collapse_seeds``) show their
    IQM with the two-level interval and one faint dot per seed; fixed values are joined in grid
    order. Labels never overlap (:func:`place_labels`): on the left the points outside the zoom box,
    on the right those of ``label`` (default: all of ``zoom``). The legend sits below the panels.
    Returns the figure."""
    from matplotlib.patches import Rectangle

    from adaptfilt import style
    from adaptfilt.plots import plot_tradeoff, policy_style

    fig, (ax, axz) = style.figure(1, 2, size=size)
    plot_tradeoff(res, list(names), ax=ax, floor=floor, annotate=False, unit=unit)
    plot_tradeoff(res, list(zoom), ax=axz, annotate=False, unit=unit, logx=False, logy=False)
    handles, labels = ax.get_legend_handles_labels()
    labels = [t.replace(" nx ", " $n_x$ ") for t in labels]  # "ideal ANEES = nx = 1"
    for a in (ax, axz):
        a.get_legend().remove()
    seeds = lambda n, m: list(getattr(res[n], "seed_points", {}).get(m, []))
    xs = np.concatenate([res[n].rmse_ci for n in zoom])  # the intervals: a far seed dot may fall outside
    ys = np.concatenate([res[n].anees_ci for n in zoom])
    pad = lambda v: (v.min() - 0.06 * np.ptp(v), v.max() + 0.06 * np.ptp(v))
    (x0, x1), (y0, y1) = pad(xs), pad(ys)
    axz.set(xlim=(x0, x1), ylim=(y0, y1), title="zoom: the dashed box on the left", ylabel="")
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", lw=0.9, color="0.35", zorder=0))
    ax.set_title("every policy")
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 5), fontsize=8.5)
    color = lambda n: policy_style(res, n)["color"] if policy_style(res, n)["family"] != "fixed" else "0.25"
    outside = [n for n in names if not (x0 <= res[n].rmse <= x1 and y0 <= res[n].anees <= y1)]
    for a, sel, rest in ((axz, list(zoom if label is None else label), zoom), (ax, outside, names)):
        order = sorted(sel, key=lambda n: n.startswith("fixed-"))  # adaptive policies place first
        dots = [(u, v) for n in rest for u, v in zip(seeds(n, "rmse"), seeds(n, "anees"))]
        bars = [s for n in rest for s in (((res[n].rmse_ci[0], res[n].anees), (res[n].rmse_ci[1], res[n].anees)),
                                          ((res[n].rmse, res[n].anees_ci[0]), (res[n].rmse, res[n].anees_ci[1])))]
        place_labels(a, {_short(n): (res[n].rmse, res[n].anees) for n in order},
                     colors={_short(n): color(n) for n in order}, segments=bars,
                     avoid=[(res[n].rmse, res[n].anees) for n in rest if n not in sel] + dots)
    return fig


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
        ax.plot(np.arange(1, y.size + 1), y, color=c, lw=1.1, label=_short(n))
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
    """The Bayes floor per step on UNGM, ``RMSE_k (T,)`` of the point-mass filter (grid -45..45, 901
    points, as :func:`adaptfilt.experiments.references.ungm_floor`) on the first ``n_runs``
    trajectories of the UNGM evaluation with ``seed`` (the runs the stored floor and the policies
    are scored on; ``data/`` stores only the floor's time average)."""
    from adaptfilt import metrics
    from adaptfilt.evaluation import TRAJ_SEED_KEY
    from adaptfilt.exact import PointMassFilter
    from adaptfilt.experiment_registry import get_experiment

    env = get_experiment("ungm-ukf").make_env(seed=seed, n_steps=n_steps)
    traj = env.model.simulate(max(int(eval_runs), n_runs), env.n_steps,
                              rng=np.random.default_rng([TRAJ_SEED_KEY, int(seed)]))
    pmf = PointMassFilter(env.model, grid=np.linspace(-45, 45, 901))
    x, z = traj.x[:n_runs], traj.z[:n_runs]
    se = np.concatenate([metrics.squared_error(x[i:i + chunk], pmf.run(z[i:i + chunk]).mean)
                         for i in range(0, n_runs, chunk)])
    return np.sqrt(se.mean(axis=0))


# ------------------------------------------------------------------ CTM: position and velocity apart
def position_velocity_rmse(env, policies, traj, pos: Sequence[int] = (0, 2), vel: Sequence[int] = (1, 3)) -> dict:
    """Roll every policy through ``env`` on ``traj`` and split its error: ``{name: {"full",
    "position", "velocity"}}``, each a time-averaged RMSE (the full state mixes metres and metres per
    second; position and velocity keep their units)."""
    from adaptfilt.mdp import rollout

    out = {}
    for p in policies:
        run, _ = rollout(env, p, traj=traj)
        e = np.asarray(traj.x)[:, : run.mean.shape[1]] - run.mean
        r = lambda idx: float(np.sqrt((e[..., list(idx)] ** 2).sum(-1).mean(axis=0)).mean())
        out[p.name] = {"full": r(range(e.shape[-1])), "position": r(pos), "velocity": r(vel)}
    return out


def position_velocity_md(pv: dict, names: Sequence[str], stored=None) -> str:
    """Table of :func:`position_velocity_rmse` for ``names``; a seed group (``<group>-s<i>``
    members) as the median over its seeds with their range. ``stored`` (the evaluation the runs
    of ``pv`` were drawn beside, a :class:`~adaptfilt.evaluation.Results`) adds its full-state
    RMSE as the last column, summarised the same way, so that an order that differs between the
    two sets of runs shows in numbers."""
    summary = lambda v: f"{np.median(v):.1f}" + (f" ({v.min():.1f}-{v.max():.1f})" if v.size > 1 else "")
    rows = []
    for n in names:
        ms = [m for m in pv if m == n or (m.startswith(n + "-s") and m[len(n) + 2:].isdigit())]
        if not ms:
            raise KeyError(f"no policy {n!r} in these results")
        cells = [summary(np.array([pv[m][k] for m in ms])) for k in ("full", "position", "velocity")]
        if stored is not None:
            cells.append(summary(np.array([stored[m].rmse for m in ms])))
        rows.append([n + (f" ({len(ms)} seeds: median, range)" if len(ms) > 1 else ""), *cells])
    head = ["policy", "RMSE full state", "position (m)", "velocity (m/s)"]
    if stored is not None:
        head.append(f"RMSE full state, stored (M = {stored.config['n_runs']})")
    return _md(head, rows)


def plot_position_velocity(pv: dict, res, names: Sequence[str], unit: tuple[str, str] = ("m", "m/s"), ax=None,
                           label: Sequence[str] | None = None):
    """:func:`position_velocity_rmse` as a picture: position RMSE across, velocity RMSE up, one point
    per policy of ``names`` in its colour of ``res`` (:func:`adaptfilt.plots.policy_style`); a seed
    group as the median of its seeds (a star) with one faint dot per seed. Labels: ``label``
    (default every name), placed without overlaps. Returns the figure."""
    from adaptfilt import style
    from adaptfilt.plots import policy_style

    fig, ax = style.figure(size=(8, 5.2)) if ax is None else (ax.figure, ax)
    pts, cols, dots = {}, {}, []
    for n in names:
        ms = [m for m in pv if m == n or (m.startswith(n + "-s") and m[len(n) + 2:].isdigit())]
        st = policy_style(res, ms[0])
        p, v = np.array([pv[m]["position"] for m in ms]), np.array([pv[m]["velocity"] for m in ms])
        if len(ms) > 1:
            ax.scatter(p, v, s=12, color=st["color"], alpha=0.45, lw=0, zorder=1)
            dots += list(zip(p, v))
        ax.plot(np.median(p), np.median(v), st["marker"], color=st["color"], ms=9 if st["family"] != "fixed" else 6,
                mec="black" if st["family"] != "fixed" else st["color"], mew=0.6, zorder=3)
        pts[n] = (float(np.median(p)), float(np.median(v)))
        cols[_short(n)] = st["color"] if st["family"] != "fixed" else "0.25"
    fixed = sorted((n for n in names if n.startswith("fixed-")), key=lambda n: float(n.split("=")[1]))
    ax.plot([pts[n][0] for n in fixed], [pts[n][1] for n in fixed], color="0.6", lw=1, zorder=0)
    ax.set(xlabel=f"time-averaged RMSE of the position ({unit[0]})",
           ylabel=f"time-averaged RMSE of the velocity ({unit[1]})")
    ax.grid(alpha=0.3)
    sel = [n for n in names if label is None or n in label]
    order = sorted(sel, key=lambda n: n.startswith("fixed-"))
    place_labels(ax, {_short(n): pts[n] for n in order}, colors=cols,
                 avoid=[pts[n] for n in names if n not in sel] + dots)
    return fig


def innovation_response(env, policy, n_runs: int = 200, seed: int = 5, early: int = 10,
                        features: str = "paper+innov@1") -> dict:
    """Roll ``policy`` through ``env`` on ``n_runs`` runs (``rng = default_rng(seed)``) and record,
    at every step, the parameter it chose and the size of the innovation feature it saw (the norm
    of the ``innov@...`` block of its own feature set, else of ``features``; on the SIF's CTM the
    bearing innovation of a one-iteration update, in radians).

    Returns ``{"early", "late", "quartiles", "edges"}``: the mean parameter over steps
    ``1..early`` and after them, and over the run-steps in each quartile of the innovation
    (pooled over runs and steps; non-finite innovations, a diverged run's, left out), with the
    three quartile edges. A policy whose choice follows the innovation has rising ``quartiles``.
    """
    from adaptfilt.features import FeatureSet
    from adaptfilt.mdp import rollout

    fs = FeatureSet.parse(getattr(policy, "feature_set", None) or features)
    cols = [i for i, n in enumerate(fs.names(env.model, env.grid)) if n.startswith("innov")]
    seen = []

    class _Watch:  # passes the choices through, and records the innovation each one saw
        name, predict_param = getattr(policy, "name", "policy"), getattr(policy, "predict_param", None)

        def act(self, d):
            seen.append(np.linalg.norm(d.observe(fs)[:, cols], axis=-1))
            return policy.act(d)

    run, _ = rollout(env, _Watch(), n_runs=n_runs, rng=np.random.default_rng(seed))
    n, a = np.asarray(run.params, dtype=float).T, np.array(seen)  # (T, M): chosen, innovation seen
    ok = np.isfinite(a)
    edges = np.quantile(a[ok], [0.25, 0.5, 0.75])
    q = np.digitize(a, edges)
    quart = np.array([n[ok & (q == k)].mean() if np.any(ok & (q == k)) else np.nan for k in range(4)])
    return {"early": float(n[:early].mean()), "late": float(n[early:].mean()), "quartiles": quart, "edges": edges,
            "early_steps": early}


def innovation_responses(experiments: Sequence[str], groups: Sequence[str] = ("adaptive", "myopic"),
                         seeds: Sequence[int] = range(8), n_runs: int = 200, seed: int = 5, load=None,
                         n_steps: int | None = None) -> dict:
    """:func:`innovation_response` of every training seed of every group, each on the same runs
    (``seed``) in a fresh environment of its experiment (``make_env(0, n_steps)``):
    ``{(experiment, group): [response of seed 0, seed 1, ...]}``. ``load(experiment, group, seed=s)``
    gives a policy (default :func:`adaptfilt.experiments.artefacts.load_policy`)."""
    from adaptfilt.experiment_registry import get_experiment

    if load is None:
        from adaptfilt.experiments.artefacts import load_policy as load
    return {(e, g): [innovation_response(get_experiment(e).make_env(0, n_steps), load(e, g, seed=s), n_runs, seed)
                     for s in seeds] for e in experiments for g in groups}


def innovation_response_md(responses: dict, what: str = "N_it") -> str:
    """:func:`innovation_responses` as a table, one row per (experiment, group): each statistic as
    the IQM over the seeds with the seeds' range, and two differences per seed, with their IQM, range
    and how many seeds have them above zero: steps ``1..early`` less the steps after them, and the
    loudest quarter of the innovation less the quietest."""
    from adaptfilt.seed_stats import iqm

    cell = lambda v: f"{iqm(v):.1f} ({v.min():.1f}-{v.max():.1f})" if v.size > 1 else f"{v[0]:.1f}"
    # a difference: two decimals (a seed that nearly always chooses one value differs by hundredths), and how
    # many seeds have it above zero
    diff = lambda d: (f"{iqm(d):+.2f} ({d.min():+.2f} to {d.max():+.2f}); " if d.size > 1 else f"{d[0]:+.2f}; ") \
        + f"{np.sum(d > 0)} / {d.size} > 0"
    rows = []
    for (e, g), rs in responses.items():
        early, late = np.array([r["early"] for r in rs]), np.array([r["late"] for r in rs])
        qs = np.array([r["quartiles"] for r in rs])
        rows.append([e, g, str(len(rs)), cell(early), cell(late), *(cell(qs[:, k]) for k in range(4)),
                     diff(early - late), diff(qs[:, 3] - qs[:, 0])])
    k = next(iter(responses.values()))[0]["early_steps"]
    head = ["experiment", "group", "seeds", f"{what}, steps 1-{k}", "after", "quartile 1 (quietest)", "quartile 2",
            "quartile 3", "quartile 4 (loudest)", "early - after", "quartile 4 - quartile 1"]
    return _md(head, rows)
