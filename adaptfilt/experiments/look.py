r"""How much can looking ahead buy? The look-ahead study of ``adaptfilt beyond --studies look``.

The learned policies are measured against greedy, the exact one-step optimum; when they lose, it may be
that there is little to gain on the model, or that the learner fails to find it. This study asks the
first question without a learner: the non-learned look-ahead references of :mod:`adaptfilt.lookahead`
(rollout with greedy as the base policy, horizon ``H`` and ``S`` sampled continuations, and the
exhaustive two-step look-ahead as a cross-check), evaluated beside greedy, maximum likelihood, the
default, every update-only constant and the learned groups (the reproduction's adaptive policies, the
candidate-aware and the greedy-anchored ones of ``beyond``) on the same paired runs.

Each (experiment, policy family) is one job of the same evaluation (same seed, same runs, same
bootstrap resamples), merged into one :class:`~adaptfilt.results.Results` (:meth:`~adaptfilt.results.Results.merge`):
``("base",)`` the baselines and learned files, ``("rollout", H, S)``, ``("twostep", S)``.

:func:`look_summary` gives, per experiment, each reference's paired difference to greedy (run level:
a reference is one policy) on the verdict cost (charged for what it computes where the cost charges
compute, the SIF), RMSE and ANEES, its compute per step, and the learned groups' seed-level differences;
:func:`plot_look_gain` draws the gain over greedy against the horizon.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from adaptfilt.experiments.report import md_table
from adaptfilt.verdicts import verdict

__all__ = ["LOOK", "LOOK_QUICK", "look_specs", "look_job", "look_summary", "rejudge", "plot_look_gain", "look_md",
           "look_files"]

#: experiment -> (paired runs, ((H, S), ...)): the rollout references; UNGM also gets the two-step cross-check.
#: Sized by ``benchmarks/bench_lookahead.py`` (rollout H = 1, S = 4 costs 36x greedy's time on UNGM, 59x on
#: the CTM, 8x on the SIF): M = 2000 paired runs keep the intervals narrow on the UKF; on the SIF, where
#: a reference's charged cost is set mostly by its (deterministic) compute, 500 runs do, at a quarter of
#: the 1000-run study's CPU time (its SIF part was about two thirds of 1.5 CPU-hours).
LOOK = {"ungm-ukf": (2000, ((1, 4), (2, 4), (4, 4), (1, 16), (2, 16))),
        "ctm-ukf": (2000, ((1, 4), (2, 4), (1, 16))),
        "ctm-sif-stateinnov": (500, ((1, 4), (2, 4)))}
#: The same at toy scale (tests).
LOOK_QUICK = {"ungm-ukf": (40, ((1, 2), (2, 2))), "ctm-ukf": (30, ((1, 2),)), "ctm-sif-stateinnov": (20, ((1, 2),))}
#: Samples of the two-step cross-check (UNGM: 13 x S x 13 updates per step).
TWOSTEP_SAMPLES = 4
#: Discount of the references: the adaptive policies' (the paper's gamma = 0.5).
GAMMA = 0.5


def look_specs(experiment: str, grid_hs, quick: bool = False) -> list[tuple]:
    """The jobs' policy families for ``experiment``: baselines, one rollout per (H, S), two-step on UNGM."""
    specs = [("base",)] + [("rollout", int(h), int(s)) for h, s in grid_hs]
    if experiment == "ungm-ukf":
        specs.append(("twostep", 2 if quick else TWOSTEP_SAMPLES))
    return specs


def _policies(experiment: str, spec: tuple, files: list[str]) -> list:
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.jobs import load_learned
    from adaptfilt.lookahead import RolloutPolicy, TwoStepPolicy

    exp = get_experiment(experiment)
    if spec[0] == "base":
        base = [p for p in exp.baselines() if p.kind != "fixed-both"]
        return base + load_learned(exp, files)
    if spec[0] == "rollout":
        return [RolloutPolicy(exp.grid, horizon=spec[1], samples=spec[2], gamma=GAMMA, seed=0)]
    return [TwoStepPolicy(exp.grid, samples=spec[1], gamma=GAMMA, seed=0)]


