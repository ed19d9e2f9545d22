r"""How much can looking ahead buy? The look-ahead study of ``adaptfilt beyond --studies look``.

The learned policies are measured against greedy, the exact one-step optimum; when they lose, it may be
that there is little to gain on the model, or that the learner fails to find it. This study asks the
first question without a learner: the non-learned look-ahead references of :mod:`adaptfilt.lookahead`
(rollout with greedy as the base policy, horizon ``H`` and ``S`` sampled continuations, and the
exhaustive two-step look-ahead as a cross-check), evaluated beside greedy, maximum likelihood, the
default, every update-only constant and the learned groups (the reproduction's adaptive policies, the
candidate-aware and the greedy-anchored ones of ``beyond``) on the same paired runs. On the UKF models
the rollout also runs over maximum likelihood (ML's run is the cheaper one on the CTM) and over the
better of greedy and ML per decision (:data:`LOOK_BASES`): what looking ahead can buy from the better
base; and the learners of the ``mlanchor`` study join on the same runs (:func:`look_new_files`).

Each (experiment, policy family) is one job of the same evaluation (same seed, same runs, same
bootstrap resamples), merged into one :class:`~adaptfilt.results.Results` (:meth:`~adaptfilt.results.Results.merge`):
``("base",)`` the baselines and learned files, ``("rollout", H, S)``, ``("twostep", S)``, then
``("rollout", H, S, base)`` for the other bases and ``("learned",)`` the ``mlanchor`` study's files. The
merged evaluation records each part's job key and policies (``config["parts"]``): a later run of the study
takes a part whose key it records from the stored evaluation instead of computing it again
(:func:`stored_part`), so adding parts computes only the new ones.

:func:`look_summary` gives, per experiment, each reference's paired difference to greedy (run level:
a reference is one policy) on the verdict cost (charged for what it computes where the cost charges
compute, the SIF), RMSE and ANEES, its compute per step, and the learned groups' seed-level differences
to greedy, ML and every reference with their verdicts (:func:`adaptfilt.verdicts.verdict`, "lower");
:func:`plot_look_gain` draws the gain over greedy against the horizon.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from adaptfilt.experiments.report import md_table
from adaptfilt.verdicts import verdict

__all__ = ["LOOK", "LOOK_QUICK", "LOOK_BASES", "LOOK_BASES_QUICK", "look_specs", "look_job", "look_summary",
           "rejudge", "plot_look_gain", "look_md", "look_files", "look_new_files", "stored_part", "part_names",
           "best_references"]

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
#: The rollout's other bases (:mod:`adaptfilt.lookahead`), experiment -> {base: ((H, S), ...)}: over ML at
#: every (H, S) of :data:`LOOK`; over the better of greedy and ML everywhere on the CTM (the open question)
#: and at H = 1 on UNGM, where the two bases share their one continuation step and it costs what one base
#: costs (at H > 1 the later steps run once per base).
LOOK_BASES = {"ungm-ukf": {"ml": LOOK["ungm-ukf"][1], "best": ((1, 4), (1, 16))},
              "ctm-ukf": {"ml": LOOK["ctm-ukf"][1], "best": LOOK["ctm-ukf"][1]}}
#: The same at toy scale (tests).
LOOK_BASES_QUICK = {"ungm-ukf": {"ml": ((1, 2),), "best": ((1, 2),)}, "ctm-ukf": {"ml": ((1, 2),), "best": ((1, 2),)}}
#: Samples of the two-step cross-check (UNGM: 13 x S x 13 updates per step).
TWOSTEP_SAMPLES = 4
#: Discount of the references: the adaptive policies' (the paper's gamma = 0.5).
GAMMA = 0.5


def look_specs(experiment: str, grid_hs, quick: bool = False, bases: dict | None = None,
               learned: bool = False) -> list[tuple]:
    """The jobs' policy families for ``experiment``: baselines, one rollout per (H, S), two-step on UNGM;
    then one rollout per other base and (H, S) of ``bases`` ({base: ((H, S), ...)}) and, with ``learned``,
    the ``mlanchor`` study's policies (``("learned",)``). The first ones keep their order (and job keys)."""
    specs = [("base",)] + [("rollout", int(h), int(s)) for h, s in grid_hs]
    if experiment == "ungm-ukf":
        specs.append(("twostep", 2 if quick else TWOSTEP_SAMPLES))
    for base, hs in (bases or {}).items():
        specs += [("rollout", int(h), int(s), base) for h, s in hs]
    if learned:
        specs.append(("learned",))
    return specs


