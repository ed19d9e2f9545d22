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
  Algorithm 2's loop with the library's recipe (``--algo faithful``): the reference the fast mode is
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
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from adaptfilt.experiment_registry import SIF_EXPERIMENTS
from adaptfilt.experiments.claims import claims, table1
from adaptfilt.experiments.jobs import TrainSpec, evaluate_command as _evaluate_line, load_learned, run_training
from adaptfilt.experiments.journal import Journal, load_results, save_results
from adaptfilt.experiments.references import ctm_reconciliation, ungm_floor
from adaptfilt.experiments.report import embed_report_tables, figures, report_tables, table1_md
from adaptfilt.files import atomic_write, sha256

__all__ = ["reproduce", "report_only", "Scale", "FULL", "QUICK", "SEEDS", "KINDS", "FAITHFUL", "policy_command",
           "sha256", "embed_report_tables"]

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


#: The paper's protocol: M = 10^4 paired runs, 1000 training episodes per policy (about 15 min on 2 cores).
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
RETRAIN_COST = "about 15 minutes on 2 cores"


def policy_rel(experiment: str, kind: str, seed: int) -> str:
    return f"policies/{experiment}-{kind}-s{seed}.npz"


def _episodes(kind: str, scale: Scale) -> int:
    return scale.faithful_episodes if ALGO[kind] == "faithful" and scale.faithful_episodes else scale.episodes


def policy_spec(experiment: str, kind: str, seed: int, scale: Scale = FULL, out: str | Path | None = None,
                prefix: str = "data") -> TrainSpec:
    """The training of ``policies/{experiment}-{kind}-s{seed}.npz`` into ``out``; its command records
    ``--out {prefix}/policies/...`` wherever the file is written."""
    rel = policy_rel(experiment, kind, seed)
    return TrainSpec(experiment, GAMMA[kind], _episodes(kind, scale), seed, str(out or f"{prefix}/{rel}"),
                     algo=ALGO[kind], horizon=scale.train_steps, recorded_out=f"{prefix}/{rel}")


def policy_command(experiment: str, kind: str, seed: int, scale: Scale = FULL, prefix: str = "data") -> str:
    """The one command that makes ``policies/{experiment}-{kind}-s{seed}.npz``."""
    return policy_spec(experiment, kind, seed, scale, prefix=prefix).command


def evaluate_command(experiment: str, policy_rels: list[str], scale: Scale = FULL, prefix: str = "data") -> str:
    """The command recorded for an experiment's evaluation of the policies ``policy_rels``."""
    return _evaluate_line(experiment, scale.eval_runs, SEED, f"{prefix}/results/{experiment}",
                          [f"{prefix}/{p}" for p in policy_rels], horizon=scale.eval_steps)


# ------------------------------------------------------------------ jobs (module level: they run in workers)
def _evaluate_job(experiments: tuple[str, ...], baselines: list[str], policy_files: list[str], scale: Scale):
    """Evaluate the named baselines and the policy files on the experiment's runs (a part of one
    evaluation: every part simulates the same runs and resamples them the same way); one part per
    experiment. Several experiments differ in their cost only (the SIF ones): they share the
    rollouts of their baselines (:func:`adaptfilt.evaluation.evaluate_costs`)."""
    from adaptfilt.evaluation import evaluate, evaluate_costs
    from adaptfilt.experiment_registry import get_experiment

    t0, c0 = time.perf_counter(), time.process_time()
    exp = get_experiment(experiments[0])
    by_name = {p.name: p for p in exp.baselines()}
    policies = [by_name[n] for n in baselines] + load_learned(exp, policy_files)
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
    names = [p.name for p in _baselines(experiment)]
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
    from adaptfilt.results import Results

    res = Results.merge(parts, ignore=("command",))
    exp = get_experiment(experiment)
    res.config["command"] = command
    res.config.update(experiment=exp.name, description=exp.description)
    return res


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