def look_job(experiment: str, spec: tuple, files: list[str], n_runs: int, n_steps: int | None):
    """One part of an experiment's look-ahead evaluation (module docstring); every part sees the same runs."""
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment

    res = evaluate(get_experiment(experiment), _policies(experiment, spec, files), n_runs=n_runs, seed=0,
                   progress=False, n_steps=n_steps)
    res.config.update(experiment=experiment)
    return res


def _verdict_cost(res) -> str:
    from adaptfilt.experiments.claims import charges_compute

    return "cost_charged" if charges_compute(res) else "cost"


def look_summary(res) -> dict:
    """Per policy: the metrics, compute per step, and the difference to greedy (module docstring)."""
    from adaptfilt.seed_stats import aggregate, difference, seed_groups

    cost = _verdict_cost(res)
    metrics = [cost] + (["cost"] if cost != "cost" else []) + ["rmse", "anees", "objective"]
    out = {"verdict_cost": cost, "n_runs": res.config["n_runs"], "references": {}, "learned": {}, "baselines": {}}
    refs = [n for n in res.names if n.startswith(("rollout-", "twostep-"))]
    for n in refs + ["greedy", "ml", "default"]:
        if n not in res:
            continue
        p = res[n]
        row = {m: getattr(p, m) for m in metrics}
        row.update(spent=p.spent, divergent_frac=p.divergent_frac)
        if n != "greedy":
            row["minus_greedy"] = {m: list(res.paired_difference(n, "greedy", m)) for m in metrics}
        (out["references"] if n in refs else out["baselines"])[n] = row
    fixed = res.fixed_names()
    best = min(fixed, key=lambda n: getattr(res[n], cost))
    out["baselines"]["best fixed"] = {"policy": best, **{m: getattr(res[best], m) for m in metrics},
                                      "spent": res[best].spent,
                                      "minus_greedy": {m: list(res.paired_difference(best, "greedy", m)) for m in metrics}}
    for g, names in seed_groups(res.names).items():
        out["learned"][g] = {"n_seeds": len(names), "spent": float(np.mean([res[n].spent for n in names])),
                             **{m: aggregate(res, names, m).iqm for m in metrics},
                             "minus_greedy": {m: list(difference(res, names, ["greedy"], m)["iqm"]) for m in metrics}}
    # Bertsekas' cost improvement: rollout on greedy costs no more than greedy (exact expectations, full
    # horizon); here truncated and sampled, so measured: the verdict on "the reference is lower than greedy"
    for n, row in out["references"].items():
        row["improves_on_greedy"] = verdict("lower", row["minus_greedy"][cost])
    return out


def rejudge(look: dict) -> dict:
    """A stored study's ``{experiment: look_summary}`` with every reference's ``improves_on_greedy`` judged again
    by the one rule from its stored interval of the verdict cost's difference to greedy."""
    out = {}
    for e, s in look.items():
        refs = {n: {**row, "improves_on_greedy": verdict("lower", row["minus_greedy"][s["verdict_cost"]])}
                for n, row in s["references"].items()}
        out[e] = {**s, "references": refs}
    return out


def _parse(name: str) -> tuple[str, int, int]:
    """``rollout-H2-S4`` -> ("rollout", 2, 4); ``twostep-S4`` -> ("twostep", 1, 4)."""
    parts = name.split("-")
    if parts[0] == "twostep":
        return "twostep", 1, int(parts[1][1:])
    return "rollout", int(parts[1][1:]), int(parts[2][1:])


