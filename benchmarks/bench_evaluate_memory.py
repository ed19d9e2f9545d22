"""Peak memory of a Monte-Carlo evaluation against the number of runs (the evaluation's streaming).

    python benchmarks/bench_evaluate_memory.py [--runs 10000 100000] [--policies default,fixed-kappa=0,ml]
        [--experiment ungm-ukf] [--horizon T] [--chunk-size C] [--quick]

Each ``M`` of ``--runs`` is evaluated in a fresh process (``adaptfilt.evaluation.evaluate`` with the named
baselines of ``--experiment``, ``n_boot`` 1000, no progress bar), whose peak resident memory
(``getrusage(RUSAGE_CHILDREN).ru_maxrss``) and wall time are printed, one line per ``M``, then the memory
per run between the two largest ``M`` and an extrapolation to 10^6 runs with all of the experiment's
baselines (the kept per-run arrays, 24 bytes per run and policy, added). ``--quick``: 2000 and 8000 runs of
50 steps. Run it with ``PYTHONPATH`` set to another checkout to measure that code (a code without
``chunk_size`` is run without it).

Measured (shared 2-core machine, UNGM UKF, T = 500, ``--policies default,fixed-kappa=0,fixed-both-kappa=5``):

* before streaming (one pass, commit 6d142a5): 10^4 runs 755 MB (15 s), 10^5 runs 5973 MB (308 s):
  59.4 KB per run, so 10^6 runs about 58 GB;
* streamed (chunks of 10^4): 10^4 runs 755 MB (the one-pass evaluation itself), 10^5 runs 783 MB (170 s):
  0.32 KB per run (the kept per-run arrays and O(M) draws), 10^6 runs with all 29 baselines about 1.6 GB;
* the same at commit 91ce088 (the scalar UKF compiled, the bootstrap counts kept per process, 2026-11-27,
  idle cores): 10^4 runs 801 MB (5.7 s), 10^5 runs 815 MB (51.7 s): 0.16 KB per run, 10^6 runs with all 29
  baselines about 1.5 GB. The compiled kernels' import (numba) and the kept counts (80 MB at 10^4) add to
  the level, not to the slope.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import inspect, json, resource, sys, time
from adaptfilt.evaluation import evaluate
from adaptfilt.experiment_registry import get_experiment
a = json.loads(sys.argv[1])
exp = get_experiment(a["experiment"])
pols = [p for p in exp.baselines() if p.name in a["policies"]]
kw = {} if a["chunk_size"] is None or "chunk_size" not in inspect.signature(evaluate).parameters else {"chunk_size": a["chunk_size"]}
t = time.perf_counter()
res = evaluate(exp, pols, n_runs=a["runs"], progress=False, n_steps=a["horizon"], **kw)
print(json.dumps({"wall_s": time.perf_counter() - t, "rmse": res[pols[0].name].rmse}))
"""


def measure(runs: int, args) -> tuple[float, float]:
    """``(peak MB, wall s)`` of one evaluation in a child process."""
    import resource

    spec = dict(experiment=args.experiment, policies=args.policies.split(","), runs=runs, horizon=args.horizon,
                chunk_size=args.chunk_size)
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(spec)], check=True, capture_output=True, text=True)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # KB on Linux; the largest child so far
    if peak <= before and before:
        print(f"  (M = {runs}: peak below an earlier child's; run the sizes in increasing order)", file=sys.stderr)
    return peak / 1024, json.loads(out.stdout.strip().splitlines()[-1])["wall_s"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", type=int, nargs="+", default=[10_000, 100_000])
    p.add_argument("--experiment", default="ungm-ukf")
    p.add_argument("--policies", default="default,fixed-kappa=0,ml")
    p.add_argument("--horizon", type=int, default=None)
    p.add_argument("--chunk-size", type=int, default=None, help="default: the library's CHUNK_SIZE")
    p.add_argument("--quick", action="store_true", help="2000 and 8000 runs of 50 steps")
    args = p.parse_args(argv)
    if args.quick:
        args.runs, args.horizon = [2000, 8000], args.horizon or 50
    runs = sorted(args.runs)
    peaks = []
    for m in runs:
        mb, wall = measure(m, args)
        peaks.append(mb)
        print(f"M = {m:>8}: peak {mb:8.0f} MB, {wall:7.1f} s wall", flush=True)
    if len(runs) > 1:
        per_run = (peaks[-1] - peaks[-2]) * 2**20 / (runs[-1] - runs[-2])
        from adaptfilt.experiment_registry import get_experiment

        n_all = len(get_experiment(args.experiment).baselines())
        ext = peaks[-1] + (10**6 - runs[-1]) * (per_run + 24 * (n_all - len(args.policies.split(",")))) / 2**20
        print(f"{per_run / 1024:.2f} KB per run between M = {runs[-2]} and {runs[-1]}; "
              f"10^6 runs with all {n_all} baselines: about {ext:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
