r"""Study 7, ``particles``: the particle count (chapter 17). The science is
:mod:`adaptfilt.experiments.particles_study` (the evaluation's parts, the reference filter, the floor, the
rows, table and figure); this file is what ``adaptfilt beyond`` runs of it.

Learned counts (``adaptive``, its own budget and horizon: :data:`~adaptfilt.experiments.particles_study.PARTICLE_FULL`)
against fixed counts (in the study's filter and in the reference ``exact.BootstrapParticleFilter``),
KLD-sampling, ESS targets, greedy and (UNGM) the point-mass floor. Per model, one job per part of its
evaluation (the baselines blind to the price are shared by its prices), and one floor job per experiment.
"""
from __future__ import annotations

from adaptfilt.experiments.jobs import EvalSpec, TrainSpec, job_key
from adaptfilt.experiments.study import COMPACT, Run

NAME = "particles"


def _budget(run: Run):
    from adaptfilt.experiments.particles_study import PARTICLE_FULL, PARTICLE_QUICK

    return PARTICLE_QUICK if run.quick else PARTICLE_FULL


def prepare(run: Run) -> dict:
    return {}


def policies(run: Run, summary: dict) -> list[TrainSpec]:
    from adaptfilt.experiment_registry import PARTICLE_EXPERIMENTS

    ps = _budget(run)
    return [TrainSpec(e, 0.5, ps.episodes, s, str(run.out / rel), horizon=ps.n_steps)
            for e in PARTICLE_EXPERIMENTS for s in run.scale.seeds for rel in [f"policies/{e}-adaptive-s{s}.npz"]]


def evaluations(run: Run, summary: dict, trained: list[TrainSpec]) -> list[EvalSpec]:
    from adaptfilt.experiment_registry import PARTICLE_EXPERIMENTS
    from adaptfilt.experiments.particles_study import EVAL_PARTS, evaluate_model_job, floor_job

    ps = _budget(run)
    models: dict[str, list[str]] = {}
    for e in PARTICLE_EXPERIMENTS:
        models.setdefault(e.split("-pf-")[0], []).append(e)
    specs = []
    for es in models.values():  # each model's evaluation in parts, one job each, so that they run side by side
        files = [[t.out for t in trained if t.experiment == e] for e in es]
        specs += [EvalSpec(NAME, "+".join(es), evaluate_model_job, (es, files, ps, 0, (part,)),
                           job_key("particles", part, es, *files, ps.words()), tag=es) for part in EVAL_PARTS]
    specs += [EvalSpec(NAME, e, floor_job, (e, ps), job_key("floor", e, ps.words()), tag="floor")
              for e in PARTICLE_EXPERIMENTS]
    return specs


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    """Each experiment's parts merged, saved and summarised beside its floor."""
    from adaptfilt.experiments.particles_study import merge_model_parts, particle_rows

    by_exp: dict[str, list] = {}
    floors = {}
    for spec, value in zip(specs, values):
        if spec.tag == "floor":
            floors[spec.experiment] = value
            continue
        for e, res in zip(spec.tag, value):
            by_exp.setdefault(e, []).append(res)
    out = {}
    for e, parts in by_exp.items():
        res = merge_model_parts(parts)
        res.config.update(experiment=e)
        run.save(f"particles-{e}", res, drop=COMPACT)
        out[e] = particle_rows(res, floors.get(e))
    return {NAME: out}


def figures(run: Run, summary: dict) -> list[str]:
    from adaptfilt.experiments.particles_study import plot_particle_tradeoff

    return [run.figure(plot_particle_tradeoff(summary[NAME]), "particles-tradeoff.png")] if NAME in summary else []


def markdown(summary: dict) -> str:
    from adaptfilt.experiments.particles_study import particles_md

    return particles_md(summary[NAME]) if NAME in summary else ""