def _clipped_vbar(ax, x, v, lo, hi, lim, color, marker="o", ms=6, lw=1.5):
    """A point ``v`` with the interval ``[lo, hi]`` at abscissa ``x``, cut at the view ``lim``: a part
    beyond it ends at the edge in a triangle, with the value (or the interval end) written beside it."""
    a, b = lim
    c = min(max(v, a), b)
    ax.errorbar(x, c, yerr=[[max(c - max(lo, a), 0)], [max(min(hi, b) - c, 0)]], fmt=marker if a <= v <= b else "none",
                ms=ms, color=color, capsize=3, lw=lw, mec="black" if marker != "o" else color, zorder=4)
    for end, text in ((b, "above"), (a, "below")):
        past = [w for w in (v, hi if end == b else lo) if (w > b if end == b else w < a)]
        if not past:
            continue
        ax.plot(x, end, "^" if end == b else "v", ms=7, color=color, clip_on=False, zorder=5)
        what = f"{v:+.3g}\n[{lo:+.3g}, {hi:+.3g}]" if not a <= v <= b else f"to {past[-1]:+.3g}"
        ax.annotate(what, (x, end), textcoords="offset points", xytext=(4, -4 if end == b else 4), ha="left",
                    va="top" if end == b else "bottom", fontsize=8, color=color, zorder=6)


def plot_look_gain(look: dict, metric: str | None = None, axes=None, ylim: dict | None = None):
    """The gain over greedy (greedy minus policy, on each experiment's verdict cost: positive is better)
    against the look-ahead horizon H, one line per S, with paired 95 % intervals; each learned group's
    seed-level gain (IQM, two-level interval) as a bar right of the largest H with its IQM as a dashed
    line across the panel. ``ylim[experiment]`` fixes a panel's range (by default it fits the references'
    and the learned groups' gains and intervals); a point or interval end beyond it is cut at the edge,
    marked with a triangle and its value written beside it. Returns the figure."""
    import matplotlib.pyplot as plt

    exps = list(look)
    if axes is None:
        fig, axes = plt.subplots(1, len(exps), figsize=(5.2 * len(exps), 4.2), layout="constrained", squeeze=False)
        axes = axes[0]
    fig = axes[0].figure
    for ax, e in zip(axes, exps):
        s = look[e]
        m = metric or s["verdict_cost"]
        by_s: dict[int, list] = {}
        for n, row in s["references"].items():
            kind, h, samples = _parse(n)
            if kind == "rollout":
                by_s.setdefault(samples, []).append((h, row["minus_greedy"][m]))
        curves = {}
        for samples, pts in sorted(by_s.items()):
            pts.sort()
            h = np.array([0] + [p[0] for p in pts])
            curves[samples] = (h + 0.04 * (samples - 8) / 8, -np.array([[0.0, 0.0, 0.0]] + [p[1] for p in pts]))
        learned = {g: (row["n_seeds"], -np.array(row["minus_greedy"][m])) for g, row in s["learned"].items()}
        ends = [0.0] + [v for _, g in curves.values() for v in g.ravel()] + [v for _, d in learned.values() for v in d]
        lim = (ylim or {}).get(e)
        if lim is None:
            lo, hi = min(ends), max(ends)
            pad = 0.1 * (hi - lo or 1.0)
            lim = (lo - pad, hi + pad)
        h_max = max([1] + [int(round(h.max())) for h, _ in curves.values()])
        right = h_max + 0.35 + 0.3 * max(len(learned) - 1, 0) * h_max / 2 + 0.3 * h_max / 2
        ax.set_xlim(-0.15 * h_max / 2, right)
        for i, (samples, (h, g)) in enumerate(curves.items()):  # gain = greedy - policy
            col = f"C{i}"
            ax.plot(h, g[:, 0], "-", color=col, label=f"rollout, S = {samples}")  # runs off the view where it must
            for x, (v, a, b) in zip(h, g[:, [0, 2, 1]]):  # gain interval: [-(upper), -(lower)]
                _clipped_vbar(ax, x, v, a, b, lim, col)
        for i, (gname, (n_seeds, d)) in enumerate(learned.items()):
            col, x = f"C{i + 3}", h_max + 0.35 + 0.3 * i * h_max / 2
            if lim[0] <= d[0] <= lim[1]:
                ax.axhline(d[0], color=col, lw=1, ls="--", zorder=1)
            ax.plot([], [], "D--", color=col, mec="black", label=f"learned: {gname} (IQM of {n_seeds})")
            _clipped_vbar(ax, x, d[0], d[2], d[1], lim, col, marker="D", lw=2.2)
        ax.axhline(0, color="black", lw=0.8)
        ax.axvspan(h_max + 0.2, right, color="0.94", zorder=0)  # the learned groups' column
        ax.set_ylim(*lim)
        ax.set_xticks(list(range(h_max + 1)))
        ax.text(h_max + 0.22, 0.98, "learned", transform=ax.get_xaxis_transform(), va="top", fontsize=8,
                color="0.3")
        ax.set(xlabel="look-ahead horizon H (0: greedy)", ylabel="gain over greedy in " + {"cost_charged": "cost, compute charged"}.get(m, m),
               title=f"{e} (M = {s['n_runs']})")
    # one legend for all panels, below them, off the data
    labels: dict[str, object] = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            labels.setdefault(lab, h)
    constrained = type(fig.get_layout_engine()).__name__ == "ConstrainedLayoutEngine"
    fig.legend(list(labels.values()), list(labels), ncol=min(len(labels), 5), fontsize=8,
               **({"loc": "outside lower center"} if constrained else {"loc": "upper center",
                                                                      "bbox_to_anchor": (0.5, 0.0)}))
    return fig


