r"""The analyses of chapter 10 (UKF on CTM, experiment ``ctm-ukf``): costs over time, what the grid can
do to the predicted measurement variance, the errors along and across the line of sight, and the
position and velocity errors apart.

==============================  ================================================================
function                        what
==============================  ================================================================
plot_cost_time                  mean one-step cost over time (windowed), per policy
reach_anatomy, reach_table      what the grid can do to the predicted measurement variance against
                                the squared innovation, and which value a policy chooses
line_of_sight,                  CTM: position errors and claimed standard deviations along and
line_of_sight_table,            across the line of sight from the sensor (range is what a single
plot_line_of_sight              bearing sensor cannot see), per filter
position_velocity_rmse,         CTM: the error of the position (m) and of the velocity (m/s)
position_velocity_md,           apart, per policy (the full-state RMSE mixes the two; the table can
plot_position_velocity          set the stored evaluation's full-state RMSE beside it)
==============================  ================================================================

What chapters 9-11 share (seed tables, Figure 6): :mod:`adaptfilt.course.paper_common`. Seed groups
are policies named ``<group>-s<seed>``; where a function takes a group name, a single policy name
works as well (:func:`adaptfilt.experiments.claims.members`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from adaptfilt.course.paper_common import markdown_table, short_label, place_labels, plain_log
from adaptfilt.experiments.claims import members

__all__ = ["plot_cost_time", "ReachAnatomy", "reach_anatomy", "reach_table", "LineOfSight", "line_of_sight",
           "line_of_sight_table", "plot_line_of_sight", "position_velocity_rmse", "position_velocity_md",
           "plot_position_velocity"]


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


def position_rmse_share(x: np.ndarray, run, reference, pos: Sequence[int] = (0, 2), n_boot: int = 2000,
                        seed: int = 0) -> tuple[float, float, float]:
    r"""The share of ``run``'s time-averaged position RMSE that ``reference`` (a better filter on the
    same runs) does not have, :math:`1 - \mathrm{RMSE}_\mathrm{ref} / \mathrm{RMSE}_\mathrm{run}`, with
    its 95 % percentile interval from a paired bootstrap over the runs (both filters resampled with the
    same counts, ``seed``): ``(share, lo, hi)``. With a particle filter as ``reference`` it is the part of
    a Gaussian filter's error that the exact posterior would not make, up to the particle filter's own
    excess (which makes the true share larger) and the sampling error of the runs (the interval).

    >>> import adaptfilt as af
    >>> m = af.models.coordinated_turn(n_steps=5)
    >>> tr = m.simulate(n_runs=20, rng=1)
    >>> u = af.UKF(m).run(tr.z)
    >>> position_rmse_share(tr.x, u, u)
    (0.0, 0.0, 0.0)
    """
    from adaptfilt import metrics

    x = np.asarray(x)
    se = lambda r: ((x[..., list(pos)] - np.asarray(r.mean)[..., list(pos)]) ** 2).sum(-1)
    se_run, se_ref = se(run), se(reference)
    share = 1.0 - metrics.rmse_time_average(se_ref) / metrics.rmse_time_average(se_run)
    counts = metrics.bootstrap_counts(x.shape[0], n_boot, seed)
    reps = 1.0 - metrics.bootstrap_rmse(se_ref, counts) / metrics.bootstrap_rmse(se_run, counts)
    lo, hi = metrics.percentile_ci(reps)
    return float(share), lo, hi


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
    return markdown_table(head, rows)


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
        cols[short_label(n)] = st["color"] if st["family"] != "fixed" else "0.25"
    fixed = sorted((n for n in names if n.startswith("fixed-")), key=lambda n: float(n.split("=")[1]))
    ax.plot([pts[n][0] for n in fixed], [pts[n][1] for n in fixed], color="0.6", lw=1, zorder=0)
    ax.set(xlabel=f"time-averaged RMSE of the position ({unit[0]})",
           ylabel=f"time-averaged RMSE of the velocity ({unit[1]})")
    ax.grid(alpha=0.3)
    sel = [n for n in names if label is None or n in label]
    order = sorted(sel, key=lambda n: n.startswith("fixed-"))
    place_labels(ax, {short_label(n): pts[n] for n in order}, colors=cols,
                 avoid=[pts[n] for n in names if n not in sel] + dots)
    return fig