def _policies(experiment: str, spec: tuple, files: list[str]) -> list:
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.jobs import load_learned
    from adaptfilt.lookahead import RolloutPolicy, TwoStepPolicy

    exp = get_experiment(experiment)
    if spec[0] == "base":
        base = [p for p in exp.baselines() if p.kind != "fixed-both"]
        return base + load_learned(exp, files)
    if spec[0] == "learned":
        return load_learned(exp, files)
    if spec[0] == "rollout":
        kw = {} if len(spec) == 3 else {"base": spec[3]}
        return [RolloutPolicy(exp.grid, horizon=spec[1], samples=spec[2], gamma=GAMMA, seed=0, **kw)]
    return [TwoStepPolicy(exp.grid, samples=spec[1], gamma=GAMMA, seed=0)]


def part_names(experiment: str, spec: tuple, files: list[str]) -> list[str]:
    """The names of the policies a part evaluates (what it adds to the merged evaluation)."""
    return [p.name for p in _policies(experiment, spec, files)]


def stored_part(path: str, sha: str, names: list[str]):
    """A part taken from the stored evaluation ``path`` (a ``results`` folder whose ``results.json`` has the
    sha256 ``sha``): its policies ``names`` as the part's job returned them, but for the per-run arrays the
    stored file leaves out (:data:`~adaptfilt.experiments.study.COMPACT`: saved without them again) and the
    wall times (moved to the manifest when it was saved). ValueError if the file changed since it was listed."""
    from adaptfilt.files import sha256
    from adaptfilt.results import Results

    if sha256(Path(path) / "results.json") != sha:
        raise ValueError(f"{path}/results.json changed since it was listed: its parts cannot be reused")
    res = Results.load(path)
    missing = [n for n in names if n not in res.policies]
    if missing:
        raise ValueError(f"the stored evaluation {path} lacks the part's policies {missing}")
    config = {k: v for k, v in res.config.items() if k not in ("dropped", "parts")}
    config["policies"] = list(names)
    return Results(config=config, policies={n: res.policies[n] for n in names})


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
    other_bases = any(n.startswith("rollout-") and _parse(n)[1] != "greedy" for n in refs)
    for n in refs + ["greedy", "ml", "default"]:
        if n not in res:
            continue
        p = res[n]
        row = {m: getattr(p, m) for m in metrics}
        row.update(spent=p.spent, divergent_frac=p.divergent_frac)
        if n != "greedy":
            row["minus_greedy"] = {m: list(res.paired_difference(n, "greedy", m)) for m in metrics}
        if n in refs and other_bases and "ml" in res:
            # every reference is judged against ML as well as greedy (on the CTM ML is the lower of the two)
            row["minus_ml"] = {m: list(res.paired_difference(n, "ml", m)) for m in metrics}
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
        if other_bases:
            # where the other bases ran: each learned group against ML and every reference, on the verdict
            # cost and the objective, with its seed-level verdict ("lower": the interval below 0)
            out["learned"][g]["against"] = _against(res, names, ["ml"] + refs, (cost, "objective"))
    # Bertsekas' cost improvement: rollout on greedy costs no more than greedy (exact expectations, full
    # horizon); here truncated and sampled, so measured: the verdict on "the reference is lower than greedy"
    for n, row in out["references"].items():
        _judge(row, cost)
    return out


def _judge(row: dict, cost: str) -> dict:
    """A reference's verdicts: lower verdict cost than greedy (and than ML where it was compared)."""
    row["improves_on_greedy"] = verdict("lower", row["minus_greedy"][cost])
    if "minus_ml" in row:
        row["improves_on_ml"] = verdict("lower", row["minus_ml"][cost])
    return row


def rejudge(look: dict) -> dict:
    """A stored study's ``{experiment: look_summary}`` with every reference's verdicts judged again by the
    one rule from their stored intervals: ``improves_on_greedy`` from the verdict cost's difference to
    greedy, and ``improves_on_ml`` from its difference to ML where one is stored."""
    out = {}
    for e, s in look.items():
        refs = {n: _judge(dict(row), s["verdict_cost"]) for n, row in s["references"].items()}
        out[e] = {**s, "references": refs}
    return out


def _against(res, names: list[str], refs: list[str], metrics) -> dict:
    """``{ref: {metric: [IQM difference, lo, hi], "verdict": ...}}`` of the seed group ``names`` against each
    single-policy reference (seed-level, paired runs); the verdict is on the first metric."""
    from adaptfilt.seed_stats import difference

    out = {}
    for r in refs:
        row = {m: list(difference(res, names, [r], m)["iqm"]) for m in metrics}
        row["verdict"] = verdict("lower", row[metrics[0]])
        out[r] = row
    return out


