r"""Chapter 4, parameter adaptation as an MDP: what a decision sees (:func:`innovation_spread`), a
sweep of the fixed parameter (:func:`kappa_sweep`, :func:`plot_sweep`), results in lines
(:func:`results_lines`) and the distribution of the one-step cost (:func:`cost_samples`,
:func:`cost_summary`, :func:`plot_cost_distribution`).
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

__all__ = ["innovation_spread", "kappa_sweep", "plot_sweep", "results_lines", "cost_samples", "cost_summary",
           "plot_cost_distribution", "choice_bands", "plot_choice_bands"]


# ======================================================================== chapter 4
def innovation_spread(env, n_runs: int = 3, steps: int = 5, rng: int = 0) -> str:
    """After ``steps`` default steps of ``env``: per run, the smallest and largest innovation
    over the parameter grid and the default-parameter innovation feature (a text table)."""
    d = env.reset(n_runs=n_runs, rng=np.random.default_rng(rng))
    for _ in range(steps):
        d, _, _, _ = env.step(np.full(d.n_runs, d.default_index))
    innov = d.candidates()["update"].innovation.reshape(env.nz, env.grid.size, d.n_runs)[0]  # (G, M)
    name = env.filt.rule.param_name
    lines = [f"innovation at k = {d.t + 1} for {name} = {env.grid.min():g} .. {env.grid.max():g}:"]
    for r in range(d.n_runs):
        lines.append(f"  run {r}: min {innov[:, r].min():+.4f}  max {innov[:, r].max():+.4f}   "
                     f"default-{name} feature {d.features[r, -1]:+.4f}")
    return "\n".join(lines)


def kappa_sweep(model, values: Sequence[float], n_runs: int, seed: int = 0):
    """Fixed update ``kappa`` (predict at the default) on the same trajectories:
    :func:`~adaptfilt.evaluation.evaluate` of one :class:`~adaptfilt.policies.FixedPolicy` per value."""
    from adaptfilt.evaluation import evaluate
    from adaptfilt.gaf import UKF
    from adaptfilt.mdp import Cost, FilterEnv
    from adaptfilt.policies import FixedPolicy

    env = FilterEnv(UKF(model, on_indefinite="clip"), values, cost=Cost("nis"))
    return evaluate(env, [FixedPolicy(v, "kappa", grid=values) for v in values], n_runs=n_runs, seed=seed,
                    progress=False)


def plot_sweep(res, values: Sequence[float], title: str, nx: int, log_anees: bool = True, unit: str | None = None):
    """Time-averaged RMSE and ANEES (95 % CIs) of a :func:`kappa_sweep` against ``kappa`` (symlog axis);
    ``unit`` (e.g. ``"m"``) labels the RMSE axis."""
    from adaptfilt import style

    fig, axes = style.figure(1, 2)
    rmse_label = "time-averaged RMSE" + (f" ({unit})" if unit else "")
    for ax, key, lab in [(axes[0], "rmse", rmse_label), (axes[1], "anees", "time-averaged ANEES")]:
        v = np.array([getattr(res[n], key) for n in res.names])
        ci = np.array([getattr(res[n], key + "_ci") for n in res.names])
        ax.errorbar(values, v, yerr=[v - ci[:, 0], ci[:, 1] - v], fmt="o-", ms=3, capsize=2, lw=1)
        ax.set_xscale("symlog", linthresh=1)
        ax.set(xlabel=f"fixed update {style.param_label('kappa')}", ylabel=lab, title=f"{title}: {lab.split()[1]}")
    if log_anees:
        axes[1].set_yscale("log")
    axes[1].axhline(nx, color="0.4", ls="--", lw=0.8, label=f"ideal = $n_x$ = {nx}")
    axes[1].legend()
    return fig


def results_lines(res, names: Sequence[str] | None = None) -> str:
    """One line per policy of an evaluation: time-averaged RMSE and ANEES with their 95 % CIs."""
    names = res.names if names is None else list(names)
    w = max(len(n) for n in names)
    return "\n".join(f"{n:<{w}}  RMSE {p.rmse:.3g} [{p.rmse_ci[0]:.3g}, {p.rmse_ci[1]:.3g}]   "
                     f"ANEES {p.anees:.3g} [{p.anees_ci[0]:.3g}, {p.anees_ci[1]:.3g}]"
                     for n, p in ((n, res[n]) for n in names))


def cost_samples(env, policies: Sequence, traj) -> dict[str, np.ndarray]:
    """One-step costs of each policy over all (run, step) pairs of ``traj``, flattened."""
    from adaptfilt.mdp import rollout

    return {p.name: rollout(env, p, traj=traj)[1].ravel() for p in policies}


def cost_summary(costs: Mapping[str, np.ndarray]) -> str:
    """Median, mean, 99.9 % quantile, maximum and the share of the total carried by the top 1 % of steps."""
    w = max(len(n) for n in costs)
    lines = []
    for n, c in costs.items():
        q = np.quantile(c, [0.5, 0.999])
        top = np.sort(c)[::-1][: max(1, c.size // 100)].sum() / c.sum()
        lines.append(f"{n:<{w}}  median {q[0]:.3g}  mean {c.mean():.3g}  99.9% quantile {q[1]:.3g}  "
                     f"max {c.max():.3g}  top 1% of steps carry {top:.0%} of the total")
    return "\n".join(lines)


def plot_cost_distribution(costs: Mapping[str, np.ndarray], floor: float = 1e-8, title: str = ""):
    """Densities of ``log10`` one-step costs (costs below ``floor`` drawn at it), dashed: each mean."""
    from adaptfilt.style import figure, policy_label

    fig, ax = figure()
    bins = np.linspace(np.log10(floor), 8, 81)
    for n, c in costs.items():
        line = ax.hist(np.log10(np.maximum(c, floor)), bins=bins, histtype="step", lw=1.5, density=True,
                       label=policy_label(n))[2][0]
        ax.axvline(np.log10(c.mean()), color=line.get_edgecolor(), ls="--", lw=1)
    ax.set_yscale("log")
    ax.set(xlabel=rf"$\log_{{10}}\bar L_\mathrm{{NIS}}$ (one step; costs below $10^{{{np.log10(floor):.0f}}}$ drawn there)",
           ylabel="density (log scale)", title=title)
    ax.legend()
    return fig


def choice_bands(results, policy: str, bands: Sequence[tuple[float, float]]) -> np.ndarray:
    """The fraction of runs whose choice lies in each band ``(lo, hi)`` (inclusive) at every step, ``(T, B)``.

    Every grid value must lie in exactly one band.
    """
    grid = np.asarray(results.grid, dtype=float)
    member = np.array([[lo <= g <= hi for g in grid] for lo, hi in bands])        # (B, G)
    if not (member.sum(axis=0) == 1).all():
        bad = grid[member.sum(axis=0) != 1]
        raise ValueError(f"every grid value must lie in exactly one band; not so for {bad.tolist()}")
    return results[policy].choices @ member.T.astype(float)


def _band_label(name: str, lo: float, hi: float, top: float) -> str:
    from adaptfilt.style import param_label

    sym = param_label(name)
    if lo == hi:
        return f"{sym} = {lo:g}"
    return f"{sym} ≥ {lo:g}" if hi >= top else f"{lo:g} ≤ {sym} ≤ {hi:g}"


def plot_choice_bands(results, policy: str, bands: Sequence[tuple[float, float]], ax=None, title: str | None = None):
    """What ``policy`` chooses over time, the grid grouped into a few ``bands`` ``(lo, hi)`` (inclusive):
    stacked fractions of runs per band (:func:`choice_bands`), in an ordered colour scale (a stack of
    a dozen grid values in a dozen colours cannot be read), the legend beside the axes in stack order."""
    import matplotlib

    from adaptfilt.style import figure, param_label

    shares = choice_bands(results, policy, bands)
    fig, ax = figure() if ax is None else (ax.figure, ax)
    k = np.arange(1, shares.shape[0] + 1)
    name = results.config.get("param_name", "kappa")
    top = float(np.max(results.grid))
    colors = matplotlib.colormaps["viridis"](np.linspace(0.0, 0.95, len(bands)))
    ax.stackplot(k, shares.T, colors=colors, labels=[_band_label(name, lo, hi, top) for lo, hi in bands], lw=0)
    ax.set(xlim=(k[0], k[-1]), ylim=(0, 1), xlabel="time step k", ylabel="fraction of runs",
           title=title or f"{policy}: the {param_label(name)} chosen at every step, in {len(bands)} bands")
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), reverse=True)
    return fig
