r"""Study 2, ``sif``: SIF policies and divergence.

On the three Table I costs, policies trained with a penalty on covariance repairs (``adaptive-penalised``)
and policies restricted to the iteration counts that never diverged as fixed values on *selection* runs
(``adaptive-safe``, :func:`select_safe_actions`: seed :data:`SELECTION_SEED`, never the evaluation's runs),
against the default n_it = 10, greedy, the fixed values and the unpenalised policies of the reproduction;
costs with compute charged (the verdict) and uncharged, and the divergent runs on the evaluation runs as a
rate with its exact 95 % interval.
"""
from __future__ import annotations

from adaptfilt.experiment_registry import SIF_EXPERIMENTS
from adaptfilt.experiments.jobs import EvalSpec, TrainSpec, job_key
from adaptfilt.experiments.study import Run, evaluation, groups_md, save_each, study_rows

NAME = "sif"
#: Repair penalty (in units of the transformed cost) of the SIF study.
PENALTY = 20.0
#: Seed of every choice made before an evaluation (the SIF study's safe action set): its trajectories and
#: filter draws are not those of the evaluation (seed 0), so that no set is judged on the runs it was chosen on.
SELECTION_SEED = 1
TITLE = "SIF policies: a repair penalty, a safe action set"


def select_safe_actions(experiment: str, n_runs: int, n_steps: int | None = None, seed: int = SELECTION_SEED) -> dict:
    """The safe action set of ``experiment``: the grid values that, as fixed values, left no run divergent
    (:data:`adaptfilt.metrics.DIVERGED_NEES`) on ``n_runs`` selection runs (``seed``, not the evaluation's).

    Returns ``{"safe": [values...], "divergent_runs": {value: k}, "n_runs", "seed", "experiment"}``.
    ValueError when the experiment's default diverged there (a policy on a subset must hold the default).
    """
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment

    if seed == 0:
        raise ValueError("the selection seed must differ from the evaluation seed 0")
    exp = get_experiment(experiment)
    fixed = exp.baselines(kinds=("fixed",))
    res = evaluate(exp, fixed, n_runs=n_runs, seed=seed, progress=False, n_steps=n_steps)
    diverged = {float(p.value): int(round(res[p.name].divergent_frac * n_runs)) for p in fixed}
    safe = tuple(v for v in exp.grid if diverged[float(v)] == 0)
    if exp.default_value not in safe:
        raise ValueError(f"the default {exp.param_name} = {exp.default_value:g} diverged on the selection runs: "
                         "no safe subset holding it")
    return {"experiment": experiment, "safe": list(safe), "divergent_runs": {f"{v:g}": k for v, k in diverged.items()},
            "n_runs": int(n_runs), "seed": int(seed)}


def prepare(run: Run) -> dict:
    """The safe action set, chosen before anything is trained; one selection serves the three costs: fixed
    counts filter identically in all of them."""
    sc = run.scale
    run.say(f"[beyond] choosing the safe action set on {sc.eval_runs} selection runs (seed {SELECTION_SEED})")
    job = (SIF_EXPERIMENTS[0], sc.eval_runs, sc.n_steps)
    selection = run.jobs(select_safe_actions, [job], [(job_key("select-safe-actions", *job), SELECTION_SEED)],
                         progress=False)[0]
    run.say(f"[beyond] safe action set: {', '.join(f'{v:g}' for v in selection['safe'])}")
    return {"sif-selection": selection}


def policies(run: Run, summary: dict) -> list[TrainSpec]:
    sc, safe = run.scale, summary["sif-selection"]["safe"]
    return [TrainSpec(e, 0.5, sc.episodes, s, str(run.out / rel), repair_penalty=pen, horizon=sc.n_steps,
                      actions=acts)
            for e in SIF_EXPERIMENTS for kind, pen, acts in (("adaptive-penalised", PENALTY, None),
                                                               ("adaptive-safe", 0.0, safe))
            for s in sc.seeds for rel in [f"policies/{e}-{kind}-s{s}.npz"]]


def evaluations(run: Run, summary: dict, trained: list[TrainSpec]) -> list[EvalSpec]:
    """Beside the reproduction's unpenalised policies."""
    return [evaluation(NAME, e, [t.out for t in trained if t.experiment == e] + run.reproduction(e),
                       run.scale, ("default", "greedy")) for e in SIF_EXPERIMENTS]


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    return {NAME: save_each(run, NAME, specs, values, lambda res: study_rows(NAME, res, summary["sif-selection"]))}


def figures(run: Run, summary: dict) -> list[str]:
    return []


def selection_md(summary: dict) -> str:
    """The safe action set's paragraph (before every study's table: it is chosen before anything is trained)."""
    if "sif-selection" not in summary or NAME not in summary:
        return ""
    sel = summary["sif-selection"]
    return (f"**Safe action set, chosen on selection runs** ({sel['n_runs']} runs of seed {sel['seed']}, not "
            f"the evaluation's): divergent runs per fixed {'N_it'}: "
            + ", ".join(f"{v}: {k}" for v, k in sel["divergent_runs"].items())
            + f"; safe set {', '.join(f'{v:g}' for v in sel['safe'])}.\n")


def markdown(summary: dict) -> str:
    return "\n".join(groups_md(TITLE, summary[NAME], charged=True)) + "\n" if NAME in summary else ""
