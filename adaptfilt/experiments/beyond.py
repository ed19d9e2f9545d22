r"""Beyond the paper: ``adaptfilt beyond --out DIR [--quick] [--studies cand,sif,ood,raw,anchor,look,particles]``.

Studies the paper leaves open, each at the seed level (8 training seeds, paired runs), written
into ``DIR/beyond/`` with their own manifest entries (``DIR/beyond/manifest.json``):

1. **Candidate-aware information state** (``cand``): the paper's information state cannot see what
   the exhaustive greedy policy sees (on UNGM the innovation feature is the same for every kappa).
   Policies that also see every grid value's one-step cost (``features=...+cand``,
   :mod:`adaptfilt.features`) are trained with gamma 0.5 (``adaptive-cand``) and gamma 0
   (``myopic-cand``, the control: it should land on greedy) on UNGM-UKF and CTM-UKF, and compared
   with greedy and ML on the cost, the objective, RMSE and ANEES.
2. **SIF policies and divergence** (``sif``): on the three Table I costs, policies trained with a
   penalty on covariance repairs (``adaptive-penalised``) and policies restricted to the iteration
   counts that never diverged as fixed values on *selection* runs (``adaptive-safe``,
   :func:`select_safe_actions`: seed :data:`SELECTION_SEED`, never the evaluation's runs), against
   the default n_it = 10, greedy, the fixed values and the unpenalised policies of the reproduction;
   costs with compute charged (the verdict) and uncharged, and the divergent runs on the evaluation
   runs as a rate with its exact 95 % interval.
3. **Out of distribution and retuning** (``ood``): the reproduction's adaptive UNGM-UKF policies
   (8 seeds) on a 3 x 3 grid of mismatched process and measurement noise
   (:mod:`adaptfilt.experiments.ood`), against default, best fixed in hindsight and greedy; then
   retuned with 50 episodes on each condition; heat maps of the gain over the default.
4. **Training on the untransformed cost** (``raw``): the learners minimise the mean of
   ``log(1 + L)``, while the costs reported are means of ``L``, set by rare large steps. Policies
   trained on ``-L`` itself (``adaptive-raw``, gamma 0.5, the fast mode, ``--cost-transform none``)
   on UNGM-UKF and CTM-UKF, against the reproduction's adaptive policies (trained on ``log(1 + L)``),
   greedy, ML and the default, on the same runs.

7. **The particle count** (``particles``, :mod:`adaptfilt.experiments.particles_study`): learned counts
   against fixed counts (in the study's filter and in the reference ``exact.BootstrapParticleFilter``),
   KLD-sampling, ESS targets, greedy and (UNGM) the point-mass floor.

(Studies 5 and 6, ``anchor`` and ``look``: :mod:`adaptfilt.anchor`, :mod:`adaptfilt.experiments.look`.)

Every training and evaluation is a job of :func:`adaptfilt.experiments.sweep.run_jobs` (local pool or
Dask), recorded as it finishes in ``DIR/beyond/journal.jsonl`` (:mod:`adaptfilt.experiments.journal`):
the same command run again after an interrupt reuses every finished job and gives the same files. A
policy that ``DIR/beyond/manifest.json`` lists with the same training command and sha256 is reused too
(studies run separately with ``--studies`` share the folder). The reproduction's policies are looked
for in ``--data DIR``, ``$ADAPTFILT_DATA``, then the checkout's ``data/`` (:func:`adaptfilt.experiments.artefacts.find_data`).
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from adaptfilt.experiment_registry import SIF_EXPERIMENTS  # re-exported: chapter 13 reads beyond.SIF_EXPERIMENTS
from adaptfilt.experiments.journal import Journal, load_results, save_results
from adaptfilt.files import atomic_savefig, atomic_write, sha256

__all__ = ["BeyondScale", "FULL", "QUICK", "run", "CAND_ALGO", "PENALTY", "SELECTION_SEED", "select_safe_actions",
           "STUDIES", "GROUPS", "study_rows"]

#: The journal of a run's finished jobs, in ``DIR/beyond`` (removed when the run completes).
JOURNAL = "journal.jsonl"

#: The learner of the candidate study (chosen by the measurement reported in REPRODUCTION.md).
CAND_ALGO = "fast"
#: Repair penalty (in units of the transformed cost) of the SIF study.
PENALTY = 20.0
#: The learned groups a study summarises (policy names ``<group>-s<seed>``).
GROUPS = ("adaptive-cand", "myopic-cand", "adaptive-penalised", "adaptive-safe", "adaptive-raw", "adaptive-anchored",
          "adaptive")
#: Seed of every choice made before an evaluation (the SIF study's safe action set): its trajectories and
#: filter draws are not those of the evaluation (seed 0), so that no set is judged on the runs it was chosen on.
SELECTION_SEED = 1
#: Per-run arrays left out of the stored evaluations (about 85 % of each file); the seed-level aggregates,
#: paired differences (bootstrap replicates), usage and per-step curves stay.
COMPACT = ("run_rmse", "run_anees", "run_cost", "choices")
CAND_EXPERIMENTS = {"ungm-ukf": "paper+time+cand", "ctm-ukf": "paper+circ+cand"}
RAW_EXPERIMENTS = ("ungm-ukf", "ctm-ukf")
STUDIES = ("cand", "sif", "ood", "raw", "anchor", "look", "particles")
#: The anchored learner of the ``anchor`` study (:mod:`adaptfilt.anchor`): a residual over greedy's choice
#: (strength, KL weight and shield: the library's defaults, recorded explicitly in each file's command).
ANCHOR = ("greedy", 3.0, 0.01, 1.0)
#: Evaluation seed of the ``anchor`` study: runs that no choice of its recipe saw (the recipe was tuned on
#: selection runs, seed 1, and its shield added after a first check on the evaluation runs of seed 0).
ANCHOR_EVAL_SEED = 2


@dataclass(frozen=True)
class BeyondScale:
    name: str
    episodes: int
    seeds: tuple[int, ...]
    n_steps: int | None
    eval_runs: int
    retune_episodes: int


FULL = BeyondScale("full", 1000, tuple(range(8)), None, 10_000, 50)
QUICK = BeyondScale("quick", 10, (0, 1), 20, 100, 2)


def _train_command(experiment: str, kind: str, gamma: float, seed: int, out: str, scale: BeyondScale,
                   features: str | None, algo: str, repair_penalty: float, actions: tuple | None = None,
                   cost_transform: str = "log1p", anchor: tuple | None = None) -> str:
    """The command recorded in (and by) a training job of :func:`_train_job` (same arguments)."""
    return (f"adaptfilt train {experiment} --algo {algo} --gamma {gamma:g} --episodes {scale.episodes} --seed {seed}"
            + (f" --features {features}" if features else "") + (f" --repair-penalty {repair_penalty:g}" if repair_penalty else "")
            + (f" --horizon {scale.n_steps}" if scale.n_steps else "")
            + (" --actions " + ",".join(f"{v:g}" for v in actions) if actions else "")
            + (f" --cost-transform {cost_transform}" if cost_transform != "log1p" else "")
            + (" --anchor {} --anchor-strength {:g} --anchor-kl {:g} --anchor-shield {:g}".format(*anchor) if anchor else "")
            + f" --out {out}")


def _train_job(experiment: str, kind: str, gamma: float, seed: int, out: str, scale: BeyondScale,
               features: str | None, algo: str, repair_penalty: float, actions: tuple | None = None,
               cost_transform: str = "log1p", anchor: tuple | None = None) -> dict:
    from adaptfilt.trainers import train_policy

    t0, c0 = time.perf_counter(), time.process_time()
    cmd = _train_command(experiment, kind, gamma, seed, out, scale, features, algo, repair_penalty, actions,
                         cost_transform, anchor)
    kw = dict(zip(("anchor", "anchor_strength", "anchor_kl", "anchor_shield"), anchor)) if anchor else {}
    train_policy(experiment, algo, gamma, scale.episodes, seed, features=features, n_steps=scale.n_steps,
                 progress=False, out=out, command=cmd, repair_penalty=repair_penalty, actions=actions,
                 cost_transform=cost_transform, **kw)
    return {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": time.process_time() - c0, "command": cmd}


def _evaluate_job(experiment: str, files: list[str], scale: BeyondScale, keep: tuple[str, ...] | None, seed: int = 0):
    from adaptfilt.evaluation import evaluate, learned_name
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.learned import load_policy

    exp = get_experiment(experiment)
    base = [p for p in exp.baselines() if keep is None or p.name in keep or
            (p.name.startswith("fixed-") and not p.name.startswith("fixed-both-"))]
    pols = base + [load_policy(f, experiment=exp, name=learned_name(f, experiment)) for f in files]
    target = exp if scale.n_steps is None else exp.make_env(n_steps=scale.n_steps)
    res = evaluate(target, pols, n_runs=scale.eval_runs, seed=seed, progress=False)
    res.config.update(experiment=experiment)
    return res


def select_safe_actions(experiment: str, n_runs: int, n_steps: int | None = None, seed: int = SELECTION_SEED) -> dict:
    """The safe action set of ``experiment``: the grid values that, as fixed values, left no run divergent
    (:data:`adaptfilt.evaluation.DIVERGED_NEES`) on ``n_runs`` selection runs (``seed``, not the evaluation's).

    Returns ``{"safe": [values...], "divergent_runs": {value: k}, "n_runs", "seed", "experiment"}``.
    ValueError when the experiment's default diverged there (a policy on a subset must hold the default).
    """
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment

    if seed == 0:
        raise ValueError("the selection seed must differ from the evaluation seed 0")
    exp = get_experiment(experiment)
    fixed = [p for p in exp.baselines() if p.name.startswith("fixed-") and not p.name.startswith("fixed-both-")]
    res = evaluate(exp, fixed, n_runs=n_runs, seed=seed, progress=False, n_steps=n_steps)
    diverged = {float(p.value): int(round(res[p.name].divergent_frac * n_runs)) for p in fixed}
    safe = tuple(v for v in exp.grid if diverged[float(v)] == 0)
    if exp.default_value not in safe:
        raise ValueError(f"the default {exp.param_name} = {exp.default_value:g} diverged on the selection runs: "
                         "no safe subset holding it")
    return {"experiment": experiment, "safe": list(safe), "divergent_runs": {f"{v:g}": k for v, k in diverged.items()},
            "n_runs": int(n_runs), "seed": int(seed)}


def _divergence(res, names: list[str]) -> dict:
    """Divergent runs of ``names`` pooled over them, as a rate with its exact 95 % interval, and the worst one's."""
    from adaptfilt.metrics import rate_ci

    n = res.config["n_runs"]
    k = [int(round(res[x].divergent_frac * n)) for x in names]
    rate, lo, hi = rate_ci(sum(k), n * len(k))
    return {"divergent_runs": k, "n_runs": n, "divergent_rate": rate, "divergent_rate_ci": [lo, hi]}


def _ood_job(condition, files: list[str], scale: BeyondScale, retune_seed: int = 0):
    """One condition: the stored policies, and each retuned there, on the same runs."""
    from adaptfilt.experiments.ood import evaluate_condition, retune
    from adaptfilt.learned import load_policy

    pols = [load_policy(f, experiment="ungm-ukf", name=Path(f).stem.replace("ungm-ukf-", "")) for f in files]
    tuned = [retune(p, "ungm-ukf", condition, episodes=scale.retune_episodes, seed=retune_seed, n_steps=scale.n_steps)
             for p in pols]
    for p, t in zip(pols, tuned):
        t.name = p.name.replace("adaptive-", "retuned-")
    return evaluate_condition("ungm-ukf", condition, pols + tuned, n_runs=scale.eval_runs, n_steps=scale.n_steps)


def run(out_dir: str | Path, quick: bool = False, workers: int | None = None, cluster=None,
        studies: tuple[str, ...] = STUDIES, progress: bool = True, data: str | Path | None = None) -> dict:
    """Run the studies (module docstring) into ``out_dir/beyond``; returns their summaries. ``data``:
    where the reproduction's policies are (default: ``$ADAPTFILT_DATA``, then the checkout's ``data/``)."""
    from adaptfilt._version import __version__
    from adaptfilt.experiments.artefacts import find_data
    from adaptfilt.experiments.ood import CONDITIONS, gain_table
    from adaptfilt.experiments.reproduce import RETRAIN_COST

    scale = QUICK if quick else FULL
    root = Path(out_dir).resolve()
    need = None if quick or not set(studies) & {"sif", "ood", "raw"} else (
        "the sif, ood and raw studies compare with the reproduction's policies: make them with `adaptfilt reproduce "
        f"--out DIR --retrain` ({RETRAIN_COST}) and give --data DIR")
    data = root if quick else find_data(data, required=need)
    out = root / "beyond"
    (out / "policies").mkdir(parents=True, exist_ok=True)
    journal = Journal(out / JOURNAL)
    say = (lambda *a: print(*a, flush=True)) if progress else (lambda *a: None)
    entries: dict[str, dict] = {}
    summary: dict = {"scale": scale.name, "version": __version__}
    cmd = (f"adaptfilt beyond --out {out_dir}" + (" --quick" if quick else "")
           + ("" if set(studies) == set(STUDIES) else f" --studies {','.join(studies)}"))
    jobs, metas = [], []
    if "cand" in studies:
        for e, feats in CAND_EXPERIMENTS.items():
            for kind, g in (("adaptive-cand", 0.5), ("myopic-cand", 0.0)):
                for s in scale.seeds:
                    rel = f"policies/{e}-{kind}-s{s}.npz"
                    jobs.append((e, kind, g, s, str(out / rel), scale, feats, CAND_ALGO, 0.0))
                    metas.append(rel)
    if "sif" in studies:
        # one selection serves the three costs: fixed counts filter identically in all of them
        say(f"[beyond] choosing the safe action set on {scale.eval_runs} selection runs (seed {SELECTION_SEED})")
        sel_job = (SIF_EXPERIMENTS[0], scale.eval_runs, scale.n_steps)
        selection = journal.run(select_safe_actions, [sel_job],
                                [(f"select_safe_actions{sel_job!r}", SELECTION_SEED)],
                                workers=workers, cluster=cluster, progress=False)[0]
        summary["sif-selection"] = selection
        say(f"[beyond] safe action set: {', '.join(f'{v:g}' for v in selection['safe'])}")
        for e in SIF_EXPERIMENTS:
            for kind, pen, acts in (("adaptive-penalised", PENALTY, None), ("adaptive-safe", 0.0, selection["safe"])):
                for s in scale.seeds:
                    rel = f"policies/{e}-{kind}-s{s}.npz"
                    jobs.append((e, kind, 0.5, s, str(out / rel), scale, None, "fast", pen, acts))
                    metas.append(rel)
    if "raw" in studies:
        for e in RAW_EXPERIMENTS:
            for s in scale.seeds:
                rel = f"policies/{e}-adaptive-raw-s{s}.npz"
                jobs.append((e, "adaptive-raw", 0.5, s, str(out / rel), scale, None, "fast", 0.0, None, "none"))
                metas.append(rel)
    if "anchor" in studies:  # on the candidate-aware state: greedy is a function of its inputs
        for e, feats in CAND_EXPERIMENTS.items():
            for s in scale.seeds:
                rel = f"policies/{e}-adaptive-anchored-s{s}.npz"
                jobs.append((e, "adaptive-anchored", 0.5, s, str(out / rel), scale, feats, "fast", 0.0, None, "log1p",
                             ANCHOR))
                metas.append(rel)
    if "particles" in studies:  # the particle count (chapter 14): its own budget and horizon
        from adaptfilt.experiment_registry import PARTICLE_EXPERIMENTS
        from adaptfilt.experiments.particles_study import PARTICLE_FULL, PARTICLE_QUICK

        ps = PARTICLE_QUICK if quick else PARTICLE_FULL
        pscale = BeyondScale(scale.name, ps.episodes, scale.seeds, ps.n_steps, ps.eval_runs, 0)
        for e in PARTICLE_EXPERIMENTS:
            for s in scale.seeds:
                rel = f"policies/{e}-adaptive-s{s}.npz"
                jobs.append((e, "adaptive", 0.5, s, str(out / rel), pscale, None, "fast", 0.0))
                metas.append(rel)
    listed = _listed_policies(out)
    todo = [(j, m) for j, m in zip(jobs, metas) if not _same_training(listed.get(m), _train_command(*j), out / m)]
    keys = [(_train_command(*j), j[3]) for j, _ in todo]
    resumed = journal.count(keys)
    say(f"[beyond] {len(todo) - resumed} policies to train, {resumed} finished by an earlier run ({JOURNAL}), "
        f"{len(jobs) - len(todo)} listed in the manifest")
    times = journal.run(_train_job, [j for j, _ in todo], keys, files=[[out / m] for _, m in todo], workers=workers,
                        cluster=cluster, progress=progress, desc="beyond: train")
    for (_, rel), t in zip(todo, times):
        entries[rel] = t

    # ---- evaluations
    ejobs, names = [], []

    def reproduction(e: str) -> list[str]:
        """The reproduction's adaptive policies of ``e`` (those there are)."""
        paths = [data / f"policies/{e}-adaptive-s{s}.npz" for s in scale.seeds]
        return [str(p) for p in paths if p.exists()]

    if "cand" in studies:
        for e in CAND_EXPERIMENTS:
            files = [str(out / m) for m in metas if m.startswith(f"policies/{e}-") and "cand" in m]
            ejobs.append((e, files, scale, ("default", "ml", "greedy")))
            names.append(("cand", e))
    if "sif" in studies:
        for e in SIF_EXPERIMENTS:
            files = [str(out / m) for m in metas if m.startswith((f"policies/{e}-adaptive-penalised",
                                                                   f"policies/{e}-adaptive-safe"))]
            files += reproduction(e)
            ejobs.append((e, files, scale, ("default", "greedy")))
            names.append(("sif", e))
    if "raw" in studies:  # beside the reproduction's policies, trained on log(1 + L) with the same recipe
        for e in RAW_EXPERIMENTS:
            files = [str(out / m) for m in metas if m.startswith(f"policies/{e}-adaptive-raw")]
            files += reproduction(e)
            ejobs.append((e, files, scale, ("default", "ml", "greedy")))
            names.append(("raw", e))
    if "anchor" in studies:  # beside the candidate-aware policies, on runs no choice of the recipe saw
        for e in CAND_EXPERIMENTS:
            files = [str(out / m) for m in metas if m.startswith(f"policies/{e}-adaptive-anchored")]
            files += [str(p) for p in sorted((out / "policies").glob(f"{e}-adaptive-cand-s*.npz"))]
            ejobs.append((e, files, scale, ("default", "ml", "greedy"), ANCHOR_EVAL_SEED))
            names.append(("anchor", e))
    floors: dict = {}
    particle_results: dict = {}
    if "particles" in studies:  # per model, four jobs; the baselines blind to the price are shared by its prices
        from adaptfilt.experiments.particles_study import EVAL_PARTS, evaluate_model_job, floor_job, merge_model_parts

        models: dict[str, list[str]] = {}
        for e in PARTICLE_EXPERIMENTS:
            models.setdefault(e.split("-pf-")[0], []).append(e)
        # each model's evaluation in parts (EVAL_PARTS), one job each, so that the parts run side by side
        pjobs = [(es, [[str(out / m) for m in metas if m.startswith(f"policies/{e}-adaptive-s")] for e in es], ps, 0,
                  (part,)) for es in models.values() for part in EVAL_PARTS]
        pres = journal.run(evaluate_model_job, pjobs,
                           [(_job_key("particles", j[4][0], j[0], *j[1], j[2]), 0) for j in pjobs],
                           save=lambda folder, rs: (save_results(folder, rs), len(rs)), load=load_results,
                           workers=workers, cluster=cluster, progress=progress, desc="beyond: particle counts")
        by_model: dict = {}
        for (es, *_), rs in zip(pjobs, pres):
            for e, res in zip(es, rs):
                by_model.setdefault(e, []).append(res)
        for e, parts in by_model.items():
            res = merge_model_parts(parts)
            res.config.update(experiment=e)
            particle_results[e] = res
        fjobs = [(e, ps) for e in PARTICLE_EXPERIMENTS]
        floors = dict(zip(PARTICLE_EXPERIMENTS, journal.run(
            floor_job, fjobs, [(f"beyond floor {e} runs={ps.eval_runs} floor={ps.floor_runs} steps={ps.n_steps}", 0)
                               for e, ps in fjobs], workers=workers, cluster=cluster, progress=False)))
    results = journal.run(_evaluate_job, ejobs, [(_job_key("evaluate", study, e, files, scale, keep, *rest), 0)
                                                  for (study, e), (_, files, _, keep, *rest) in zip(names, ejobs)],
                          save=_save_one, load=_load_one, workers=workers, cluster=cluster, progress=progress,
                          desc="beyond: evaluate")
    for (study, e), res in [*zip(names, results), *((("particles", e), r) for e, r in particle_results.items())]:
        d = out / "results" / f"{study}-{e}"
        wall = _take_times(res)
        res.save(d, drop=COMPACT)
        entries.update({f"results/{study}-{e}/{f}": {"command": cmd, "wall_time_s": wall}
                        for f in ("results.json", "results.npz")})
        if study == "particles":
            from adaptfilt.experiments.particles_study import particle_rows

            rows = particle_rows(res, floors.get(e))
        else:
            rows = study_rows(study, res, selection if study == "sif" else None)
        summary.setdefault(study, {})[e] = rows
        if study == "anchor":
            summary["anchor-eval-seed"] = ANCHOR_EVAL_SEED

    if "particles" in summary:
        import matplotlib.pyplot as plt

        from adaptfilt.experiments.particles_study import plot_particle_tradeoff

        (out / "figures").mkdir(parents=True, exist_ok=True)
        fig = plot_particle_tradeoff(summary["particles"])
        atomic_savefig(fig, out / "figures" / "particles-tradeoff.png", dpi=100)
        plt.close(fig)
        entries["figures/particles-tradeoff.png"] = {"command": cmd}

    if "look" in studies:  # after the anchored policies: they are shown beside the references
        from adaptfilt.experiments.look import LOOK, LOOK_QUICK, look_files, look_job, look_specs, look_summary, merge_parts

        plan = LOOK_QUICK if quick else LOOK
        ljobs, lexp = [], []
        for e, (runs, grid_hs) in plan.items():
            files = look_files(data, out, e, scale.seeds)
            for spec in look_specs(e, grid_hs, quick):
                ljobs.append((e, spec, files if spec == ("base",) else [], runs, scale.n_steps))
                lexp.append(e)
        # the longest parts first (a rollout's time grows with H x S)
        order = sorted(range(len(ljobs)), key=lambda i: -np.prod(ljobs[i][1][1:] or (0,)))
        parts = journal.run(look_job, [ljobs[i] for i in order],
                            [(_job_key("look", *ljobs[i][:2], ljobs[i][2], *ljobs[i][3:]), 0) for i in order],
                            save=_save_one, load=_load_one, workers=workers, cluster=cluster, progress=progress,
                            desc="beyond: look-ahead references")
        by_exp: dict[str, list] = {}
        for i, res in sorted(zip(order, parts)):
            by_exp.setdefault(lexp[i], []).append(res)
        summary["look"] = {}
        for e, ps in by_exp.items():
            res = merge_parts(ps)
            d = out / "results" / f"look-{e}"
            wall = _take_times(res)
            res.save(d, drop=COMPACT)
            entries.update({f"results/look-{e}/{f}": {"command": cmd, "wall_time_s": wall}
                            for f in ("results.json", "results.npz")})
            summary["look"][e] = look_summary(res)
        _look_figure(summary["look"], out / "figures")
        entries["figures/look-gain.png"] = {"command": cmd}

    if "ood" in studies:
        files = reproduction("ungm-ukf")
        if files:
            conds = CONDITIONS if not quick else CONDITIONS[:2]
            ood_res = journal.run(_ood_job, [(c, files, scale) for c in conds],
                                  [(_job_key("ood", c.key, "ungm-ukf", files, scale), 0) for c in conds],
                                  save=_save_one, load=_load_one, workers=workers, cluster=cluster, progress=progress,
                                  desc="beyond: out of distribution")
            tables = {}
            for c, res in zip(conds, ood_res):
                d = out / "results" / f"ood-{c.key}"
                # summaries only: nine conditions x 32 policies of per-run arrays would triple data/;
                # the paired gains are computed here, before saving, and kept in summary.json
                wall = _take_times(res)
                res.save(d, arrays=False)
                entries[f"results/ood-{c.key}/results.json"] = {"command": cmd, "wall_time_s": wall}
                tables[c.key] = res
            groups = {"learned": [n for n in ood_res[0].names if n.startswith("adaptive-s")],
                      "retuned": [n for n in ood_res[0].names if n.startswith("retuned-s")]}
            summary["ood"] = {m: gain_table(tables, groups, m) for m in ("objective", "rmse")}
            _ood_figures(summary["ood"], out / "figures")
            for f in (out / "figures").glob("*.png"):
                entries[str(f.relative_to(out))] = {"command": cmd}

    # studies run separately (--studies) add to what an earlier run of the same scale wrote
    old_summary, old_files = {}, {}
    if (out / "summary.json").exists() and (out / "manifest.json").exists():
        prev = json.loads((out / "summary.json").read_text())
        if prev.get("scale") == scale.name:
            old_summary = prev
            old_files = {f["path"]: f for f in json.loads((out / "manifest.json").read_text())["files"]}
    summary = {**{k: v for k, v in old_summary.items() if k not in summary}, **summary}
    atomic_write(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    entries["summary.json"] = {"command": cmd}
    files = {rel: f for rel, f in old_files.items() if rel not in entries and (out / rel).exists()}
    for rel, e in entries.items():
        files[rel] = {"path": rel, "sha256": sha256(out / rel), "command": e.get("command"),
                      "seed": 0, "version": __version__,
                      "wall_time_s": e.get("wall_time_s"), "cpu_time_s": e.get("cpu_time_s")}
    atomic_write(out / "manifest.json", json.dumps({"scale": scale.name, "files": [files[k] for k in sorted(files)]},
                                                   indent=1) + "\n")
    journal.finish()
    return summary


def study_rows(study: str, res, selection: dict | None = None) -> dict:
    """A study's summary rows for one experiment's evaluation ``res``: each learned group of
    :data:`GROUPS` (IQM over seeds with two-level intervals, differences to greedy and the default,
    divergence, compute, seeds below greedy alone) and the references (greedy, default, ML, the
    cheapest constant: among the ``selection``'s safe set in the SIF study)."""
    from adaptfilt.seed_stats import aggregate, difference, seed_groups

    rows = {}
    # exact group names: "adaptive-s3" is a seed of "adaptive", "adaptive-safe-s3" is not (a prefix test
    # once merged the safe policies into the reproduction's "adaptive" row of the SIF study)
    seeds = seed_groups(res.names)
    groups = {g: seeds.get(g, []) for g in GROUPS}
    metrics = ("cost", "cost_charged", "objective", "rmse", "anees")
    for g, members in groups.items():
        if not members:
            continue
        rows[g] = {m: aggregate(res, members, m).to_dict() for m in metrics}
        for ref in ("greedy", "default"):
            rows[g][f"minus_{ref}"] = {m: list(difference(res, members, [ref], m)["iqm"]) for m in metrics}
        rows[g]["divergent_frac_max"] = float(max(res[n].divergent_frac for n in members))
        rows[g].update(_divergence(res, members))
        rows[g]["spent"] = float(np.mean([res[n].spent for n in members]))
        # each seed alone: is its own paired run-level interval of the cost difference below 0?
        c = "cost_charged" if study == "sif" else "cost"
        rows[g]["seeds_below_greedy"] = int(sum(res.paired_difference(n, "greedy", c)[2] < 0 for n in members))
    if groups["adaptive-raw"] and groups["adaptive"]:  # the transform's effect, paired
        rows["adaptive-raw"]["minus_adaptive"] = {m: list(difference(res, groups["adaptive-raw"],
                                                                     groups["adaptive"], m)["iqm"])
                                                  for m in ("cost", "objective", "rmse", "anees")}
    # what a constant can do: the cheapest fixed value, among the safe ones where the study chose a safe set
    # (on its selection runs: a value that happened not to diverge on these runs was not chosen on them)
    fixed = [n for n in res.names if n.startswith("fixed-") and not n.startswith("fixed-both-")]
    if study == "sif":
        fixed = [n for n in fixed if any(n == f"fixed-{res.config['param_name']}={v:g}" for v in selection["safe"])]
    label = "best safe fixed" if study == "sif" else "best fixed"
    best = min(fixed, key=lambda n: res[n].cost_charged) if fixed else None
    for ref, name in (("greedy", "greedy"), ("default", "default"), ("ml", "ml"), (label, best)):
        if name in res:
            p = res[name]
            rows[ref] = {"cost": p.cost, "cost_charged": p.cost_charged, "objective": p.objective, "rmse": p.rmse,
                         "anees": p.anees, "divergent_frac": p.divergent_frac, "policy": name, "spent": p.spent,
                         **_divergence(res, [name])}
    return rows


def _look_figure(look: dict, fig_dir: Path) -> None:
    import matplotlib.pyplot as plt

    from adaptfilt.experiments.look import plot_look_gain

    fig_dir.mkdir(parents=True, exist_ok=True)
    fig = plot_look_gain(look)
    atomic_savefig(fig, fig_dir / "look-gain.png", dpi=100)
    plt.close(fig)


def _take_times(res) -> float:
    """The evaluation's wall time, moved from its policies to the manifest: the same command then
    writes byte-identical results, resumed or not."""
    wall = sum(p.wall_time_s for p in res.policies.values())
    for p in res.policies.values():
        p.wall_time_s = 0.0
    return round(wall, 2)


def _listed_policies(out: Path) -> dict[str, dict]:
    """The policies ``out/manifest.json`` lists (an earlier run's), by path."""
    p = out / "manifest.json"
    files = json.loads(p.read_text())["files"] if p.exists() else []
    return {f["path"]: f for f in files if f["path"].startswith("policies/")}


def _same_training(entry: dict | None, command: str, path: Path) -> bool:
    """A listed policy made by ``command`` (its --out aside: the folder may have moved) and unchanged since."""
    if entry is None or not path.is_file():
        return False
    recorded = str(entry.get("command", "")).rsplit(" --out ", 1)[0]
    return recorded == command.rsplit(" --out ", 1)[0] and sha256(path) == entry["sha256"]


def _job_key(kind: str, *parts) -> str:
    """What identifies an evaluation job for the journal; policy files by their name and contents."""
    def word(x) -> str:
        if isinstance(x, BeyondScale):
            return f"runs={x.eval_runs} steps={x.n_steps} episodes={x.episodes} retune={x.retune_episodes}"
        if isinstance(x, (list, tuple)):
            return "[" + ",".join(f"{Path(f).name}@{sha256(f)[:16]}" if str(f).endswith(".npz") else str(f)
                                  for f in x) + "]"
        return str(x)

    return f"beyond {kind} " + " ".join(word(x) for x in parts)


def _save_one(folder: Path, res) -> tuple[list[Path], int]:
    return save_results(folder, [res]), 1


def _load_one(folder: Path, n: int):
    return load_results(folder, n)[0]


def _ood_figures(tables: dict, fig_dir: Path) -> None:
    import matplotlib.pyplot as plt

    from adaptfilt.experiments.ood import plot_gain

    fig_dir.mkdir(parents=True, exist_ok=True)
    for metric, table in tables.items():
        fig, axes = plt.subplots(1, 4, figsize=(17, 3.8), layout="constrained")
        for ax, col in zip(axes, ("greedy", "best fixed", "learned", "retuned")):
            plot_gain(table, col, metric, ax=ax, title=f"{col}: {metric} gain over default")
        atomic_savefig(fig, fig_dir / f"ood-gain-{metric}.png", dpi=100)
        plt.close(fig)


def summary_md(summary: dict, studies: tuple[str, ...] = STUDIES) -> str:
    """The studies' tables for REPRODUCTION.md (IQM over seeds [seed-level CI], differences to greedy)."""
    summary = {k: v for k, v in summary.items() if k not in STUDIES or k in studies}
    f = lambda a: f"{a['iqm']:.4g} [{a['iqm_ci'][0]:.4g}, {a['iqm_ci'][1]:.4g}]"  # noqa: E731
    d = lambda x: f"{x[0]:+.4g} [{x[1]:+.4g}, {x[2]:+.4g}]"  # noqa: E731
    parts = []
    if "sif-selection" in summary and "sif" in summary:
        sel = summary["sif-selection"]
        parts.append(f"**Safe action set, chosen on selection runs** ({sel['n_runs']} runs of seed {sel['seed']}, not "
                     f"the evaluation's): divergent runs per fixed {'N_it'}: "
                     + ", ".join(f"{v}: {k}" for v, k in sel["divergent_runs"].items())
                     + f"; safe set {', '.join(f'{v:g}' for v in sel['safe'])}.\n")
    rate = lambda r: (f"{1e4 * r['divergent_rate']:.3g} [{1e4 * r['divergent_rate_ci'][0]:.2g}, "  # noqa: E731
                      f"{1e4 * r['divergent_rate_ci'][1]:.2g}]" + (f" ({', '.join(map(str, r['divergent_runs']))})"
                                                                    if len(r["divergent_runs"]) > 1 else ""))
    for study, title in (("cand", "Candidate-aware information state"), ("sif", "SIF policies: a repair penalty, a safe action set"),
                         ("raw", "Training on the untransformed cost (adaptive-raw) against log(1 + L) (adaptive)"),
                         ("anchor", "Learned policies anchored on greedy (adaptive-anchored), evaluated on runs of seed "
                          f"{summary.get('anchor-eval-seed', ANCHOR_EVAL_SEED)}")):
        if study not in summary:
            continue
        charged = study == "sif"
        cost = "cost_charged" if charged else "cost"
        lines = [f"**{title}** (IQM over seeds [two-level 95 % CI]; differences to greedy and the default; "
                 + ("cost with compute charged, the verdict, and the paper's uncharged cost; " if charged else "")
                 + "compute per step in SIF iterations or UKF updates; divergent runs per 10^4 [exact 95 % CI] "
                 "(per seed))", "",
                 "| experiment | policy | " + ("cost charged | cost uncharged" if charged else "cost") + " | log(1+L) | "
                 "RMSE | ANEES | compute per step | cost - greedy | cost - default | RMSE - greedy | divergent runs |",
                 "|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if charged else "")]
        refs = ("greedy", "default", "ml", "best safe fixed", "best fixed")
        for e, rows in summary[study].items():
            for ref in refs:
                if ref in rows:
                    r = rows[ref]
                    label = ref if not ref.startswith("best") else f"{ref} ({r['policy']})"
                    costs = f"{r['cost_charged']:.4g} | {r['cost']:.4g}" if charged else f"{r['cost']:.4g}"
                    lines.append(f"| {e} | {label} | {costs} | {r['objective']:.4g} | {r['rmse']:.4g} | "
                                 f"{r['anees']:.4g} | {r['spent']:.3g} | | | | {rate(r)} |")
            for g, r in rows.items():
                if g in refs:
                    continue
                costs = f"{f(r['cost_charged'])} | {f(r['cost'])}" if charged else f(r["cost"])
                alone = (f" ({r['seeds_below_greedy']} of {len(r['divergent_runs'])} seeds below alone)"
                         if "seeds_below_greedy" in r else "")
                lines.append(f"| {e} | {g} | {costs} | {f(r['objective'])} | {f(r['rmse'])} | {f(r['anees'])} "
                             f"| {r['spent']:.3g} | {d(r['minus_greedy'][cost])}{alone} | {d(r['minus_default'][cost])} "
                             f"| {d(r['minus_greedy']['rmse'])} | {rate(r)} |")
        paired = [(e, rows["adaptive-raw"]["minus_adaptive"]) for e, rows in summary[study].items()
                  if "minus_adaptive" in rows.get("adaptive-raw", {})] if study == "raw" else []
        if paired:
            lines += ["", "| experiment | adaptive-raw - adaptive, IQM [seed-level 95 % CI] | cost | log(1+L) | RMSE | ANEES |",
                      "|---|---|---|---|---|---|"]
            lines += [f"| {e} | | " + " | ".join(d(x[m]) for m in ("cost", "objective", "rmse", "anees")) + " |"
                      for e, x in paired]
        parts.append("\n".join(lines) + "\n")
    if "particles" in summary:
        from adaptfilt.experiments.particles_study import particles_md

        parts.append(particles_md(summary["particles"]))
    if "look" in summary:
        from adaptfilt.experiments.look import look_md

        parts.append(look_md(summary["look"]))
    if "ood" in summary:
        lines = ["**Out of distribution** (UNGM-UKF; gain over the default in mean log(1+L), positive is better; "
                 "learned and retuned: IQM over seeds [CI])", "",
                 "| truth | greedy | best fixed (in hindsight) | learned | retuned (50 episodes) |", "|---|---|---|---|---|"]
        for key, row in summary["ood"]["objective"].items():
            cells = []
            for col in ("greedy", "best fixed", "learned", "retuned"):
                c = row.get(col)
                cells.append("" if c is None else f"{c['gain']:+.3g} [{c['ci'][0]:+.3g}, {c['ci'][1]:+.3g}]"
                             + (f" ({c['policy']})" if col == "best fixed" else ""))
            lines.append(f"| {key} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines) + "\n")
    return "\n".join(parts)
