r"""What a study of ``adaptfilt beyond`` is: the small interface each file of
:mod:`adaptfilt.experiments.studies` implements, what a study sees of the run (:class:`Run`), and the
rows and table the learned-group studies (cand, sif, raw, anchor) share.

A study is a module with a ``NAME`` (its ``--studies`` word) and six functions (:class:`Study`); the driver
(:func:`adaptfilt.experiments.beyond.run`) calls them in phases, every chosen study's at once, so that the
jobs of all studies share the workers:

1. ``prepare(run)``: what must be chosen before training (the SIF study's safe action set), as summary entries;
2. ``policies(run, summary)``: what it trains, ``[Training]`` (:class:`~adaptfilt.experiments.jobs.Training`:
   ``adaptfilt train`` or ``adaptfilt train-gain`` lines, each naming the files it writes in DIR/beyond);
3. ``evaluations(run, summary, trained)``: what it evaluates, ``[EvalSpec]`` (``trained``: its own trainings);
4. ``rows(run, summary, specs, values)``: writes the evaluations' files, returns its summary entries;
5. ``figures(run, summary)``: draws its figures into ``DIR/beyond/figures``, returns their paths;
6. ``markdown(summary)``: its tables for REPRODUCTION.md (empty when the summary lacks it).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from adaptfilt.experiments.jobs import EvalSpec, Training, evaluate_spec, job_key, load_learned, same_command, take_times
from adaptfilt.experiments.report import md_table
from adaptfilt.files import sha256
from adaptfilt.verdicts import verdict

__all__ = ["Study", "Run", "BeyondScale", "FULL", "QUICK", "GROUPS", "COMPACT", "study_rows", "groups_md",
           "evaluation", "evaluate_job", "divergence", "listed_policies", "same_training"]


class Study(Protocol):
    """The interface of a study (module docstring); each module of :mod:`adaptfilt.experiments.studies` is one."""

    NAME: str

    def prepare(self, run: "Run") -> dict: ...
    def policies(self, run: "Run", summary: dict) -> list[Training]: ...
    def evaluations(self, run: "Run", summary: dict, trained: list[Training]) -> list[EvalSpec]: ...
    def rows(self, run: "Run", summary: dict, specs: list[EvalSpec], values: list) -> dict: ...
    def figures(self, run: "Run", summary: dict) -> list[str]: ...
    def markdown(self, summary: dict) -> str: ...


@dataclass(frozen=True)
class BeyondScale:
    """The budgets of a run of the studies."""

    name: str
    episodes: int
    seeds: tuple[int, ...]
    n_steps: int | None
    eval_runs: int
    retune_episodes: int

    def words(self) -> str:
        """The budgets, as a journal key reads them."""
        return f"runs={self.eval_runs} steps={self.n_steps} episodes={self.episodes} retune={self.retune_episodes}"


FULL = BeyondScale("full", 1000, tuple(range(8)), None, 10_000, 50)
QUICK = BeyondScale("quick", 10, (0, 1), 20, 100, 2)

#: The learned groups a study summarises (policy names ``<group>-s<seed>``).
GROUPS = ("adaptive-cand", "myopic-cand", "adaptive-penalised", "adaptive-safe", "adaptive-raw", "adaptive-anchored",
          "myopic-anchored", "adaptive")
#: Per-run arrays left out of the stored evaluations (about 85 % of each file); the seed-level aggregates,
#: paired differences (bootstrap replicates), usage and per-step curves stay.
COMPACT = ("run_rmse", "run_anees", "run_cost", "choices")


@dataclass
class Run:
    """What a study sees of the run: where it writes (``out`` = DIR/beyond), where the reproduction's
    policies are (``data``), its scale, the run's command (recorded for every file but the policies), the
    journal; ``entries`` collects the manifest's entries of what the studies write."""

    out: Path
    data: Path
    scale: BeyondScale
    quick: bool
    command: str
    journal: Any
    workers: int | None = None
    cluster: Any = None
    progress: bool = True
    entries: dict[str, dict] = field(default_factory=dict)
    #: The output folder as the user typed it (``data``): what the manifest's commands say for the resolved one.
    typed_out: str | None = None

    def say(self, *a) -> None:
        if self.progress:
            print(*a, flush=True)

    def jobs(self, fn: Callable, jobs: Sequence[tuple], keys: Sequence[tuple[str, int]], **kw) -> list:
        """The journal's run of ``fn`` over ``jobs`` on this run's workers."""
        return self.journal.run(fn, jobs, keys, workers=self.workers, cluster=self.cluster, **kw)

    def reproduction(self, experiment: str) -> list[str]:
        """The reproduction's adaptive policies of ``experiment`` (those there are)."""
        paths = [self.data / f"policies/{experiment}-adaptive-s{s}.npz" for s in self.scale.seeds]
        return [str(p) for p in paths if p.exists()]

    def save(self, name: str, res, **save_kw) -> None:
        """Write the evaluation ``res`` into ``results/<name>`` (its wall time into the manifest)."""
        wall = take_times(res)
        res.save(self.out / "results" / name, **save_kw)
        files = ("results.json", "results.npz") if save_kw.get("arrays", True) else ("results.json",)
        self.entries.update({f"results/{name}/{f}": {"command": self.command, "wall_time_s": wall} for f in files})

    def figure(self, fig, name: str) -> str:
        """Save ``fig`` as ``figures/<name>`` (closed after) and record it."""
        import matplotlib.pyplot as plt

        from adaptfilt.files import atomic_savefig

        (self.out / "figures").mkdir(parents=True, exist_ok=True)
        atomic_savefig(fig, self.out / "figures" / name, dpi=100)
        plt.close(fig)
        self.entries[f"figures/{name}"] = {"command": self.command}
        return f"figures/{name}"


