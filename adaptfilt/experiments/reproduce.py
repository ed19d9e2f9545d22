r"""Reproduce the paper at the seed level: ``adaptfilt reproduce --out DIR [--scale quick|medium|full] [--retrain] [--faithful]``.

:func:`reproduce` writes into ``DIR`` exactly the layout of the committed
``data/`` folder (which :mod:`adaptfilt.experiments.artefacts` reads for the course)::

    DIR/manifest.json                         every file: sha256, command, seed, version, wall/CPU time
    DIR/policies/{experiment}-{kind}-s{seed}.npz
    DIR/results/{experiment}/                 Results.save + summary.json + summary.md
    DIR/results/ungm-floor.json               point-mass (Bayes) RMSE floor on UNGM
    DIR/results/ctm-reconciliation.json       the CTM RMSE tension
    DIR/results/table1.json, table1.md        Table I at the seed level, beside the paper's
    DIR/results/claims.json                   C1-C6, every comparison with its seed-level CI and verdict
    DIR/figures/*.png                         the paper's Figures 1-6 with per-seed points, choices
    DIR/report-tables.md                      every table REPRODUCTION.md embeds
    DIR/timings.json                          wall and CPU time per stage and per job

Learned policies (``kind``):

* ``adaptive`` (gamma = 0.5) and ``myopic`` (gamma = 0), every experiment,
  :data:`SEEDS` training seeds each, trained by the fast mode
  (:mod:`adaptfilt.trainers`, ``--algo fast``);
* ``adaptive-faithful``, on UNGM-UKF and CTM-UKF, the same seeds trained by
  Algorithm 2 as printed (``--algo faithful``): the reference the fast mode is
  measured against. About 11 CPU-minutes each, so trained only with
  ``faithful=True`` (``--faithful``) and otherwise reused from ``data/`` when
  their file records the expected command.

Stages (wall and CPU time of each recorded): **train** (one job per policy),
**evaluate** (per experiment, every baseline and learned policy on the same
``M`` runs; split into jobs of a few policies that are merged, which is exact:
an evaluation's trajectories, filter draws and bootstrap resamples depend on
its seed only), **floor** and **reconcile** (:mod:`adaptfilt.experiments.references`),
**report** (:mod:`adaptfilt.experiments.claims`, :mod:`adaptfilt.experiments.report`).
Jobs run on :func:`adaptfilt.experiments.sweep.run_jobs`: a local process pool
by default, a Dask cluster with ``cluster=``; the files do not depend on which.

Stopping and resuming: every job writes its files atomically and is recorded, as it finishes, in
``DIR/journal.jsonl`` (:mod:`adaptfilt.experiments.journal`); the same command run again into the
same ``DIR`` takes every recorded job whose command, seed, version and files match from there (the
final files are byte-identical to an uninterrupted run's) and runs the rest. A completed run removes
the journal.

The stored artefacts are looked for in ``data`` (``--data DIR``), ``$ADAPTFILT_DATA``, then the
checkout's ``data/`` (:func:`adaptfilt.experiments.artefacts.find_data`); a full-scale run without ``retrain``
needs them and says so rather than retraining everything.
Artefacts already in ``data/`` whose sha256 matches the manifest are reused
unless ``retrain``; the paper-faithful policies are reused even then (``faithful``
trains the ones ``data/`` lacks). Scales (:data:`SCALES`): ``full`` is the paper's
protocol and makes ``data/``; ``medium`` keeps the 8 seeds and every policy but halves
the training and evaluates on M = 2000 runs, to check every verdict in a quarter of the time
(``data/timings.json`` and ``data/medium/timings.json`` record both); ``quick`` runs the same
pipeline at toy scale.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from adaptfilt.experiments.claims import PAPER_TABLE1, SIF_EXPERIMENTS, claims, table1  # noqa: F401 (re-exported)
from adaptfilt.experiments.journal import Journal, load_results, save_results
from adaptfilt.experiments.references import ctm_reconciliation, ungm_floor  # noqa: F401 (old commands use these names)
from adaptfilt.experiments.report import embed_report_tables, figures, report_tables, table1_md
from adaptfilt.files import atomic_write, sha256

__all__ = ["reproduce", "Scale", "FULL", "QUICK", "SEEDS", "KINDS", "FAITHFUL", "policy_command", "sha256",
           "ungm_floor", "ctm_reconciliation", "embed_report_tables"]

#: Training seeds of every learned policy.
SEEDS = tuple(range(8))
#: Evaluation seed (trajectories, filter draws, bootstrap resamples).
SEED = 0
#: Learned kinds trained by the fast mode on every experiment: kind -> gamma.
KINDS = {"adaptive": 0.5, "myopic": 0.0}
#: Learned kinds trained paper-faithfully: kind -> (gamma, experiments).
FAITHFUL = {"adaptive-faithful": (0.5, ("ungm-ukf", "ctm-ukf"))}
ALGO = {"adaptive": "fast", "myopic": "fast", "adaptive-faithful": "faithful"}
GAMMA = {**KINDS, **{k: g for k, (g, _) in FAITHFUL.items()}}


@dataclass(frozen=True)
class Scale:
    """How big a reproduction is."""

    name: str
    episodes: int
    seeds: tuple[int, ...]
    train_steps: int | None  # None: the model's horizon
    eval_runs: int
    eval_steps: int | None
    floor_runs: int
    floor_steps: int | None
    recon_runs: int
    recon_steps: int | None
    eval_chunk: int = 4      # learned policies per evaluation job
    faithful_episodes: int | None = None  # the paper-faithful policies' episodes (None: ``episodes``)


#: The paper's protocol: M = 10^4 paired runs, 1000 training episodes per policy (about 78 min on 2 cores).
FULL = Scale("full", episodes=1000, seeds=SEEDS, train_steps=None, eval_runs=10_000, eval_steps=None,
             floor_runs=2000, floor_steps=None, recon_runs=2000, recon_steps=None)
#: Every learned policy at 8 seeds in a quarter of the full scale's time: half the training episodes,
#: M = 2000 paired runs; the paper-faithful policies of ``data/`` (1000 episodes) are reused.
MEDIUM = Scale("medium", episodes=500, seeds=SEEDS, train_steps=None, eval_runs=2000, eval_steps=None,
               floor_runs=500, floor_steps=None, recon_runs=500, recon_steps=None, faithful_episodes=1000)
#: The same pipeline at toy scale (about a minute): for tests.
QUICK = Scale("quick", episodes=20, seeds=(0, 1), train_steps=25, eval_runs=200, eval_steps=30,
              floor_runs=100, floor_steps=60, recon_runs=200, recon_steps=40)
SCALES = {s.name: s for s in (QUICK, MEDIUM, FULL)}
#: The journal of a run's finished jobs, in its output folder (removed when the run completes).
JOURNAL = "journal.jsonl"
#: What --retrain costs at full scale, for the message that asks for it (outside a checkout, where
#: data/timings.json is not there to read; tests/test_quoted_times.py holds it to that record).
RETRAIN_COST = "about 78 minutes on 2 cores"


def policy_rel(experiment: str, kind: str, seed: int) -> str:
    return f"policies/{experiment}-{kind}-s{seed}.npz"


def _episodes(kind: str, scale: Scale) -> int:
    return scale.faithful_episodes if ALGO[kind] == "faithful" and scale.faithful_episodes else scale.episodes


def policy_command(experiment: str, kind: str, seed: int, scale: Scale = FULL, prefix: str = "data") -> str:
    """The one command that makes ``policies/{experiment}-{kind}-s{seed}.npz``."""
    steps = "" if scale.train_steps is None else f" --horizon {scale.train_steps}"
    return (f"adaptfilt train {experiment} --algo {ALGO[kind]} --gamma {GAMMA[kind]:g} --episodes {_episodes(kind, scale)} "
            f"--seed {seed}{steps} --out {prefix}/{policy_rel(experiment, kind, seed)}")


def evaluate_command(experiment: str, policy_rels: list[str], scale: Scale = FULL, prefix: str = "data") -> str:
    steps = "" if scale.eval_steps is None else f" --horizon {scale.eval_steps}"
    pol = "".join(f" --policy {prefix}/{p}" for p in policy_rels)
    return (f"adaptfilt evaluate {experiment} --runs {scale.eval_runs} --seed {SEED}{steps} "
            f"--out {prefix}/results/{experiment}{pol}")


# ------------------------------------------------------------------ jobs (module level: they run in workers)
def _train_job(experiment: str, kind: str, seed: int, out: str, scale: Scale) -> dict:
    from adaptfilt.trainers import train_policy

    t0, c0 = time.perf_counter(), time.process_time()
    train_policy(experiment, ALGO[kind], GAMMA[kind], _episodes(kind, scale), seed, n_steps=scale.train_steps,
                 progress=False, out=out, command=policy_command(experiment, kind, seed, scale))
    return {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": time.process_time() - c0}


def _evaluate_job(experiments: tuple[str, ...], baselines: list[str], policy_files: list[str], scale: Scale):
    """Evaluate the named baselines and the policy files on the experiment's runs (a part of one
    evaluation: every part simulates the same runs and resamples them the same way); one part per
    experiment. Several experiments differ in their cost only (the SIF ones): they share the
    rollouts of their baselines (:func:`adaptfilt.evaluation.evaluate_costs`)."""
    from adaptfilt.evaluation import evaluate, evaluate_costs, learned_name
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.learned import load_policy

    t0, c0 = time.perf_counter(), time.process_time()
    exp = get_experiment(experiments[0])
    by_name = {p.name: p for p in exp.baselines()}
    policies = [by_name[n] for n in baselines]
    policies += [load_policy(p, experiment=exp, name=learned_name(p, exp.name)) for p in policy_files]
    kw = dict(n_runs=scale.eval_runs, seed=SEED, progress=False, n_steps=scale.eval_steps)
    parts = (list(evaluate_costs(list(experiments), policies, **kw).values()) if len(experiments) > 1
             else [evaluate(exp, policies, **kw)])
    walls = {}
    for res in parts:
        for p in res.policies.values():  # per-run arrays in float32: data/ stays small; summaries are computed
            for k in ("run_rmse", "run_anees", "run_cost"):
                setattr(p, k, np.asarray(getattr(p, k), dtype=np.float32))
            # times go to timings.json, not into the results: the same command gives byte-identical files
            walls[p.name], p.wall_time_s = max(walls.get(p.name, 0.0), p.wall_time_s), 0.0
    return parts, {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": time.process_time() - c0, "policies": walls}


def _cheap_and_heavy(experiment: str) -> tuple[list[str], list[str]]:
    """The experiment's baselines: the cheap ones, and greedy and ML (they try every grid value)."""
    from adaptfilt.experiment_registry import get_experiment

    names = [p.name for p in get_experiment(experiment).baselines()]
    heavy = [n for n in names if n in ("greedy", "ml")]
    return [n for n in names if n not in heavy], heavy


