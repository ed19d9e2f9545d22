"""The full retrain's CPU time by stage: the last full run, and today's code extrapolated from probes.

    python benchmarks/bench_retrain.py [--baseline DIR] [--episodes 100] [--runs 1000] [--repeat 2]

``adaptfilt reproduce --scale full --retrain`` takes over an hour on 2 cores, so this benchmark does
not run it. It prints

1. the stage tables of the full runs recorded: the one that made ``data/`` (``data/timings.json``) and
   the latest retrain into another folder (``data/retrain/timings.json``, a check of ``data/``), CPU-s
   of each stage, training split by experiment from the per-policy records, the total against the
   target;
2. probes: for each experiment, one fast-mode training of ``--episodes`` episodes (seed 0, the
   experiment's horizon) and one evaluation of ``--runs`` runs (the default, greedy and one stored
   learned policy), each in a fresh process, timed by CPU; with ``--baseline DIR`` (a checkout of
   an earlier commit, e.g. ``git archive a41ad71 | tar -x -C DIR``) the same probes run on that code
   too, in the same session, interleaved, best of ``--repeat``;
3. the extrapolation from the latest record: each recorded stage's CPU time scaled by the ratio today/baseline of its
   probes (training per experiment; evaluation per experiment, weighted by the recorded wall time of
   its policies; the floor, reconciliation and report unchanged), against the target of 1800 CPU-s.

A probe first runs a tiny training (evaluation) untimed: a worker pays its imports (torch, SB3)
and loads its compiled kernels once for dozens of jobs, so they are left out of the timed part.
Without ``--baseline`` only today's probes are printed. The ratios are the figures to trust; the
extrapolated total assumes a job's time scales like its probe's (the scaler's fit and the network's
set-up weigh more in a 100-episode probe than in a 1000-episode job).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_CPU_S = 1800.0
#: the full runs recorded: the one that made data/, and the latest retrain into another folder (a check of data/)
RECORDS = (("data/timings.json", "the full run that made data/"),
           ("data/retrain/timings.json", "the latest full retrain (adaptfilt reproduce --out DIR --retrain)"))
EXPERIMENTS = ("ungm-ukf", "ctm-ukf", "ctm-sif-stateinnov", "ctm-sif-logmaxnis", "ctm-sif-nis")

TRAIN = r"""
import sys, time
from adaptfilt.trainers import train_policy
exp, episodes = sys.argv[1], int(sys.argv[2])
train_policy(exp, "fast", 0.5, 2, 1, n_steps=5, progress=False)  # a worker's one-off costs: imports, compiled kernels
c0 = time.process_time()
train_policy(exp, "fast", 0.5, episodes, 0, progress=False)
print(time.process_time() - c0)
"""

EVALUATE = r"""
import sys, time
from adaptfilt.evaluation import evaluate
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.learned import learned_name, load_policy
exp, runs, policy = sys.argv[1], int(sys.argv[2]), sys.argv[3]
e = get_experiment(exp)
pols = [p for p in e.baselines() if p.name in ("default", "greedy")]
pols.append(load_policy(policy, experiment=e, name=learned_name(policy, e.name)))
evaluate(e.make_env(seed=0, n_steps=3), pols, n_runs=4, seed=0, progress=False)  # one-off costs, as in a worker
c0 = time.process_time()
evaluate(e, pols, n_runs=runs, seed=0, progress=False)
print(time.process_time() - c0)
"""


def recorded(timings: dict) -> dict:
    """CPU-s of the last full run: stages, and training per experiment."""
    t = timings["timings"]
    train = defaultdict(float)
    for rel, job in timings["jobs"].items():
        if rel.startswith("policies/") and job.get("cpu_time_s"):
            train[next(e for e in sorted(EXPERIMENTS, key=len, reverse=True) if rel[9:].startswith(e + "-"))] += job["cpu_time_s"]
    evaluate_wall = defaultdict(float)
    for rel, job in timings["jobs"].items():
        if rel.startswith("results/"):
            evaluate_wall[rel.split("/")[1]] += job.get("wall_time_s") or 0.0
    return {"stages": {k: v["cpu_time_s"] for k, v in t.items()}, "train": dict(train), "evaluate_wall": dict(evaluate_wall)}


def probe(code: str, args: list[str], checkout: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    out = subprocess.run([sys.executable, "-c", code, *args], cwd=checkout, env=env, capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"probe {args} in {checkout} failed:\n{out.stderr[-2000:]}")
    return float(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--baseline", type=Path, default=None, help="a checkout of the code to compare with")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--runs", type=int, default=1000)
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--experiments", nargs="+", default=list(EXPERIMENTS))
    args = p.parse_args(argv)
    for rel, what in RECORDS:
        if not (ROOT / rel).is_file():
            continue
        timings = json.loads((ROOT / rel).read_text())
        rec = recorded(timings)
        print(f"{what} ({rel}: {timings['scale']['name']} scale, {timings['workers']} workers, "
              f"{timings['cpu_count']} cores):")
        for k, v in rec["stages"].items():
            print(f"  {k:16s} {v:8.0f} CPU-s" + (f"  target {TARGET_CPU_S:.0f}: "
                                                 f"{'met' if v <= TARGET_CPU_S else 'NOT met'}" if k == "total" else ""))
        for e, v in rec["train"].items():
            print(f"    train {e:20s} {v:8.0f} CPU-s")
    # the extrapolation starts from the latest record (the last one printed)
    checkouts = {"today": ROOT, **({"baseline": args.baseline.resolve()} if args.baseline else {})}
    best: dict[tuple, float] = {}
    for e in args.experiments:
        policy = str(ROOT / "data" / "policies" / f"{e}-adaptive-s0.npz")
        for _ in range(args.repeat):
            for name, co in checkouts.items():  # interleaved: the load of the moment falls on both
                for kind, code, a in (("train", TRAIN, [e, str(args.episodes)]),
                                      ("evaluate", EVALUATE, [e, str(args.runs), policy])):
                    s = probe(code, a, co)
                    best[(name, kind, e)] = min(s, best.get((name, kind, e), float("inf")))
        line = "  ".join(f"{kind} {name} {best[(name, kind, e)]:.1f} s" for kind in ("train", "evaluate") for name in checkouts)
        print(f"probe {e}: {line}", flush=True)
    if not args.baseline:
        return 0
    ratio = {(k, e): best[("today", k, e)] / best[("baseline", k, e)] for k in ("train", "evaluate") for e in args.experiments}
    train = sum(v * ratio.get(("train", e), 1.0) for e, v in rec["train"].items())
    w = {e: rec["evaluate_wall"].get(e, 0.0) for e in args.experiments}
    scale_eval = sum(w[e] * ratio[("evaluate", e)] for e in w) / sum(w.values())
    evaluate = rec["stages"]["evaluate"] * scale_eval
    rest = rec["stages"]["floor+reconcile"] + rec["stages"]["report"]
    total = train + evaluate + rest
    print("\nextrapolated full retrain with today's code (CPU-s):")
    print(f"  train    {rec['stages']['train']:8.0f} -> {train:8.0f}  (ratios "
          + ", ".join(f"{e} {ratio[('train', e)]:.2f}" for e in args.experiments) + ")")
    print(f"  evaluate {rec['stages']['evaluate']:8.0f} -> {evaluate:8.0f}  (ratio {scale_eval:.2f}: "
          + ", ".join(f"{e} {ratio[('evaluate', e)]:.2f}" for e in args.experiments) + ")")
    print(f"  rest     {rest:8.0f} -> {rest:8.0f}  (floor, reconciliation, report: not probed)")
    print(f"  total    {rec['stages']['total']:8.0f} -> {total:8.0f}  target {TARGET_CPU_S:.0f}: "
          f"{'met' if total <= TARGET_CPU_S else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
