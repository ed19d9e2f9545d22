"""The particle-count study of ``adaptfilt beyond --studies particles`` (chapter 17).

Learned particle counts (the fast mode, gamma 0.5, 8 seeds) on every experiment of
:data:`~adaptfilt.experiment_registry.PARTICLE_EXPERIMENTS` (UNGM and the CTM, two prices per particle),
evaluated on the same runs as every fixed count of the grid, KLD-sampling, the ESS targets and greedy;
on UNGM also the point-mass filter's RMSE on the first runs, the accuracy floor. The verdict rows
(:func:`particle_rows`) answer the study's question at the seed level: does a learned count beat
the best KLD-sampling bins and the best fixed count on the cost (squared error plus the price of the particles,
i.e. at equal price), and where does it sit on RMSE against mean particles per step?

The jobs are those of :mod:`adaptfilt.experiments.beyond` (journaled, resumable); this module holds
what is particular to the study: its scale, its jobs' arguments, the floor and the summary rows.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from adaptfilt.experiments.report import md_table
from adaptfilt.verdicts import verdict

__all__ = ["ParticleScale", "PARTICLE_FULL", "PARTICLE_QUICK", "REFERENCE_PREFIX", "EVAL_PARTS", "evaluate_model_job",
           "merge_model_parts", "reference_parts", "floor_job", "particle_rows", "particles_md", "plot_particle_tradeoff"]

#: Names of the reference filter's fixed counts: ``bpf-1000`` is the library's bootstrap particle filter
#: (systematic resampling when ESS < N/2) with 1000 particles.
REFERENCE_PREFIX = "bpf-"
#: Keys the reference filters' random streams, apart from the trajectories' and the study filter's.
_REFERENCE_KEY = 24


@dataclass(frozen=True)
class ParticleScale:
    """Episodes per policy, horizon (None: the experiment's), evaluation runs and floor runs."""

    episodes: int
    n_steps: int | None
    eval_runs: int
    floor_runs: int

    def words(self) -> str:
        """The budgets, as a journal key reads them."""
        return f"episodes={self.episodes} steps={self.n_steps} runs={self.eval_runs} floor={self.floor_runs}"


#: Budgets of the particle study: 500 training episodes (5x10^4 transitions on UNGM's 100 steps; about 6
#: CPU-minutes a policy on the CTM), evaluation on 250 runs (every fixed count of the grid is 15,225 particles
#: a step together, in each of the two forms: about 25 CPU-minutes on the CTM), the floor on 200.
PARTICLE_FULL = ParticleScale(500, None, 250, 200)
PARTICLE_QUICK = ParticleScale(4, 10, 20, 5)


#: The parts of one model's evaluation, each its own job (so that a model's parts run side by side):
#: the fixed counts and the default, the rules (KLD-sampling, ESS targets), the reference filter's fixed
#: counts, and greedy with the learned policies (per price).
EVAL_PARTS = ("fixed", "rules", "reference", "own")


def evaluate_model_job(experiments: list[str], files: list[list[str]], scale: ParticleScale, seed: int = 0,
                       parts: tuple[str, ...] = EVAL_PARTS) -> list:
    """The evaluations of one model's experiments (the same filter and runs at different prices), one
    :class:`~adaptfilt.results.Results` each, holding the policies of ``parts`` (:data:`EVAL_PARTS`; a part
    alone is one job of ``adaptfilt beyond``, :func:`merge_model_parts` joins them). The baselines that
    cannot see the price (fixed counts, KLD, ESS, the reference filter) are rolled out once and charged
    every price (:func:`~adaptfilt.evaluation.evaluate_costs`), greedy and each experiment's learned
    ``files`` per experiment: bit for bit what one :func:`~adaptfilt.evaluation.evaluate` per experiment
    gives (but for wall times)."""
    from adaptfilt.evaluation import evaluate, evaluate_costs
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.jobs import load_learned
    from adaptfilt.particle_env import ESSTargetPolicy, KLDSamplingPolicy

    unknown = set(parts) - set(EVAL_PARTS)
    if unknown:
        raise ValueError(f"unknown parts {sorted(unknown)}; known: {', '.join(EVAL_PARTS)}")
    exps = [get_experiment(e) for e in experiments]
    blind = [p for p in exps[0].baselines() if p.name != "greedy"]
    rules = [p for p in blind if isinstance(p, (KLDSamplingPolicy, ESSTargetPolicy))]
    out: list[list] = [[] for _ in exps]
    for part in parts:
        if part in ("fixed", "rules"):
            pols = rules if part == "rules" else [p for p in blind if p not in rules]
            shared = evaluate_costs(exps, pols, n_runs=scale.eval_runs, seed=seed, progress=False, n_steps=scale.n_steps)
            got = [shared[e.name] for e in exps]
        elif part == "reference":
            ref, failed = reference_parts(exps, scale, seed)
            got = [ref[e.name] for e in exps]
            for r in got:
                r.config["reference_failed"] = failed
        else:
            got = []
            for exp, fs in zip(exps, files):
                pols = [p for p in exp.baselines() if p.name == "greedy"]
                pols += load_learned(exp, fs)
                got.append(evaluate(exp, pols, n_runs=scale.eval_runs, seed=seed, progress=False, n_steps=scale.n_steps))
        for o, r in zip(out, got):
            o.append(r)
    return [merge_model_parts(o) for o in out]


def merge_model_parts(parts: list):
    """One experiment's :class:`~adaptfilt.results.Results` from its parts (same runs), in the order given;
    the reference filter's failures (``config["reference_failed"]``) carried over."""
    from adaptfilt.results import Results

    failed: dict = {}
    for p in parts:
        failed.update(p.config.pop("reference_failed", {}))
    res = Results.merge(parts)
    res.config["reference_failed"] = failed
    return res


def reference_parts(exps: list, scale: ParticleScale, seed: int = 0) -> tuple[dict, dict]:
    """The fixed counts in their best-known form: the library's
    :class:`~adaptfilt.exact.BootstrapParticleFilter` (systematic resampling, only when ESS < N/2; the
    weights carried otherwise) with every count ``N`` of the grid, named ``bpf-N``, evaluated beside the
    policies on the evaluation's runs (:func:`~adaptfilt.evaluation.evaluate_costs` with ``filters``),
    charged each experiment's cost (``||x_filt - x||^2 + price N``). The study's own filter resamples
    multinomially at every step, which is what KLD-sampling and a count that changes per step need, and
    what makes particle ``j`` the same for every count; a fixed count needs neither, so this is the bar a
    learned count has to clear. Returns ``({experiment: Results}, {N: reason})``: a count whose filter
    fails (no particle explains a measurement) has no row and its reason."""
    from adaptfilt.evaluation import evaluate_costs
    from adaptfilt.exact import BootstrapParticleFilter

    for e in exps:
        if getattr(e.cost, "kind", None) != "sqerr":
            raise ValueError(f"{e.name}: the reference filter is charged the squared error only (its NIS and update "
                             f"step are not the study filter's), got the cost {e.cost.name!r}")
    env = exps[0].make_env(seed=seed, n_steps=scale.n_steps)
    filters = {f"{REFERENCE_PREFIX}{N}": BootstrapParticleFilter(env.model, n_particles=int(N),
                                                                 seed=[_REFERENCE_KEY, seed, int(N)])
               for N in env.grid.astype(int)}
    out = evaluate_costs(exps, [], n_runs=scale.eval_runs, seed=seed, progress=False, n_steps=scale.n_steps,
                         filters=filters, on_filter_error="skip")
    failed: dict = {}
    for r in out.values():  # every experiment's results name the same failures
        failed = {int(n[len(REFERENCE_PREFIX):]): why for n, why in r.config.pop("failed_filters", {}).items()}
    return out, failed


def floor_job(experiment: str, scale: ParticleScale, seed: int = 0) -> dict:
    """RMSE of the point-mass filter (the exact posterior up to its grid, :func:`~adaptfilt.exact.bayes_floor`)
    on the first ``floor_runs`` of the evaluation's runs of a one-dimensional model: the accuracy no particle
    count can beat. None for others."""
    from adaptfilt.exact import UNGM_STUDY_FLOOR_GRID, bayes_floor
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.runs import EvalRuns

    env = get_experiment(experiment).make_env(seed=seed, n_steps=scale.n_steps)
    if env.nx != 1:
        return {"rmse": None, "runs": 0}
    runs = EvalRuns(env.truth, scale.eval_runs, seed, env.n_steps)
    return bayes_floor(env.model, runs, scale.floor_runs, UNGM_STUDY_FLOOR_GRID).summary()


def particle_rows(res, floor: dict | None = None) -> dict:
    """The study's summary of one experiment's evaluation ``res``: for the learned group ``adaptive`` the
    IQM over seeds (two-level intervals) of cost, RMSE and the objective, mean particles per step per seed,
    and the differences to the cheapest KLD-sampling bins, the cheapest fixed count of the study's filter and
    of the reference filter (``bpf-N``, :func:`reference_parts`) (seed-level intervals, paired runs) with how
    many seeds lie below each alone; for every baseline its cost, RMSE, mean particles and divergent runs;
    the floor and the counts at which the reference filter failed."""
    from adaptfilt.seed_stats import aggregate, difference, seed_groups

    fixed = [n for n in res.names if n.startswith("fixed-")]
    best = min(fixed, key=lambda n: res[n].cost_charged)
    ref = [n for n in res.names if n.startswith(REFERENCE_PREFIX)]
    best_ref = min(ref, key=lambda n: res[n].cost_charged) if ref else None
    # the best KLD bins in hindsight, on the evaluation runs themselves: a bar that favours KLD-sampling
    kld = min((n for n in res.names if n.startswith("kld")), key=lambda n: res[n].cost_charged)
    rows: dict = {"best fixed": best, "best kld": kld, "best reference": best_ref, "floor": floor,
                  "reference_failed": sorted(int(n) for n in res.config.get("reference_failed", {}))}
    rows["baselines"] = {n: {"cost": res[n].cost_charged, "rmse": res[n].rmse, "anees": res[n].anees,
                             "particles": res[n].spent, "divergent_frac": res[n].divergent_frac}
                         for n in res.names if not n.startswith("adaptive")}
    members = seed_groups(res.names).get("adaptive", [])
    if members:
        g = {m: aggregate(res, members, m).to_dict() for m in ("cost_charged", "rmse", "objective")}
        g["particles"] = [res[n].spent for n in members]
        g["divergent_frac"] = [res[n].divergent_frac for n in members]
        for label, other in (("best kld", kld), ("best fixed", best), ("best reference", best_ref)):
            if other is not None:
                g[f"minus_{label}"] = {m: list(difference(res, members, [other], m)["iqm"]) for m in ("cost_charged", "rmse")}
        # a seed is below a baseline alone when its own paired run-level interval confirms "lower"
        for label, other in (("kld", kld), ("fixed", best), ("reference", best_ref)):
            if other is not None:
                g[f"seeds_below_{label}"] = sum(verdict("lower", res.paired_difference(n, other, "cost_charged"))
                                                == "confirmed" for n in members)
        rows["adaptive"] = g
    return rows


def particles_md(particles: dict) -> str:
    """The study's table for REPRODUCTION.md: per experiment the best KLD bins, the best fixed count of the
    study's filter and of the reference filter, greedy, the default and the learned group (IQM [seed-level
    CI], differences paired), and the floor."""
    f = lambda a: f"{a['iqm']:.4g} [{a['iqm_ci'][0]:.4g}, {a['iqm_ci'][1]:.4g}]"  # noqa: E731
    d = lambda x: f"{x[0]:+.4g} [{x[1]:+.4g}, {x[2]:+.4g}]"  # noqa: E731
    lines = ["**The particle count** (cost = squared error + price x particles, i.e. compared at equal price; "
             "learned: IQM over seeds [two-level 95 % CI], differences paired; `bpf-N`: the reference filter, "
             "systematic resampling when ESS < N/2)", "",
             *md_table(["experiment", "policy", "cost", "RMSE", "particles per step", "divergent runs",
                        "cost - best KLD", "cost - best fixed", "cost - best bpf"])]
    for e, rows in particles.items():
        for n in (rows["best kld"], rows["best fixed"], rows.get("best reference"), "greedy", "default"):
            b = rows["baselines"].get(n) if n else None
            if b is not None:
                lines.append(f"| {e} | {n} | {b['cost']:.4g} | {b['rmse']:.4g} | {b['particles']:.4g} | "
                             f"{b['divergent_frac']:.2%} | | | |")
        a = rows.get("adaptive")
        if a is not None:
            k = len(a["particles"])
            cols = [f"{d(a[f'minus_best {lab}']['cost_charged'])} ({a[f'seeds_below_{key}']} of {k} seeds below alone)"
                    if f"minus_best {lab}" in a else "" for lab, key in (("kld", "kld"), ("fixed", "fixed"),
                                                                       ("reference", "reference"))]
            lines.append(f"| {e} | adaptive | {f(a['cost_charged'])} | {f(a['rmse'])} | "
                         f"{min(a['particles']):.4g}-{max(a['particles']):.4g} | {max(a['divergent_frac']):.2%} (max) | "
                         + " | ".join(cols) + " |")
        if rows.get("floor") and rows["floor"]["rmse"] is not None:
            lines.append(f"| {e} | point-mass floor ({rows['floor']['runs']} runs) | | {rows['floor']['rmse']:.4g} "
                         "| | | | | |")
        if rows.get("reference_failed"):
            lines.append(f"| {e} | bpf failed at N = {', '.join(map(str, rows['reference_failed']))} "
                         "(no particle explained a measurement) | | | | | | | |")
    return "\n".join(lines) + "\n"


def plot_particle_tradeoff(particles: dict, axes=None):
    """RMSE against mean particles per step (log axis), one panel per experiment of the study's summary
    (:func:`particle_rows` by experiment): the fixed counts of the study's filter and of the reference filter
    as lines, the KLD-sampling bins and the ESS
    targets as their own lines, greedy and the default as points, each learned seed as a dot and the
    group's IQM with its seed-level 95 % interval at the seeds' mean count, and the point-mass floor (where
    there is one) as a dashed line. Returns the figure."""
    import matplotlib.pyplot as plt

    exps = list(particles)
    if axes is None:
        fig, axes = plt.subplots(1, len(exps), figsize=(4.6 * len(exps), 3.9), layout="constrained", squeeze=False)
        axes = axes[0]
    fig = axes[0].figure
    for ax, e in zip(axes, exps):
        rows = particles[e]
        base = rows["baselines"]
        for prefix, label, style in (("fixed-", "fixed N", "o-"), (REFERENCE_PREFIX, "fixed N, reference PF", "o-."),
                                     ("kld", "KLD-sampling", "s--"), ("ess-", "ESS target", "^:")):
            pts = sorted((b["particles"], b["rmse"]) for n, b in base.items() if n.startswith(prefix))
            if pts:
                ax.plot(*zip(*pts), style, ms=4, lw=1, label=label)
        for n, marker in (("greedy", "D"), ("default", "x")):
            if n in base:
                ax.plot(base[n]["particles"], base[n]["rmse"], marker, ms=6, color="k" if n == "greedy" else "0.4",
                        label=n)
        a = rows.get("adaptive")
        if a is not None:
            n_mean = float(np.mean(a["particles"]))
            ax.plot(a["particles"], a["rmse"]["values"], ".", color="C3", alpha=0.6, label="learned seeds")
            lo, hi = a["rmse"]["iqm_ci"]
            ax.errorbar([n_mean], [a["rmse"]["iqm"]], yerr=[[a["rmse"]["iqm"] - lo], [hi - a["rmse"]["iqm"]]],
                        fmt="*", ms=10, color="C3", capsize=3, label="learned (IQM, seed-level CI)")
        floor = rows.get("floor")
        if floor and floor.get("rmse") is not None:
            ax.axhline(floor["rmse"], ls="--", color="0.5", lw=1, label=f"point-mass floor ({floor['runs']} runs)")
        ax.set_xscale("log")
        ax.set_xlabel("mean particles per step")
        ax.set_ylabel("RMSE")
        ax.set_title(e)
    # one legend for all panels, below them: every family once, the floor too (not every panel has one)
    seen: dict = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    fig.legend(list(seen.values()), list(seen), loc="outside lower center", ncol=min(len(seen), 5), fontsize="small")
    return fig