@dataclass
class _Run:
    """One reproduction under way: its scale and folders, what it may reuse, and what it has recorded."""

    out: Path
    data: Path
    found: Path | None
    scale: Scale
    retrain: bool
    workers: int
    cluster: object
    progress: bool
    journal: Journal
    kept: dict                # data/'s manifest (the paper-faithful policies are reused from it even on --retrain)
    dman: dict                # what may be reused of the rest
    entries: dict[str, dict] = field(default_factory=dict)
    timings: dict[str, dict] = field(default_factory=dict)
    job_times: dict[str, dict] = field(default_factory=dict)

    @property
    def quick(self) -> bool:
        return self.scale is QUICK

    @property
    def full(self) -> bool:
        return self.scale is FULL

    @property
    def same(self) -> bool:
        return self.found is not None and self.out == self.data

    @property
    def engine(self) -> str:
        return f"cluster {self.cluster}" if self.cluster is not None else f"{self.workers} local workers"

    def say(self, *a) -> None:
        if self.progress:
            print(*a, flush=True)

    def jobs(self, fn, jobs, keys, desc: str, **kw) -> list:
        return self.journal.run(fn, jobs, keys, workers=self.workers, cluster=self.cluster, progress=self.progress,
                                desc=desc, **kw)

    def reuse(self, rel: str, man: dict | None = None) -> bool:
        """Take ``rel`` from data/ where its manifest lists it unchanged."""
        e = _reusable(self.data, rel, self.dman if man is None else man)
        if e is None:
            return False
        if not self.same:
            (self.out / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(self.data / rel, self.out / rel)
        self.entries[rel] = dict(e)
        return True

    def adopt(self, rel: str, command: str, keep: bool = False) -> bool:
        """A policy file in data/ that no manifest lists yet, made by the expected command."""
        from adaptfilt.files import read_npz

        if self.quick or self.found is None or (self.retrain and not keep) or not (self.data / rel).exists():
            return False
        meta = read_npz(self.data / rel)[1]
        recorded = " ".join(w for w in str(meta.get("command", "")).split() if w != "--no-progress")
        if recorded != command:
            return False
        if not self.same:
            shutil.copy2(self.data / rel, self.out / rel)
        # the training seed is the file's own, not the evaluation seed; its time was not recorded
        self.entries[rel] = {"command": command, "seed": int(meta["seed"]), "wall_time_s": None, "cpu_time_s": None}
        return True


def reproduce(out_dir: str | Path, quick: bool = False, retrain: bool = False, progress: bool = True,
              workers: int | None = None, cluster=None, experiments: tuple[str, ...] | None = None,
              faithful: bool = False, scale: str | Scale | None = None,
              data: str | Path | None = None) -> dict:
    """Train + evaluate + floor + reconciliation + figures + tables into ``out_dir`` (module docstring).

    ``scale``: ``"full"`` (default), ``"medium"`` or ``"quick"`` (:data:`SCALES`; ``quick=True``
    is ``"quick"``). Only the full scale reuses the fast-mode policies and results of ``data/``;
    every scale but ``quick`` reuses its paper-faithful policies.
    ``workers``: local processes (default: every core, or ``$ADAPTFILT_JOBS``); ``cluster``: a Dask scheduler address, ``"local"`` or a ``distributed.Client``.
    ``data``: the stored artefacts to reuse (default: ``$ADAPTFILT_DATA``, then the checkout's ``data/``).
    Returns ``{"timings", "table1", "claims", "figures"}``.
    """
    from adaptfilt.experiment_registry import EXPERIMENTS
    from adaptfilt.results import Results

    exps = tuple(EXPERIMENTS) if experiments is None else tuple(experiments)
    r = _start(out_dir, quick, retrain, progress, workers, cluster, scale, data, exps)
    T0 = time.perf_counter()
    learned = _train_stage(r, exps, faithful)
    _evaluate_stage(r, exps, learned)
    results = {e: Results.load(r.out / f"results/{e}") for e in exps}
    floor, rec = _reference_stage(r, exps)
    return _report_stage(r, results, floor, rec, T0)


def _start(out_dir, quick: bool, retrain: bool, progress: bool, workers: int | None, cluster, scale, data,
           exps: tuple[str, ...]) -> _Run:
    """The run's scale, folders and what it may reuse (errors before anything is written)."""
    from adaptfilt.experiments.artefacts import find_data
    from adaptfilt.experiments.sweep import default_workers

    if quick and scale not in (None, "quick", QUICK):
        raise ValueError(f"quick=True and scale={scale!r}: give one of them")
    if not isinstance(scale, Scale):
        if (scale or "full") not in SCALES:
            raise ValueError(f"unknown scale {scale!r}; one of {', '.join(SCALES)}")
        scale = QUICK if quick else SCALES[scale or "full"]
    full = scale is FULL
    out = Path(out_dir).resolve()
    need = None if (retrain or not full) else (f"or add --retrain to train the {len(exps) * len(KINDS) * len(scale.seeds)} "
                                               f"fast-mode policies and evaluate everything here ({RETRAIN_COST})")
    found = find_data(data, required=need)
    data = found.resolve() if found is not None else out
    if found is not None and out == data and not full:
        raise ValueError(f"--scale {scale.name} into {out} would overwrite the full-scale reproduction there; "
                         "give another --out")
    for sub in ("policies", "results"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    # --retrain retrains the fast-mode policies; the paper-faithful ones (hours) are still reused
    kept = {"files": []} if (scale is QUICK or found is None) else _load_manifest(data)
    r = _Run(out, data, found, scale, retrain, workers if workers is not None else default_workers(), cluster,
             progress, Journal(out / JOURNAL), kept, {"files": []} if (retrain or not full) else kept)
    r.say(f"reproduce ({scale.name} scale, {len(scale.seeds)} seeds) into {out}; {r.engine}; retrain={retrain}; "
          + (f"stored artefacts: {data}" if found is not None else "no stored artefacts"))
    return r


def _train_stage(r: _Run, exps: tuple[str, ...], faithful: bool) -> dict[str, list[str]]:
    """1. train what cannot be reused; returns each experiment's policy files (relative paths)."""
    t0, scale = time.perf_counter(), r.scale
    todo, learned, n_reused = [], {e: [] for e in exps}, 0
    wanted = [(e, k) for e in exps for k in KINDS] + [(e, k) for k, (_, es) in FAITHFUL.items() for e in es if e in exps]
    for e, k in wanted:
        for s in scale.seeds:
            rel = policy_rel(e, k, s)
            spec = policy_spec(e, k, s, scale, out=r.out / rel)
            keep = k in FAITHFUL  # hours each: reused even by --retrain
            if r.reuse(rel, r.kept if keep else None) or r.adopt(rel, spec.command, keep):
                n_reused += 1
                learned[e].append(rel)
            elif k in KINDS or faithful:
                todo.append((rel, spec))
                learned[e].append(rel)
    # the slow ones first, so that they do not finish last on a worker of their own
    todo.sort(key=lambda a: (a[1].algo != "faithful", a[1].experiment not in SIF_EXPERIMENTS))
    keys = [spec.key for _, spec in todo]
    resumed = r.journal.count(keys)
    r.say(f"[train] {len(todo) - resumed} policies to train, {resumed} finished by an earlier run ({JOURNAL}), "
          f"{n_reused} reused")
    made = r.jobs(run_training, [(spec,) for _, spec in todo], keys, "train", files=[[spec.out] for _, spec in todo])
    res_jobs = [m[spec.out] for m, (_, spec) in zip(made, todo)]
    for (rel, spec), t in zip(todo, res_jobs):
        t = {k: v for k, v in t.items() if k != "command"}
        r.entries[rel] = {"command": spec.command, "seed": spec.seed, **t}
        r.job_times[rel] = t
    r.timings["train"] = {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": sum(t["cpu_time_s"] for t in res_jobs),
                          "note": f"{len(todo) - resumed} trained ({scale.episodes} episodes each), {resumed} by an "
                                  f"earlier run (journal), {n_reused} reused; {r.engine}"}
    return learned


_RESULT_FILES = ("results.json", "results.npz", "summary.json", "summary.md")


def _stale(r: _Run, e: str, learned: list[str]) -> bool:
    """Evaluate again unless data/ holds this experiment's results for exactly these policies."""
    if r.retrain or not r.full or any(rel in r.job_times for rel in learned):
        return True
    p = r.data / f"results/{e}/results.json"
    if not p.exists() or set(json.loads(p.read_text()).get("policies", {})) != \
            set(_names(e, learned)) | set(n.name for n in _baselines(e)):
        return True
    return not all(r.reuse(f"results/{e}/{f}") for f in _RESULT_FILES)


def _evaluate_stage(r: _Run, exps: tuple[str, ...], learned: dict[str, list[str]]) -> None:
    """2. evaluate every experiment whose results cannot be reused, in jobs merged per experiment."""
    t0, scale = time.perf_counter(), r.scale
    todo_e = [e for e in exps if _stale(r, e, learned[e])]
    # the SIF experiments differ in their cost only: one job rolls their constant baselines out once
    sif = tuple(e for e in todo_e if e in SIF_EXPERIMENTS)
    sif = sif if len(sif) > 1 else ()
    ejobs = [(sif, _cheap_and_heavy(sif[0])[0], [], scale)] if sif else []
    for e in todo_e:
        ejobs += _evaluation_jobs(e, [str(r.out / rel) for rel in learned[e]], scale, cheap=e not in sif)
    # the SIF greedy jobs are the longest: start them first, then the shared SIF baselines
    order = sorted(range(len(ejobs)), key=lambda i: (not set(ejobs[i][0]) & set(SIF_EXPERIMENTS),
                                                     ejobs[i][1] != ["greedy"], len(ejobs[i][0]) == 1))
    ekeys = [(_evaluation_key(ejobs[i]), SEED) for i in order]
    resumed = r.journal.count(ekeys)
    r.say(f"[evaluate] {len(todo_e)} experiments at M = {scale.eval_runs} in {len(ejobs)} jobs, {resumed} of them "
          f"finished by an earlier run ({JOURNAL})")
    outs = r.jobs(_evaluate_job, [ejobs[i] for i in order], ekeys, "evaluate", save=_save_parts, load=_load_parts)
    # each experiment's parts in job order (a shared job first): the merged tables keep their order
    by_job = dict(zip(order, outs))
    parts: dict[str, list] = {e: [] for e in todo_e}
    cpu = 0.0
    for i, (exps_i, *_rest) in enumerate(ejobs):
        res, t = by_job[i]
        for e, part in zip(exps_i, res):
            parts[e].append(part)
        cpu += t["cpu_time_s"]
        for name, w in t["policies"].items():  # a shared rollout's time is recorded under the first experiment
            r.job_times[f"results/{exps_i[0]}/{name}"] = {"wall_time_s": w}
            for e in exps_i[1:]:
                r.job_times[f"results/{e}/{name}"] = {"wall_time_s": 0.0, "shared_with": exps_i[0]}
    for e in todo_e:
        cmd = evaluate_command(e, learned[e], scale)
        res = _merge(parts[e], e, cmd)
        d = r.out / f"results/{e}"
        res.save(d)
        atomic_write(d / "summary.json", json.dumps(res.summary(), indent=1) + "\n")
        atomic_write(d / "summary.md", res.table())
        for f in _RESULT_FILES:
            r.entries[f"results/{e}/{f}"] = {"command": cmd, "seed": SEED}
    r.timings["evaluate"] = {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": cpu,
                             "note": f"{len(todo_e)} experiments x M = {scale.eval_runs}, {len(ejobs)} jobs; {r.engine}"}


def _reference_stage(r: _Run, exps: tuple[str, ...]) -> tuple[dict | None, dict | None]:
    """3. the point-mass floor on UNGM, 4. the CTM reconciliation (reused from data/ where they can be)."""
    t0, scale = time.perf_counter(), r.scale
    refs = []
    if "ungm-ukf" in exps and not (r.full and not r.retrain and r.reuse("results/ungm-floor.json")):
        refs.append(("results/ungm-floor.json", ungm_floor,
                     (scale.floor_runs, SEED, scale.floor_steps, 250, 1000, scale.eval_runs)))
    if not (r.full and not r.retrain and r.reuse("results/ctm-reconciliation.json")):
        refs.append(("results/ctm-reconciliation.json", ctm_reconciliation, (scale.recon_runs, SEED, scale.recon_steps)))
    ref_out = r.jobs(_reference_job, [(x[0], x[2]) for x in refs], [(f"{x[0]}: {x[1].__name__}{x[2]!r}", SEED)
                                                                    for x in refs], "references")
    for (rel, _, _), o in zip(refs, ref_out):
        atomic_write(r.out / rel, json.dumps(o, indent=1) + "\n")
        r.entries[rel] = {"command": o["command"], "seed": SEED, "wall_time_s": o["wall_time_s"],
                          "cpu_time_s": o["cpu_time_s"]}
    read = lambda rel: json.loads((r.out / rel).read_text()) if (r.out / rel).exists() else None  # noqa: E731
    r.timings["floor+reconcile"] = {"wall_time_s": time.perf_counter() - t0,
                                    "cpu_time_s": sum(o["cpu_time_s"] for o in ref_out),
                                    "note": "point-mass Bayes floor on UNGM, CTM variants"}
    return read("results/ungm-floor.json"), read("results/ctm-reconciliation.json")


def _report_stage(r: _Run, results: dict, floor: dict | None, rec: dict | None, T0: float) -> dict:
    """5. figures, Table I, claims, the report's tables, timings and the manifest."""
    t0, c0 = time.perf_counter(), time.process_time()
    figs = figures(results, floor, r.out / "figures")
    t1 = table1(results)
    cl = claims(results)
    extra = _extra_tables(r, results, cl)
    for rel, value in (("results/table1.json", t1), ("results/claims.json", cl)):
        atomic_write(r.out / rel, json.dumps(value, indent=1) + "\n")
    atomic_write(r.out / "results/table1.md", table1_md(t1))
    for rel in ("results/table1.json", "results/table1.md", "results/claims.json",
                *(str(p.relative_to(r.out)) for p in figs)):
        r.entries[rel] = {}
    r.timings["report"] = {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": time.process_time() - c0,
                           "note": "figures, Table I, claims, manifest"}
    r.timings["total"] = {"wall_time_s": time.perf_counter() - T0,
                          "cpu_time_s": sum(v.get("cpu_time_s", 0) or 0 for v in r.timings.values()),
                          "note": f"{r.scale.name} scale, {'retrain' if r.retrain else 'reusing data/'}; {r.engine}"}
    atomic_write(r.out / "report-tables.md", report_tables(results, floor, t1, cl, rec, r.timings, extra))
    atomic_write(r.out / "timings.json", json.dumps(
        {"timings": r.timings, "jobs": r.job_times, "scale": asdict(r.scale), "workers": r.workers,
         "cluster": None if r.cluster is None else str(r.cluster), "python": sys.version.split()[0],
         "cpu_count": os.cpu_count()}, indent=1) + "\n")
    _write_manifest(r)
    r.journal.finish()
    r.say(_timings_text(r.timings))
    return {"timings": r.timings, "table1": t1, "claims": cl, "figures": figs}


def _extra_tables(r: _Run, results: dict, cl: dict) -> dict[str, str]:
    """The report's optional tables: the fast trainer against the faithful one where both are there, and a
    smaller scale's verdicts against the full scale's of data/."""
    extra = {}
    if any("adaptive-faithful-s0" in x for x in results.values()):
        from adaptfilt.experiments.fast_vs_faithful import comparison, comparison_md

        ff = comparison(results, r.job_times)
        atomic_write(r.out / "results/fast-vs-faithful.json", json.dumps(ff, indent=1) + "\n")
        extra["Fast trainer vs paper-faithful trainer (seed level)"] = comparison_md(ff)
        r.entries["results/fast-vs-faithful.json"] = {}
    ref = r.data / "results/claims.json"
    # a smaller reproduction, or a full one into another folder (a retrain), is a check of the full one in data/
    if not r.same and r.found is not None and ref.exists() and _load_manifest(r.data).get("scale") == "full":
        from adaptfilt.experiments.agreement import agreement, agreement_md

        agr = agreement(json.loads(json.dumps(cl)), json.loads(ref.read_text()))
        atomic_write(r.out / "results/agreement.json", json.dumps(agr, indent=1) + "\n")
        r.entries["results/agreement.json"] = {}
        here = f"{r.scale.name} scale" if not r.full else "this run"
        title = f"Verdicts at {here}" if not r.full else "Verdicts of this full-scale run"
        extra[f"{title} against the full scale (data/)"] = agreement_md(agr, here, "full scale (data/)")
        r.say(f"[report] {agr['n_same']} of {agr['n']} seed-level verdicts as in data/ (results/agreement.json)")
    return extra


def report_only(out_dir: str | Path, data: str | Path | None = None, progress: bool = True) -> list[str]:
    """``adaptfilt reproduce --out DIR --report-only``: the verdicts and the report's tables again, from what
    ``DIR`` holds, nothing trained or evaluated; for a change of the verdict rule or of the report. Returns the
    files rewritten; each is listed in DIR's manifest with its new sha256 and, as its command, this one.

    * A reproduction (``data/``, or a full-scale ``DIR``): the claims, Table I and the fast-vs-faithful
      comparison recomputed from its evaluations (``results/<experiment>/``), and ``report-tables.md`` with
      every stage time and training time that ``timings.json`` recorded (kept unchanged: no run was made);
      the figures are kept (they hold no verdict); a ``DIR`` other than ``data/`` also gets its agreement
      with ``data/`` again, as ``reproduce`` writes it.
    * A stored check (``data/medium``, ``data/retrain``: its summaries only,
      :func:`adaptfilt.experiments.artefacts.store_check`): every stored row judged again by the one rule from
      its stored interval and margin (:func:`adaptfilt.experiments.claims.rejudge`), its agreement with
      ``data/``'s claims recomputed, and the verdict sections of its ``report-tables.md`` rewritten.
    """
    from adaptfilt.experiment_registry import EXPERIMENTS
    from adaptfilt.experiments.artefacts import find_data

    out = Path(out_dir).resolve()
    man = _load_manifest(out)
    if not man.get("files"):
        raise ValueError(f"{out}: no manifest.json listing files; not a reproduction or a stored check")
    found = find_data(data)
    ref_dir = found.resolve() if found is not None else None
    exps = [e for e in EXPERIMENTS if (out / f"results/{e}/results.json").exists()]  # the reproduction's order
    files = _rejudge_reproduction(out, exps, ref_dir) if exps else _rejudge_check(out, ref_dir)
    cmd = report_only_command(out, ref_dir)
    files = {rel: text for rel, text in files.items()  # a file that comes out byte for byte the same stays as made
             if not (out / rel).exists() or (out / rel).read_text() != text}
    for rel, text in files.items():
        atomic_write(out / rel, text)
    for e in man["files"]:  # the files the manifest lists (data/'s does not list its report-tables.md)
        if e["path"] in files:
            e.update(sha256=sha256(out / e["path"]), command=cmd)
    atomic_write(out / "manifest.json", json.dumps(man, indent=1) + "\n")
    if progress:
        print(f"[report-only] {out}: {len(files)} files rewritten ({', '.join(sorted(files))})", file=sys.stderr)
    return sorted(files)


def _read_json(out: Path, rel: str):
    return json.loads((out / rel).read_text()) if (out / rel).exists() else None


def _rejudge_reproduction(out: Path, exps: list[str], ref_dir: Path | None) -> dict[str, str]:
    """:func:`report_only` on a reproduction: its files' new texts, everything from its evaluations."""
    from adaptfilt.experiments.agreement import agreement, agreement_md
    from adaptfilt.experiments.fast_vs_faithful import comparison_md
    from adaptfilt.results import Results

    files: dict[str, str] = {}
    results = {e: Results.load(out / f"results/{e}") for e in exps}
    stored = _read_json(out, "timings.json") or {}
    t1, cl = table1(results), claims(results)
    files["results/table1.json"], files["results/claims.json"] = _dump(t1), _dump(cl)
    files["results/table1.md"] = table1_md(t1)
    extra = {}
    if any("adaptive-faithful-s0" in x for x in results.values()):
        from adaptfilt.experiments.fast_vs_faithful import comparison

        ff = comparison(results, stored.get("jobs", {}))
        files["results/fast-vs-faithful.json"] = _dump(ff)
        extra["Fast trainer vs paper-faithful trainer (seed level)"] = comparison_md(ff)
    if ref_dir is not None and ref_dir != out and (ref_dir / "results/claims.json").exists():
        agr = agreement(json.loads(files["results/claims.json"]), json.loads((ref_dir / "results/claims.json")
                                                                            .read_text()))
        files["results/agreement.json"] = _dump(agr)
        extra["Verdicts of this full-scale run against the full scale (data/)"] = agreement_md(
            agr, "this run", "full scale (data/)")
    files["report-tables.md"] = report_tables(results, _read_json(out, "results/ungm-floor.json"), t1, cl,
                                              _read_json(out, "results/ctm-reconciliation.json"),
                                              stored.get("timings", {}), extra)
    return files


def _rejudge_check(out: Path, ref_dir: Path | None) -> dict[str, str]:
    """:func:`report_only` on a stored check: its files' new texts, its rows judged again from their intervals."""
    from adaptfilt.experiments.agreement import agreement, agreement_md
    from adaptfilt.experiments.artefacts import CHECK_FILES
    from adaptfilt.experiments.claims import rejudge
    from adaptfilt.experiments.fast_vs_faithful import comparison_md, rejudge as rejudge_ff
    from adaptfilt.experiments.report import claims_md, replace_sections

    files: dict[str, str] = {}
    have = [rel for rel in CHECK_FILES if (out / rel).exists()]
    if "results/claims.json" not in have:
        raise ValueError(f"{out}: neither evaluations (results/<experiment>/) nor stored claims to judge again")
    cl = rejudge(_read_json(out, "results/claims.json"))
    files["results/claims.json"] = _dump(cl)
    sections = {"Claims (fast trainer, seed level)": claims_md(cl)}
    if "faithful" in cl:
        sections["Claims, paper-faithful training (seed level)"] = claims_md(cl["faithful"])
    if "results/table1.json" in have:
        files["results/table1.json"] = _dump(rejudge(_read_json(out, "results/table1.json")))
    if "results/fast-vs-faithful.json" in have:
        ff = rejudge_ff(_read_json(out, "results/fast-vs-faithful.json"))
        files["results/fast-vs-faithful.json"] = _dump(ff)
        sections["Fast trainer vs paper-faithful trainer (seed level)"] = comparison_md(ff)
    if "results/agreement.json" in have:
        if ref_dir is None or not (ref_dir / "results/claims.json").exists():
            raise ValueError(f"{out} holds an agreement with data/'s claims, and no data/ was found")
        agr = agreement(cl, json.loads((ref_dir / "results/claims.json").read_text()))
        files["results/agreement.json"] = _dump(agr)
        tables = (out / "report-tables.md").read_text()
        title = next(t for t in ("Verdicts at medium scale against the full scale (data/)",
                                 "Verdicts of this full-scale run against the full scale (data/)")
                     if f"\n### {t}\n" in tables)
        here = "medium scale" if "medium" in title else "this run"
        sections[title] = agreement_md(agr, here, "full scale (data/)")
    if "report-tables.md" in have:
        files["report-tables.md"] = replace_sections((out / "report-tables.md").read_text(), sections)
    return files


def report_only_command(out: Path, data: Path | None = None) -> str:
    """The command a file rewritten by :func:`report_only` records: ``--out data`` for the repository's
    ``data/`` and its checks (``data/medium``), ``--out DIR`` elsewhere."""
    try:
        rel = out.relative_to(data.parent) if data is not None else None
    except ValueError:
        rel = None
    where = str(rel) if rel is not None and str(rel).split("/")[0] == data.name == "data" else "DIR"
    return f"adaptfilt reproduce --out {where} --report-only"


def _dump(value) -> str:
    return json.dumps(value, indent=1) + "\n"


def run_command(scale: Scale) -> str:
    """The command recorded for the report's files (and as the manifest's ``generated_by``)."""
    return ("adaptfilt reproduce --out " + ("data" if scale is FULL else "DIR")
            + {"full": "", "quick": " --quick"}.get(scale.name, f" --scale {scale.name}") + " --retrain")


def _write_manifest(r: _Run) -> None:
    from adaptfilt._version import __version__

    cmd = run_command(r.scale)
    files = []
    for rel in sorted(r.entries):
        e = r.entries[rel]
        files.append({"path": rel, "sha256": sha256(r.out / rel), "command": e.get("command") or cmd,
                      "seed": e.get("seed", SEED), "version": e.get("version", __version__),
                      "wall_time_s": _seconds(e.get("wall_time_s")), "cpu_time_s": _seconds(e.get("cpu_time_s"))})
    manifest = {"package_version": __version__, "scale": r.scale.name, "seeds": list(r.scale.seeds),
                "generated_by": cmd, "files": files}
    atomic_write(r.out / "manifest.json", json.dumps(manifest, indent=1) + "\n")


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
    from adaptfilt.learned import learned_name

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