# ------------------------------------------------------------------ the learned-group studies' evaluation
def evaluate_job(experiment: str, files: list[str], scale: BeyondScale, keep: tuple[str, ...] | None, seed: int = 0):
    """The baselines in ``keep`` (and every update-only constant) and the policy ``files`` on ``scale``'s runs."""
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment

    exp = get_experiment(experiment)
    base = [p for p in exp.baselines() if keep is None or p.name in keep or p.kind == "fixed"]
    target = exp if scale.n_steps is None else exp.make_env(n_steps=scale.n_steps)
    res = evaluate(target, base + load_learned(exp, files), n_runs=scale.eval_runs, seed=seed, progress=False)
    res.config.update(experiment=experiment)
    return res


def evaluation(study: str, experiment: str, files: list[str], scale: BeyondScale, keep: tuple[str, ...],
               *seed: int) -> EvalSpec:
    """The :func:`evaluate_job` of ``study`` on ``experiment`` (``seed``: the evaluation seed when not 0)."""
    return EvalSpec(study, experiment, evaluate_job, (experiment, files, scale, keep, *seed),
                    job_key("evaluate", study, experiment, files, scale.words(), keep, *seed))


def save_each(run: Run, study: str, specs: list[EvalSpec], values: list, rows: Callable) -> dict:
    """Write each experiment's evaluation as ``results/<study>-<experiment>`` and summarise it with ``rows``."""
    out = {}
    for spec, res in zip(specs, values):
        run.save(f"{study}-{spec.experiment}", res, drop=COMPACT)
        out[spec.experiment] = rows(res)
    return out


def divergence(res, names: list[str]) -> dict:
    """Divergent runs of ``names`` pooled over them, as a rate with its exact 95 % interval, and the worst one's."""
    from adaptfilt.metrics import rate_ci

    n = res.config["n_runs"]
    k = [int(round(res[x].divergent_frac * n)) for x in names]
    rate, lo, hi = rate_ci(sum(k), n * len(k))
    return {"divergent_runs": k, "n_runs": n, "divergent_rate": rate, "divergent_rate_ci": [lo, hi]}


def study_rows(study: str, res, selection: dict | None = None, groups: Sequence[str] = GROUPS) -> dict:
    """A study's summary rows for one experiment's evaluation ``res``: each learned group of ``groups``
    (default :data:`GROUPS`; IQM over seeds with two-level intervals, differences to greedy and the default,
    divergence, compute, seeds below greedy alone) and the references (greedy, default, ML, the
    cheapest constant: among the ``selection``'s safe set in the SIF study)."""
    from adaptfilt.seed_stats import aggregate, difference, seed_groups

    rows = {}
    # exact group names: "adaptive-s3" is a seed of "adaptive", "adaptive-safe-s3" is not (a prefix test
    # once merged the safe policies into the reproduction's "adaptive" row of the SIF study)
    seeds = seed_groups(res.names)
    groups = {g: seeds.get(g, []) for g in (*GROUPS, *groups)}
    metrics = ("cost", "cost_charged", "objective", "rmse", "anees")
    for g, members in groups.items():
        if not members:
            continue
        rows[g] = {m: aggregate(res, members, m).to_dict() for m in metrics}
        for ref in ("greedy", "default"):
            rows[g][f"minus_{ref}"] = {m: list(difference(res, members, [ref], m)["iqm"]) for m in metrics}
        rows[g]["divergent_frac_max"] = float(max(res[n].divergent_frac for n in members))
        rows[g].update(divergence(res, members))
        rows[g]["spent"] = float(np.mean([res[n].spent for n in members]))
        # each seed alone: does its own paired run-level interval confirm a lower cost than greedy's?
        c = "cost_charged" if study == "sif" else "cost"
        rows[g]["seeds_below_greedy"] = sum(verdict("lower", res.paired_difference(n, "greedy", c)) == "confirmed"
                                            for n in members)
    if groups["adaptive-raw"] and groups["adaptive"]:  # the transform's effect, paired
        rows["adaptive-raw"]["minus_adaptive"] = {m: list(difference(res, groups["adaptive-raw"],
                                                                     groups["adaptive"], m)["iqm"])
                                                  for m in ("cost", "objective", "rmse", "anees")}
    # what a constant can do: the cheapest fixed value, among the safe ones where the study chose a safe set
    # (on its selection runs: a value that happened not to diverge on these runs was not chosen on them)
    fixed = res.fixed_names()
    if study == "sif":
        fixed = [n for n in fixed if any(n == f"fixed-{res.config['param_name']}={v:g}" for v in selection["safe"])]
    label = "best safe fixed" if study == "sif" else "best fixed"
    best = min(fixed, key=lambda n: res[n].cost_charged) if fixed else None
    for ref, name in (("greedy", "greedy"), ("default", "default"), ("ml", "ml"), (label, best)):
        if name in res:
            p = res[name]
            rows[ref] = {"cost": p.cost, "cost_charged": p.cost_charged, "objective": p.objective, "rmse": p.rmse,
                         "anees": p.anees, "divergent_frac": p.divergent_frac, "policy": name, "spent": p.spent,
                         **divergence(res, [name])}
    return rows