def _evaluation_jobs(experiment: str, policy_paths: list[str], scale: Scale, cheap: bool = True) -> list[tuple]:
    """An experiment's evaluation split into jobs: the cheap baselines together (unless ``cheap``
    is False: a job shared with other experiments has them), greedy (and ML) alone, learned
    policies ``eval_chunk`` at a time."""
    light, heavy = _cheap_and_heavy(experiment)
    jobs = ([((experiment,), light, [], scale)] if cheap else []) + [((experiment,), [n], [], scale) for n in heavy]
    for i in range(0, len(policy_paths), scale.eval_chunk):
        jobs.append(((experiment,), [], policy_paths[i:i + scale.eval_chunk], scale))
    return jobs


def _merge(parts: list, experiment: str, command: str):
    """One Results from the parts of one evaluation, in the experiment's order of policies."""
    from adaptfilt.experiment_registry import get_experiment

    first = parts[0]
    for other in parts[1:]:
        same = {k: v for k, v in other.config.items() if k not in ("policies", "command")}
        mine = {k: v for k, v in first.config.items() if k not in ("policies", "command")}
        if same != mine:
            raise RuntimeError(f"parts of the {experiment} evaluation disagree on their configuration")
        first.policies.update(other.policies)
    first.config["policies"] = list(first.policies)
    first.config["command"] = command
    exp = get_experiment(experiment)
    first.config.update(experiment=exp.name, description=exp.description)
    return first