def look_md(look: dict) -> str:
    """The study's table: per experiment, references, baselines and learned groups against greedy."""
    f = lambda d: f"{d[0]:+.4g} [{d[1]:+.3g}, {d[2]:+.3g}]"  # noqa: E731
    lines = ["**How much can looking ahead buy?** (paired runs; differences to greedy with 95 % intervals: run "
             "level for a single policy, seed level (IQM over seeds, two-level bootstrap) for a learned group; "
             "cost: the experiment's verdict cost, charged for what a policy computes where the cost charges "
             "compute; compute per step in UKF updates or SIF iterations)", "",
             *md_table(["experiment", "policy", "cost", "cost - greedy", "RMSE - greedy", "ANEES - greedy",
                        "compute per step", "lower cost than greedy"])]
    for e, s in look.items():
        c = s["verdict_cost"]
        g = s["baselines"]["greedy"]
        lines.append(f"| {e} (M = {s['n_runs']}) | greedy | {g[c]:.4g} | | | | {g['spent']:.3g} | |")
        for n, row in s["references"].items():
            d = row["minus_greedy"]
            lines.append(f"| {e} | {n} | {row[c]:.4g} | {f(d[c])} | {f(d['rmse'])} | {f(d['anees'])} "
                         f"| {row['spent']:.4g} | {row['improves_on_greedy']} |")
        for n in ("ml", "default", "best fixed"):
            if n in s["baselines"]:
                row = s["baselines"][n]
                label = n if n != "best fixed" else f"best fixed ({row['policy']})"
                d = row["minus_greedy"]
                lines.append(f"| {e} | {label} | {row[c]:.4g} | {f(d[c])} | {f(d['rmse'])} | {f(d['anees'])} "
                             f"| {row['spent']:.3g} | |")
        for n, row in s["learned"].items():
            d = row["minus_greedy"]
            lines.append(f"| {e} | {n} ({row['n_seeds']} seeds) | {row[c]:.4g} | {f(d[c])} | {f(d['rmse'])} "
                         f"| {f(d['anees'])} | {row['spent']:.3g} | |")
    return "\n".join(lines) + "\n"


def look_files(data: Path, out: Path, experiment: str, seeds) -> list[str]:
    """The learned policies shown beside the references: the reproduction's adaptive ones, and the
    candidate-aware and anchored ones of ``beyond`` where they exist."""
    paths = [data / f"policies/{experiment}-adaptive-s{s}.npz" for s in seeds]
    paths += [out / f"policies/{experiment}-{k}-s{s}.npz" for k in ("adaptive-cand", "adaptive-anchored") for s in seeds]
    return [str(p) for p in paths if p.exists()]