# ------------------------------------------------------------------ tables
def _ci(a: dict) -> str:
    return f"{a['iqm']:.4g} [{a['iqm_ci'][0]:.4g}, {a['iqm_ci'][1]:.4g}]"


def diff_ci(x) -> str:
    """A difference and its interval, ``+d [+lo, +hi]``."""
    return f"{x[0]:+.4g} [{x[1]:+.4g}, {x[2]:+.4g}]"


def _rate(r: dict) -> str:
    return (f"{1e4 * r['divergent_rate']:.3g} [{1e4 * r['divergent_rate_ci'][0]:.2g}, "
            f"{1e4 * r['divergent_rate_ci'][1]:.2g}]"
            + (f" ({', '.join(map(str, r['divergent_runs']))})" if len(r["divergent_runs"]) > 1 else ""))


def groups_md(title: str, table: dict, charged: bool = False) -> list[str]:
    """The learned-group studies' table (:func:`study_rows` per experiment): references, then groups."""
    cost = "cost_charged" if charged else "cost"
    head = ["experiment", "policy", *(("cost charged", "cost uncharged") if charged else ("cost",)), "log(1+L)",
            "RMSE", "ANEES", "compute per step", "cost - greedy", "cost - default", "RMSE - greedy", "divergent runs"]
    lines = [f"**{title}** (IQM over seeds [two-level 95 % CI]; differences to greedy and the default; "
             + ("cost with compute charged, the verdict, and the paper's uncharged cost; " if charged else "")
             + "compute per step in SIF iterations or UKF updates; divergent runs per 10^4 [exact 95 % CI] "
             "(per seed))", "", *md_table(head)]
    refs = ("greedy", "default", "ml", "best safe fixed", "best fixed")
    for e, rows in table.items():
        for ref in refs:
            if ref in rows:
                r = rows[ref]
                label = ref if not ref.startswith("best") else f"{ref} ({r['policy']})"
                costs = f"{r['cost_charged']:.4g} | {r['cost']:.4g}" if charged else f"{r['cost']:.4g}"
                lines.append(f"| {e} | {label} | {costs} | {r['objective']:.4g} | {r['rmse']:.4g} | "
                             f"{r['anees']:.4g} | {r['spent']:.3g} | | | | {_rate(r)} |")
        for g, r in rows.items():
            if g in refs:
                continue
            costs = f"{_ci(r['cost_charged'])} | {_ci(r['cost'])}" if charged else _ci(r["cost"])
            alone = (f" ({r['seeds_below_greedy']} of {len(r['divergent_runs'])} seeds below alone)"
                     if "seeds_below_greedy" in r else "")
            lines.append(f"| {e} | {g} | {costs} | {_ci(r['objective'])} | {_ci(r['rmse'])} | {_ci(r['anees'])} "
                         f"| {r['spent']:.3g} | {diff_ci(r['minus_greedy'][cost])}{alone} "
                         f"| {diff_ci(r['minus_default'][cost])} | {diff_ci(r['minus_greedy']['rmse'])} | {_rate(r)} |")
    return lines


def run_evaluations(run: Run, specs: list[EvalSpec]) -> list:
    """Every chosen study's evaluation jobs in one journal run (longest first), values in ``specs``' order."""
    from adaptfilt.experiments.jobs import load_value, save_value

    order = sorted(range(len(specs)), key=lambda i: -specs[i].order)
    values = run.jobs(evaluate_spec, [(specs[i],) for i in order], [(specs[i].key, specs[i].seed) for i in order],
                      save=save_value, load=load_value, progress=run.progress, desc="beyond: evaluate")
    out: list = [None] * len(specs)
    for i, v in zip(order, values):
        out[i] = v
    return out


def listed_policies(out: Path) -> dict[str, dict]:
    """The policies ``out/manifest.json`` lists (an earlier run's), by path."""
    p = out / "manifest.json"
    files = json.loads(p.read_text())["files"] if p.exists() else []
    return {f["path"]: f for f in files if f["path"].startswith("policies/")}


def same_training(entry: dict | None, command: str, path: Path) -> bool:
    """A listed policy made by ``command`` (its --out aside: the folder may have moved) and unchanged since."""
    if entry is None or not path.is_file():
        return False
    return same_command(str(entry.get("command", "")), command) and sha256(path) == entry["sha256"]