# ------------------------------------------------------------------ driver
def _load_manifest(d: Path) -> dict:
    p = d / "manifest.json"
    return json.loads(p.read_text()) if p.exists() else {"files": []}


def _reusable(data: Path, rel: str, man: dict) -> dict | None:
    """The manifest entry of ``data/rel`` if the file exists and matches its sha256."""
    for e in man.get("files", []):
        if e["path"] == rel and (data / rel).exists() and sha256(data / rel) == e["sha256"]:
            return e
    return None


def reproduce(out_dir: str | Path, quick: bool = False, retrain: bool = False, progress: bool = True,
              workers: int | None = None, cluster=None, experiments: tuple[str, ...] | None = None,
              faithful: bool = False, jobs: int | None = None, scale: str | Scale | None = None,
              data: str | Path | None = None) -> dict:
    """Train + evaluate + floor + reconciliation + figures + tables into ``out_dir`` (module docstring).

    ``scale``: ``"full"`` (default), ``"medium"`` or ``"quick"`` (:data:`SCALES`; ``quick=True``
    is ``"quick"``). Only the full scale reuses the fast-mode policies and results of ``data/``;
    every scale but ``quick`` reuses its paper-faithful policies.
    ``workers``: local processes (default: every core, or ``$ADAPTFILT_JOBS``; ``jobs`` is
    its old name); ``cluster``: a Dask scheduler address, ``"local"`` or a ``distributed.Client``.
    ``data``: the stored artefacts to reuse (default: ``$ADAPTFILT_DATA``, then the checkout's ``data/``).
    Returns ``{"timings", "table1", "claims", "figures"}``.
    """
    from adaptfilt._version import __version__
    from adaptfilt.experiments.artefacts import find_data
    from adaptfilt.results import Results
    from adaptfilt.experiment_registry import EXPERIMENTS
    from adaptfilt.experiments.sweep import default_workers
    from adaptfilt.learned import read_npz

    if quick and scale not in (None, "quick", QUICK):
        raise ValueError(f"quick=True and scale={scale!r}: give one of them")
    if not isinstance(scale, Scale):
        if (scale or "full") not in SCALES:
            raise ValueError(f"unknown scale {scale!r}; one of {', '.join(SCALES)}")
        scale = QUICK if quick else SCALES[scale or "full"]
    quick, full = scale is QUICK, scale is FULL
    workers = workers if workers is not None else (jobs if jobs is not None else default_workers())
    out = Path(out_dir).resolve()
    exps = tuple(EXPERIMENTS) if experiments is None else tuple(experiments)
    need = None if (retrain or not full) else (f"or add --retrain to train the {len(exps) * len(KINDS) * len(scale.seeds)} "
                                               f"fast-mode policies and evaluate everything here ({RETRAIN_COST})")
    found = find_data(data, required=need)
    data = found.resolve() if found is not None else out
    same = found is not None and out == data
    if same and not full:
        raise ValueError(f"--scale {scale.name} into {out} would overwrite the full-scale reproduction there; "
                         "give another --out")
    for sub in ("policies", "results"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    # --retrain retrains the fast-mode policies; the paper-faithful ones (hours) are still reused
    kept = {"files": []} if (quick or found is None) else _load_manifest(data)
    dman = {"files": []} if (retrain or not full) else kept
    entries: dict[str, dict] = {}
    timings: dict[str, dict] = {}
    job_times: dict[str, dict] = {}
    say = (lambda *a: print(*a, flush=True)) if progress else (lambda *a: None)
    engine = f"cluster {cluster}" if cluster is not None else f"{workers} local workers"
    say(f"reproduce ({scale.name} scale, {len(scale.seeds)} seeds) into {out}; {engine}; retrain={retrain}; "
        + (f"stored artefacts: {data}" if found is not None else "no stored artefacts"))
    journal = Journal(out / JOURNAL)
    T0 = time.perf_counter()

    def reuse(rel: str, man: dict | None = None) -> bool:
        e = _reusable(data, rel, dman if man is None else man)
        if e is None:
            return False
        if not same:
            (out / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(data / rel, out / rel)
        entries[rel] = dict(e)
        return True

    def adopt(rel: str, command: str, keep: bool = False) -> bool:
        """A policy file in data/ that no manifest lists yet, made by the expected command."""
        if quick or found is None or (retrain and not keep) or not (data / rel).exists():
            return False
        meta = read_npz(data / rel)[1]
        recorded = " ".join(w for w in str(meta.get("command", "")).split() if w != "--no-progress")
        if recorded != command:
            return False
        if not same:
            shutil.copy2(data / rel, out / rel)
        # the training seed is the file's own, not the evaluation seed; its time was not recorded
        entries[rel] = {"command": command, "seed": int(meta["seed"]), "wall_time_s": None, "cpu_time_s": None}
        return True

    # ---- 1. train
    t0 = time.perf_counter()
    todo, learned, n_reused = [], {e: [] for e in exps}, 0
    wanted = [(e, k) for e in exps for k in KINDS] + [(e, k) for k, (_, es) in FAITHFUL.items() for e in es if e in exps]
    for e, k in wanted:
        for s in scale.seeds:
            rel = policy_rel(e, k, s)
            cmd = policy_command(e, k, s, scale)
            keep = k in FAITHFUL  # hours each: reused even by --retrain
            if reuse(rel, kept if keep else None) or adopt(rel, cmd, keep):
                n_reused += 1
                learned[e].append(rel)
            elif k in KINDS or faithful:
                todo.append((e, k, s, str(out / rel), scale))
                learned[e].append(rel)
    # the slow ones first, so that they do not finish last on a worker of their own
    todo.sort(key=lambda a: (ALGO[a[1]] != "faithful", a[0] not in SIF_EXPERIMENTS))
    keys = [(policy_command(e, k, s, scale), s) for e, k, s, _, _ in todo]
    resumed = journal.count(keys)
    say(f"[train] {len(todo) - resumed} policies to train, {resumed} finished by an earlier run ({JOURNAL}), "
        f"{n_reused} reused")
    res_jobs = journal.run(_train_job, todo, keys, files=[[a[3]] for a in todo], workers=workers, cluster=cluster,
                           progress=progress, desc="train")
    for (e, k, s, _, _), r in zip(todo, res_jobs):
        rel = policy_rel(e, k, s)
        entries[rel] = {"command": policy_command(e, k, s, scale), "seed": s, **r}
        job_times[rel] = r
    timings["train"] = {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": sum(r["cpu_time_s"] for r in res_jobs),
                        "note": f"{len(todo) - resumed} trained ({scale.episodes} episodes each), {resumed} by an earlier "
                                f"run (journal), {n_reused} reused; {engine}"}

    # ---- 2. evaluate
    t0 = time.perf_counter()
    files = ("results.json", "results.npz", "summary.json", "summary.md")
    def stale(e: str) -> bool:
        """Evaluate again unless data/ holds this experiment's results for exactly these policies."""
        if retrain or not full or any(rel in job_times for rel in learned[e]):
            return True
        p = data / f"results/{e}/results.json"
        if not p.exists() or set(json.loads(p.read_text()).get("policies", {})) != \
                set(_names(e, learned[e])) | set(n.name for n in _baselines(e)):
            return True
        return not all(reuse(f"results/{e}/{f}") for f in files)

    todo_e = [e for e in exps if stale(e)]
    # the SIF experiments differ in their cost only: one job rolls their constant baselines out once
    sif = tuple(e for e in todo_e if e in SIF_EXPERIMENTS)
    sif = sif if len(sif) > 1 else ()
    ejobs = [(sif, _cheap_and_heavy(sif[0])[0], [], scale)] if sif else []
    for e in todo_e:
        ejobs += _evaluation_jobs(e, [str(out / rel) for rel in learned[e]], scale, cheap=e not in sif)
    # the SIF greedy jobs are the longest: start them first, then the shared SIF baselines
    order = sorted(range(len(ejobs)), key=lambda i: (not set(ejobs[i][0]) & set(SIF_EXPERIMENTS),
                                                     ejobs[i][1] != ["greedy"], len(ejobs[i][0]) == 1))
    ekeys = [(_evaluation_key(ejobs[i]), SEED) for i in order]
    resumed = journal.count(ekeys)
    say(f"[evaluate] {len(todo_e)} experiments at M = {scale.eval_runs} in {len(ejobs)} jobs, {resumed} of them "
        f"finished by an earlier run ({JOURNAL})")
    outs = journal.run(_evaluate_job, [ejobs[i] for i in order], ekeys, save=_save_parts, load=_load_parts,
                       workers=workers, cluster=cluster, progress=progress, desc="evaluate")
    # each experiment's parts in job order (a shared job first): the merged tables keep their order
    by_job = dict(zip(order, outs))
    parts: dict[str, list] = {e: [] for e in todo_e}
    cpu = 0.0
    for i, (exps_i, *_rest) in enumerate(ejobs):
        res, t = by_job[i]
        for e, r in zip(exps_i, res):
            parts[e].append(r)
        cpu += t["cpu_time_s"]
        for name, w in t["policies"].items():  # a shared rollout's time is recorded under the first experiment
            job_times[f"results/{exps_i[0]}/{name}"] = {"wall_time_s": w}
            for e in exps_i[1:]:
                job_times[f"results/{e}/{name}"] = {"wall_time_s": 0.0, "shared_with": exps_i[0]}
    for e in todo_e:
        cmd = evaluate_command(e, learned[e], scale)
        res = _merge(parts[e], e, cmd)
        d = out / f"results/{e}"
        res.save(d)
        atomic_write(d / "summary.json", json.dumps(res.summary(), indent=1) + "\n")
        atomic_write(d / "summary.md", res.table())
        for f in files:
            entries[f"results/{e}/{f}"] = {"command": cmd, "seed": SEED}
    timings["evaluate"] = {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": cpu,
                           "note": f"{len(todo_e)} experiments x M = {scale.eval_runs}, {len(ejobs)} jobs; {engine}"}
    results = {e: Results.load(out / f"results/{e}") for e in exps}

    # ---- 3. floor, 4. reconciliation
    t0 = time.perf_counter()
    refs = []
    if "ungm-ukf" in exps and not (full and not retrain and reuse("results/ungm-floor.json")):
        refs.append(("results/ungm-floor.json", ungm_floor,
                     (scale.floor_runs, SEED, scale.floor_steps, 250, 1000, scale.eval_runs)))
    if not (full and not retrain and reuse("results/ctm-reconciliation.json")):
        refs.append(("results/ctm-reconciliation.json", ctm_reconciliation, (scale.recon_runs, SEED, scale.recon_steps)))
    ref_out = journal.run(_reference_job, [(r[0], r[2]) for r in refs], [(f"{r[0]}: {r[1].__name__}{r[2]!r}", SEED)
                                                                         for r in refs],
                          workers=workers, cluster=cluster, progress=progress, desc="references")
    for (rel, _, _), o in zip(refs, ref_out):
        atomic_write(out / rel, json.dumps(o, indent=1) + "\n")
        entries[rel] = {"command": o["command"], "seed": SEED, "wall_time_s": o["wall_time_s"],
                        "cpu_time_s": o["cpu_time_s"]}
    floor = json.loads((out / "results/ungm-floor.json").read_text()) if (out / "results/ungm-floor.json").exists() else None
    rec = (json.loads((out / "results/ctm-reconciliation.json").read_text())
           if (out / "results/ctm-reconciliation.json").exists() else None)
    timings["floor+reconcile"] = {"wall_time_s": time.perf_counter() - t0,
                                  "cpu_time_s": sum(o["cpu_time_s"] for o in ref_out),
                                  "note": "point-mass Bayes floor on UNGM, CTM variants"}

    # ---- 5. figures, tables, claims, manifest
    t0, c0 = time.perf_counter(), time.process_time()
    figs = figures(results, floor, out / "figures")
    t1 = table1(results)
    cl = claims(results)
    if any("adaptive-faithful-s0" in r for r in results.values()):
        from adaptfilt.experiments.fast_vs_faithful import comparison, comparison_md

        ff = comparison(results, job_times)
        atomic_write(out / "results/fast-vs-faithful.json", json.dumps(ff, indent=1) + "\n")
        extra = {"Fast trainer vs paper-faithful trainer (seed level)": comparison_md(ff)}
        entries["results/fast-vs-faithful.json"] = {}
    else:
        extra = {}
    ref = data / "results/claims.json"
    # a smaller reproduction is a check of the full one in data/
    if not full and not same and found is not None and ref.exists() and _load_manifest(data).get("scale") == "full":
        from adaptfilt.experiments.agreement import agreement, agreement_md

        agr = agreement(json.loads(json.dumps(cl)), json.loads(ref.read_text()))
        atomic_write(out / "results/agreement.json", json.dumps(agr, indent=1) + "\n")
        entries["results/agreement.json"] = {}
        extra[f"Verdicts at {scale.name} scale against the full scale (data/)"] = agreement_md(
            agr, f"{scale.name} scale", "full scale (data/)")
        say(f"[report] {agr['n_same']} of {agr['n']} seed-level verdicts as at full scale (results/agreement.json)")
    atomic_write(out / "results/table1.json", json.dumps(t1, indent=1) + "\n")
    atomic_write(out / "results/table1.md", table1_md(t1))
    atomic_write(out / "results/claims.json", json.dumps(cl, indent=1) + "\n")
    cmd = ("adaptfilt reproduce --out " + ("data" if full else "DIR")
           + {"full": "", "quick": " --quick"}.get(scale.name, f" --scale {scale.name}") + " --retrain")
    for rel in ("results/table1.json", "results/table1.md", "results/claims.json",
                *(str(p.relative_to(out)) for p in figs)):
        entries[rel] = {}
    timings["report"] = {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": time.process_time() - c0,
                         "note": "figures, Table I, claims, manifest"}
    timings["total"] = {"wall_time_s": time.perf_counter() - T0,
                        "cpu_time_s": sum(v.get("cpu_time_s", 0) or 0 for v in timings.values()),
                        "note": f"{scale.name} scale, {'retrain' if retrain else 'reusing data/'}; {engine}"}
    atomic_write(out / "report-tables.md", report_tables(results, floor, t1, cl, rec, timings, extra))
    atomic_write(out / "timings.json", json.dumps({"timings": timings, "jobs": job_times, "scale": asdict(scale),
                                                  "workers": workers, "cluster": None if cluster is None else str(cluster),
                                                  "python": sys.version.split()[0], "cpu_count": os.cpu_count()},
                                                 indent=1) + "\n")
    manifest_files = []
    for rel in sorted(entries):
        e = entries[rel]
        manifest_files.append({"path": rel, "sha256": sha256(out / rel), "command": e.get("command") or cmd,
                               "seed": e.get("seed", SEED), "version": e.get("version", __version__),
                               "wall_time_s": _seconds(e.get("wall_time_s")), "cpu_time_s": _seconds(e.get("cpu_time_s"))})
    manifest = {"package_version": __version__, "scale": scale.name, "seeds": list(scale.seeds),
                "generated_by": cmd, "files": manifest_files}
    atomic_write(out / "manifest.json", json.dumps(manifest, indent=1) + "\n")
    journal.finish()
    say(_timings_text(timings))
    return {"timings": timings, "table1": t1, "claims": cl, "figures": figs}


def _evaluation_key(job: tuple) -> str:
    """What identifies an evaluation job: its experiments, baselines, runs and the policy files' contents."""
    experiments, baselines, files, scale = job
    steps = "" if scale.eval_steps is None else f" --horizon {scale.eval_steps}"
    pols = "".join(f" --policy {Path(f).name}@{sha256(f)[:16]}" for f in files)
    return f"evaluate {'+'.join(experiments)} --runs {scale.eval_runs} --seed {SEED}{steps} baselines {','.join(baselines)}{pols}"


def _save_parts(folder: Path, value: tuple) -> tuple[list[Path], dict]:
    """An evaluation job's value as files for the journal: its Results parts, and its times."""
    parts, times = value
    return save_results(folder, parts), {"parts": len(parts), "times": times}


def _load_parts(folder: Path, stored: dict) -> tuple[list, dict]:
    return load_results(folder, stored["parts"]), stored["times"]


def _names(experiment: str, rels: list[str]) -> list[str]:
    from adaptfilt.evaluation import learned_name

    return [learned_name(r, experiment) for r in rels]


def _baselines(experiment: str) -> list:
    from adaptfilt.experiment_registry import get_experiment

    return get_experiment(experiment).baselines()


def _reference_job(rel: str, args: tuple) -> dict:
    fn = ungm_floor if rel.endswith("ungm-floor.json") else ctm_reconciliation
    return fn(*args)


def _seconds(v) -> float | None:
    return None if v is None else round(float(v), 2)


def _timings_text(timings: dict) -> str:
    from adaptfilt.experiments.report import timings_md

    return timings_md(timings)
