"""Speed of the SIF candidate updates: the prefix-average path against the tiled path.

    python benchmarks/bench_candidates.py [--runs 10000] [--episode-runs 2000] [--steps 150] [--repeats 3]

The MDP evaluates the update under every grid value at once
(:meth:`adaptfilt.gaf.GaussianAssumedFilter.update_candidates_rl`). Tiled, the
SIF makes ``max(grid) = 30`` draws on ``G * M = 9 M`` runs; with a fixed count
the ``n_iter = k`` candidate is the average of the first ``k`` draws, so the
prefix path makes the 30 draws once on ``M`` runs and keeps the running sums at
every grid value.

(a) one candidates computation of ``ctm-sif-nis`` (CTM, grid 1 .. 30) at step 5
    of a SIF run, ``M = --runs``: best and median of ``--repeats`` calls each
    way (interleaved, so both see the same load), and the ratio;
(b) a whole greedy evaluation episode (``rollout`` with ``GreedyPolicy``),
    ``M = --episode-runs``, ``T = --steps``, both ways, with a check that the
    choices are identical.

Prints wall and CPU time and the load average before and after: on a shared
machine the CPU time is the better yardstick, and the ratio is measured in one
run.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from adaptfilt.experiment_registry import get_experiment
from adaptfilt.mdp import rollout
from adaptfilt.policies import GreedyPolicy

EXPERIMENT = "ctm-sif-nis"


def timed(fn):
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg()) + f" on {os.cpu_count()} cpus"


def bench_candidates(runs: int, repeats: int) -> None:
    exp = get_experiment(EXPERIMENT)
    filt = exp.make_filter(seed=0)
    grid = np.asarray(exp.grid, dtype=float)
    traj = filt.model.simulate(runs, 6, rng=0)
    run = filt.run(traj.z[:, :6], keep_pred=True)
    t = 5
    m, P, z = run.x_pred[:, t].T.copy(), np.moveaxis(run.P_pred[:, t], 0, -1).copy(), traj.z[:, t].T.copy()
    times = {True: [], False: []}
    outs = {}
    for _ in range(repeats):
        for prefixes in (False, True):
            filt.candidate_prefixes = prefixes
            outs[prefixes], wall, cpu = timed(lambda: filt.update_candidates_rl(m, P, z, t, grid, rng=filt.rng(1, t, 0)))
            times[prefixes].append((wall, cpu))
    a, b = outs[True].x_filt, outs[False].x_filt
    rel = float(np.abs(a - b).max() / np.abs(b).max())
    print(f"(a) one candidates computation, {EXPERIMENT}, grid {grid.astype(int).tolist()}, M = {runs}, {repeats} calls each")
    for prefixes, label in ((False, "tiled "), (True, "prefix")):
        w = np.array(times[prefixes])
        print(f"    {label}: best {w[:, 0].min():7.3f} s wall, median {np.median(w[:, 0]):7.3f} s wall, "
              f"median {np.median(w[:, 1]):7.3f} s CPU")
    wt, wp = np.array(times[False]), np.array(times[True])
    print(f"    ratio tiled/prefix: {wt[:, 0].min() / wp[:, 0].min():.1f}x (best wall), "
          f"{np.median(wt[:, 1]) / np.median(wp[:, 1]):.1f}x (median CPU); max |x_filt| rel. difference {rel:.1e}")


def bench_episode(runs: int, steps: int) -> None:
    exp = get_experiment(EXPERIMENT)
    traj = exp.make_env(n_steps=steps).model.simulate(runs, steps + 1, rng=1)
    res = {}
    for prefixes in (False, True):
        env = exp.make_env(seed=0, n_steps=steps)
        env.filt.candidate_prefixes = prefixes
        res[prefixes] = timed(lambda: rollout(env, GreedyPolicy(), traj=traj, stream=0))
    (fast, cf), wp, cp = res[True]
    (slow, cs), wt, ct = res[False]
    same = bool(np.array_equal(fast.params, slow.params))
    rel = float(np.abs(cf - cs).max() / np.abs(cs).max())
    print(f"(b) greedy evaluation episode, {EXPERIMENT}, M = {runs}, T = {steps}")
    print(f"    tiled : {wt:7.1f} s wall, {ct:7.1f} s CPU")
    print(f"    prefix: {wp:7.1f} s wall, {cp:7.1f} s CPU")
    print(f"    ratio tiled/prefix: {wt / wp:.1f}x wall, {ct / cp:.1f}x CPU; "
          f"choices identical: {same}; max cost rel. difference {rel:.1e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10_000, help="runs of the single candidates computation (a)")
    ap.add_argument("--episode-runs", type=int, default=2000, help="runs of the greedy episode (b)")
    ap.add_argument("--steps", type=int, default=150, help="steps of the greedy episode (b)")
    ap.add_argument("--repeats", type=int, default=3, help="calls each way in (a)")
    args = ap.parse_args()
    print(load())
    bench_candidates(args.runs, args.repeats)
    print(load())
    bench_episode(args.episode_runs, args.steps)
    print(load())


if __name__ == "__main__":
    main()
