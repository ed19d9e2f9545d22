r"""Is the fast trainer as good as Algorithm 2's loop (the faithful trainer)? The seed-level comparison.

For an experiment evaluated with both seed groups, ``adaptive`` (the fast
mode, :data:`adaptfilt.trainers.FAST`) and ``adaptive-faithful`` (Algorithm 2,
one episode at a time), on the same runs: for each metric the IQM over seeds
of each group and the difference fast minus faithful with its two-level
(seeds x runs) bootstrap interval. The target: the fast mode is **not worse**
on cost, RMSE and ANEES, a non-inferiority claim judged by the one rule
(:func:`adaptfilt.verdicts.verdict`: confirmed when the interval lies below the
margin, contradicted when it lies wholly above it) with the margins declared for
``"fast vs faithful"`` in :data:`adaptfilt.verdicts.DECLARED_MARGINS` (a fraction
of the faithful IQM). The objective both optimise (mean ``log(1 + L)``) is
judged with them.
"""
from __future__ import annotations

from adaptfilt.experiments.claims import members
from adaptfilt.experiments.report import md_table
from adaptfilt.seed_stats import aggregate, difference
from adaptfilt.verdicts import judge, verdict

__all__ = ["comparison", "comparison_md", "rejudge", "METRICS", "DECLARED"]

METRICS = ("cost", "rmse", "anees", "objective")
#: The declared comparison (:data:`adaptfilt.verdicts.DECLARED_MARGINS`) whose margins judge it.
DECLARED = "fast vs faithful"


def comparison(results: dict, train_times: dict | None = None, fast: str = "adaptive",
               faithful: str = "adaptive-faithful") -> dict:
    """``{experiment: {"rows": [...], "train_cpu_s": {...}}}`` for every experiment holding both groups.
    ``train_times``: ``{policy file path: {"wall_time_s", "cpu_time_s"}}`` (the reproduction's job times)."""
    out = {}
    for e, res in results.items():
        try:
            A, B = members(res, fast), members(res, faithful)
        except KeyError:
            continue
        rows = []
        for m in METRICS:
            if m == "objective" and not all(hasattr(res[n], "boot_objective") and len(res[n].boot_objective)
                                            for n in A + B):
                continue
            d = difference(res, A, B, m)
            faithful_agg = aggregate(res, B, m)
            word, margin = judge("not worse", d["iqm"], DECLARED, m, faithful_agg.iqm)
            rows.append({"metric": m, "fast": aggregate(res, A, m).to_dict(), "faithful": faithful_agg.to_dict(),
                         "diff_iqm": list(d["iqm"]), "diff_mean": list(d["mean"]), "margin": margin,
                         "claim": "fast not worse than faithful", "declared": DECLARED, "verdict": word})
        times = {}
        for group, names in ((fast, A), (faithful, B)):
            t = [v for k, v in (train_times or {}).items() if any(k.endswith(f"{e}-{n}.npz") for n in names)]
            if t:
                times[group] = {"n": len(t), "mean_wall_s": sum(x["wall_time_s"] for x in t) / len(t),
                                "mean_cpu_s": sum(x["cpu_time_s"] for x in t) / len(t)}
        out[e] = {"rows": rows, "n_seeds": {fast: len(A), faithful: len(B)}, "train_time": times,
                  "n_runs": res.config["n_runs"]}
    return out


def rejudge(comp: dict) -> dict:
    """A stored comparison judged again by the one rule from each row's interval and margin (for the summaries
    of a reproduction whose evaluations are not kept); rows lose the old ``verdict_no_margin``."""
    out = {}
    for e, d in comp.items():
        rows = []
        for r in d["rows"]:
            r = {k: v for k, v in r.items() if k != "verdict_no_margin"}
            r.update(claim="fast not worse than faithful", declared=DECLARED,
                     verdict=verdict("not worse", r["diff_iqm"], r["margin"]))
            rows.append(r)
        out[e] = {**d, "rows": rows}
    return out


def comparison_md(comp: dict) -> str:
    lines = md_table(["experiment", "metric", "fast, IQM [95% CI] (range)", "faithful, IQM [95% CI] (range)",
                      "fast - faithful, IQM [seed-level 95% CI]", "margin", "fast not worse than faithful"])
    for e, d in comp.items():
        for r in d["rows"]:
            f, g, (x, lo, hi) = r["fast"], r["faithful"], r["diff_iqm"]
            cell = lambda a: (f"{a['iqm']:.4g} [{a['iqm_ci'][0]:.4g}, {a['iqm_ci'][1]:.4g}] "
                              f"({min(a['values']):.3g}..{max(a['values']):.3g})")
            lines.append(f"| {e} | {r['metric']} | {cell(f)} | {cell(g)} | {x:+.4g} [{lo:+.4g}, {hi:+.4g}] "
                         f"| {r['margin']:.3g} | {r['verdict']} |")
    times = []
    for e, d in comp.items():
        for g, t in d["train_time"].items():
            times.append(f"{e} {g}: {t['mean_cpu_s']:.0f} CPU-s per policy ({t['n']} policies, "
                         f"mean wall {t['mean_wall_s']:.0f} s)")
    seeds = ", ".join(f"{e}: {d['n_seeds']}" for e, d in comp.items())
    return ("Seeds per group: " + seeds + ". " + ("Training: " + "; ".join(times) + "." if times else "") + "\n\n"
            + "\n".join(lines) + "\n")