def _parse(name: str) -> tuple[str, str, int, int]:
    """``rollout-H2-S4`` -> ("rollout", "greedy", 2, 4); ``rollout-ml-H1-S4`` -> ("rollout", "ml", 1, 4);
    ``twostep-S4`` -> ("twostep", "greedy", 1, 4)."""
    parts = name.split("-")
    if parts[0] == "twostep":
        return "twostep", "greedy", 1, int(parts[1][1:])
    base = "greedy" if parts[1].startswith("H") else parts.pop(1)
    return "rollout", base, int(parts[1][1:]), int(parts[2][1:])


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


#: The learned groups the study's figure shows (where they were evaluated): the reproduction's, the
#: candidate-aware, the greedy-anchored and the ML-anchored learners (the tables list every group).
FIGURE_GROUPS = ("adaptive", "adaptive-cand", "adaptive-anchored", "adaptive-mlanchored")
#: Line colours of the rollout's bases in :func:`plot_look_gain`.
_BASE_COLOURS = {"greedy": "C0", "ml": "C1", "best": "C2"}


def plot_look_gain(look: dict, metric: str | None = None, axes=None, ylim: dict | None = None,
                   learned: dict | None = None):
    """The gain over greedy (greedy minus policy, on each experiment's verdict cost: positive is better)
    against the look-ahead horizon H, one line per base and S (colour: the base; solid S = 4, dashed
    S = 16; H = 0 is the base itself: greedy, or ML), with paired 95 % intervals; each learned group's
    seed-level gain (IQM, two-level interval) as a bar right of the largest H with its IQM as a dashed
    line across the panel (``learned[experiment]``: the groups to show, default all). ``ylim[experiment]``
    fixes a panel's range (by default it fits the references' and the learned groups' gains and intervals);
    a point or interval end beyond it is cut at the edge, marked with a triangle and its value written
    beside it. Returns the figure."""
    import matplotlib.pyplot as plt

    exps = list(look)
    if axes is None:
        fig, axes = plt.subplots(1, len(exps), figsize=(5.2 * len(exps), 4.2), layout="constrained", squeeze=False)
        axes = axes[0]
    fig = axes[0].figure
    for ax, e in zip(axes, exps):
        s = look[e]
        m = metric or s["verdict_cost"]
        by_s: dict[tuple, list] = {}
        for n, row in s["references"].items():
            kind, base, h, samples = _parse(n)
            if kind == "rollout":
                by_s.setdefault((base, samples), []).append((h, row["minus_greedy"][m]))
        curves = {}
        for (base, samples), pts in sorted(by_s.items(), key=lambda kv: (list(_BASE_COLOURS).index(kv[0][0]), kv[0][1])):
            pts.sort()
            # H = 0 is the base policy: greedy (a gain of 0), or ML (its own gain over greedy)
            at0 = s["baselines"]["ml"]["minus_greedy"][m] if base == "ml" and "ml" in s["baselines"] else [0.0] * 3
            h = np.array([0] + [p[0] for p in pts])
            shift = 0.04 * (samples - 8) / 8 + 0.05 * list(_BASE_COLOURS).index(base)
            curves[base, samples] = (h + shift, -np.array([list(at0)] + [p[1] for p in pts]))
        show = (learned or {}).get(e)
        learned_e = {g: (row["n_seeds"], -np.array(row["minus_greedy"][m])) for g, row in s["learned"].items()
                     if show is None or g in show}
        ends = [0.0] + [v for _, g in curves.values() for v in g.ravel()] + [v for _, d in learned_e.values() for v in d]
        lim = (ylim or {}).get(e)
        if lim is None:
            lo, hi = min(ends), max(ends)
            pad = 0.1 * (hi - lo or 1.0)
            lim = (lo - pad, hi + pad)
        h_max = max([1] + [int(round(h.max())) for h, _ in curves.values()])
        right = h_max + 0.35 + 0.3 * max(len(learned_e) - 1, 0) * h_max / 2 + 0.3 * h_max / 2
        ax.set_xlim(-0.15 * h_max / 2, right)
        for (base, samples), (h, g) in curves.items():  # gain = greedy - policy
            col = _BASE_COLOURS[base]
            label = "rollout" + ("" if base == "greedy" else " over ML" if base == "ml" else " over the better of both")
            ax.plot(h, g[:, 0], "-" if samples <= 4 else "--", color=col,  # runs off the view where it must
                    label=f"{label}, S = {samples}")
            for x, (v, a, b) in zip(h, g[:, [0, 2, 1]]):  # gain interval: [-(upper), -(lower)]
                _clipped_vbar(ax, x, v, a, b, lim, col)
        for i, (gname, (n_seeds, d)) in enumerate(learned_e.items()):
            col, x = f"C{(i + 3) % 10}", h_max + 0.35 + 0.3 * i * h_max / 2
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


