r"""Analyses behind the experiment chapters of the course (6: UKF on UNGM, 7: UKF on CTM,
8: SIF on CTM): what a stored evaluation says at the seed level, and what the rule-based
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
table1_before_after_md          Table I now beside an earlier release's (``course.earlier_numbers``)
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
           "line_of_sight", "line_of_sight_table", "plot_line_of_sight", "sif_spread", "table1_before_after_md"]


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


def _reference_band(ax, res, name: str, metric: str, color, label: str) -> None:
    a = aggregate(res, members(res, name), metric)
    ax.axhline(a.iqm, color=color, lw=1.4, label=label)
    ax.axhspan(*a.iqm_ci, color=color, alpha=0.15, lw=0)


def plot_fixed_conventions(res, metric: str = "rmse", refs: Sequence[str] = ("ml", "greedy", "adaptive"),
                           ax=None, unit: str | None = None, floor: float | None = None):
    r"""A metric (95 % CIs) against a *fixed* :math:`\kappa` in the two conventions, the update
    only (``fixed-kappa=v``) and predict and update (``fixed-both-kappa=v``), on a symlog axis;
    the policies ``refs`` as horizontal lines with their interval as a band (a seed group: its
    IQM and two-level interval). Returns the figure."""
    from adaptfilt import style
    from adaptfilt.plots import policy_style

    fixed = [float(n.split("=")[1]) for n in res.names if n.startswith(("fixed-kappa=", "fixed-both-kappa="))]
    if not fixed:
        raise ValueError("these results have no fixed-kappa policies")
    fig, ax = style.figure() if ax is None else (ax.figure, ax)
    for prefix, label, ls in (("fixed-kappa=", "fixed κ, update only", "-"),
                              ("fixed-both-kappa=", "fixed κ, predict and update", "--")):
        names = sorted((n for n in res.names if n.startswith(prefix)), key=lambda n: float(n.split("=")[1]))
        if not names:
            continue
        v = np.array([float(n.split("=")[1]) for n in names])
        y = np.array([getattr(res[n], metric) for n in names])
        ci = np.array([getattr(res[n], metric + "_ci") for n in names])
        ax.errorbar(v, y, yerr=[y - ci[:, 0], ci[:, 1] - y], fmt="o" + ls, color="0.35" if ls == "-" else "0.6",
                    ms=3.5, lw=1.2, capsize=2, label=label)
    for r in refs:
        _reference_band(ax, res, r, metric, policy_style(res, members(res, r)[0])["color"],
                        style.policy_label(r) + (" (IQM over seeds)" if len(members(res, r)) > 1 else ""))
    if floor is not None:
        ax.axhline(floor, color="0.2", ls=":", lw=1.2, label=f"Bayes floor {floor:.3g}")
    ax.set_xscale("symlog", linthresh=1)
    ax.set_xlim(left=-0.3 if min(fixed) >= 0 else None)  # no empty negative decades
    plain_log(ax)
    what = {"rmse": "time-averaged RMSE", "anees": "time-averaged ANEES", "cost": "mean one-step cost"}.get(metric, metric)
    ax.set(xlabel=f"fixed {style.param_label('kappa')}", ylabel=what + (f" ({unit})" if unit else ""))
    ax.legend(ncol=3, fontsize=8.5, loc="upper center", bbox_to_anchor=(0.5, -0.2))  # below: the curves fill the axes
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
    for a in anatomies:
        idx = np.digitize(a.nis0.ravel(), bins) - 1
        k = a.kappa.ravel()
        med = np.array([np.median(k[idx == i]) if (idx == i).sum() >= 20 else np.nan for i in range(mid.size)])
        ax.plot(mid, med, "o-", ms=3, label=style.policy_label(a.name))
    ax.axvline(1.0, color="0.4", ls="--", lw=1)
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=1)
    ax.set_ylim(-0.3 if np.nanmin([a.kappa.min() for a in anatomies]) >= 0 else None, None)
    ax.set(xlabel=r"NIS that the full update ($\kappa_\min$) would give", ylabel=r"median $\kappa$ chosen")
    ax.legend(fontsize=8.5)
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
    """One printed line per filter of ``runs`` (``{name: FilterRun}``): time-averaged RMSE, RMS error
    and RMS claimed standard deviation in range and cross-range, the median normalised squared
    error in each direction (0.455 for a consistent filter) and the median NEES
    (the chi-square median for ``nx`` degrees of freedom)."""
    from scipy import stats

    nx = np.asarray(x).shape[-1]
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))
    w = max(len(n) for n in runs)
    lines = [f"{'filter':<{w}}   RMSE | range: error  claimed sd  median (e/sd)^2 | cross: error  claimed sd  "
             f"median (e/sd)^2 | median NEES (consistent: {stats.chi2.median(nx):.2f})"]
    for n, run in runs.items():
        los = line_of_sight(x, run, pos)
        e = np.asarray(x) - run.mean
        nees = np.einsum("...i,...i->...", e, np.linalg.solve(run.cov, e[..., None])[..., 0])
        rmse = float(np.sqrt((e ** 2).sum(-1).mean(axis=0)).mean())
        lines.append(f"{n:<{w}}  {rmse:5.1f} | {rms(los.err_range):12.1f}  {rms(los.sd_range):10.1f}  "
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


def table1_before_after_md(t1: dict, before: dict, metrics: Sequence[str] = ("rmse", "anees", "cost", "mean_n_iter"),
                           columns: Sequence[str] | None = None) -> str:
    """Table I now (:func:`adaptfilt.experiments.claims.table1`; seed groups: the IQM over seeds)
    beside an earlier release's values (e.g. :data:`adaptfilt.course.earlier_numbers.TABLE1_BEFORE`, or
    ``{e: d["ours"] for e, d in artefacts.load_archive("onepass", "table1").items()}``),
    "before -> now" per metric, for the columns both have (or ``columns``)."""
    names = {"rmse": "RMSE", "anees": "ANEES", "cost": "cost", "mean_n_iter": "N_it chosen",
             "cost_charged": "cost charged", "divergent_frac": "divergent runs (worst seed)"}
    rows = []
    for e, d in t1.items():
        if e not in before:
            continue
        cols = [c for c in (columns or d["ours"]) if c in d["ours"] and c in before[e]]
        for col in cols:
            now, old = d["ours"][col], before[e][col]
            rows.append([d["cost_label"], col + (f" ({now['n_seeds']} seeds)" if now["n_seeds"] > 1 else "")] +
                        [f"{100 * old[m]:.2g} % → {100 * now[m]:.2g} %" if m == "divergent_frac" else
                         f"{old[m]:.4g} → {now[m]:.4g}" for m in metrics])
    if not rows:
        raise ValueError("no experiment of Table I is in the earlier release given")
    return _md(["cost", "policy"] + [f"{names.get(m, m)}: before → now" for m in metrics], rows)