def look_md(look: dict, bases: tuple[str, ...] | None = None, learned: tuple[str, ...] | None = None) -> str:
    """The study's table: per experiment, references, baselines and learned groups against greedy; then, where
    other bases ran, every reference and learned group against ML (:func:`_against_md`). ``bases``: only the
    rollouts over these bases (``("greedy",)``), ``learned``: only these groups; either one leaves out the
    tables against ML."""
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
            if bases is not None and _parse(n)[1] not in bases:
                continue
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
            if learned is not None and n not in learned:
                continue
            d = row["minus_greedy"]
            lines.append(f"| {e} | {n} ({row['n_seeds']} seeds) | {row[c]:.4g} | {f(d[c])} | {f(d['rmse'])} "
                         f"| {f(d['anees'])} | {row['spent']:.3g} | |")
    return "\n".join(lines + (_against_md(look) if bases is None and learned is None else [])) + "\n"


def best_references(s: dict) -> dict[str, str]:
    """Per rollout base, the reference with the lowest verdict cost on these runs (the bar each base sets)."""
    c, out = s["verdict_cost"], {}
    for n, row in s["references"].items():
        kind, base, _, _ = _parse(n)
        if kind == "rollout" and (base not in out or row[c] < s["references"][out[base]][c]):
            out[base] = n
    return out


def _against_md(look: dict) -> list[str]:
    """The learned groups against ML and the best rollout of each base (where the study ran the other bases)."""
    f = lambda d: f"{d[0]:+.4g} [{d[1]:+.3g}, {d[2]:+.3g}]"  # noqa: E731
    lines = []
    for e, s in look.items():
        rows = {g: r["against"] for g, r in s["learned"].items() if "against" in r}
        if not rows:
            continue
        c, refs = s["verdict_cost"], best_references(s)
        vs_ml = {n: r for n, r in s["references"].items() if "minus_ml" in r}
        lines += ["", f"**{e}: every look-ahead reference against ML** (M = {s['n_runs']}; paired runs, run-level "
                  "95 % CI; verdict on the cost, 'confirmed': below ML)", "",
                  *md_table(["reference", "cost - ml", "RMSE - ml", "lower cost than ML"])]
        lines += [f"| {n} | {f(r['minus_ml'][c])} | {f(r['minus_ml']['rmse'])} | {r['improves_on_ml']} |"
                  for n, r in vs_ml.items()]
        cols = ["ml"] + [refs[b] for b in _BASE_COLOURS if b in refs]
        lines += ["", f"**{e}: learned groups against ML and the best rollout of each base** (M = {s['n_runs']}; "
                  "IQM over seeds minus the reference, seed-level 95 % CI; verdict on the cost, 'confirmed': below)", "",
                  *md_table(["group"] + [f"cost - {r}" for r in cols])]
        for g, a in rows.items():
            lines.append(f"| {g} | " + " | ".join(f"{f(a[r][c])} {a[r]['verdict']}" for r in cols) + " |")
    return lines


def look_files(data: Path, out: Path, experiment: str, seeds) -> list[str]:
    """The learned policies shown beside the references: the reproduction's adaptive ones, and the
    candidate-aware and anchored ones of ``beyond`` where they exist."""
    paths = [data / f"policies/{experiment}-adaptive-s{s}.npz" for s in seeds]
    paths += [out / f"policies/{experiment}-{k}-s{s}.npz" for k in ("adaptive-cand", "adaptive-anchored") for s in seeds]
    return [str(p) for p in paths if p.exists()]


def look_new_files(out: Path, experiment: str, seeds) -> list[str]:
    """The ``mlanchor`` study's policies of ``experiment`` that exist (its groups of
    :data:`adaptfilt.experiments.studies.mlanchor.LOOK_GROUPS`), shown in a part of their own."""
    from adaptfilt.experiments.studies.mlanchor import LOOK_GROUPS

    paths = [out / f"policies/{experiment}-{k}-s{s}.npz" for k in LOOK_GROUPS for s in seeds]
    return [str(p) for p in paths if p.exists()]
