"""Wall time per step of the look-ahead references against greedy, to size the look-ahead study.

    python benchmarks/bench_lookahead.py [--runs 100] [--steps 16] [--experiments ungm-ukf ctm-ukf]
                                         [--configs greedy twostep:4 rollout:1:4 ...]

For each experiment, one set of ``--runs`` trajectories; each policy
(``greedy``, ``twostep:S``, ``rollout:H:S``, gamma 0.5, measurements from the
filter's predictive) drives its own episode of ``--steps`` steps, and
``policy.act(decision)`` is timed at every step whose look-ahead is not cut
by the episode's end (``t + H_max < steps - 1``), so every timed step does
the full ``H``. Printed per policy: wall and CPU seconds per step (mean over
the timed steps; the environment's own update and predict are not in it),
both per 1000 runs, the ratio to greedy's, and the compute charged per run
and step (``extra_spent``, in the rule's unit: UKF updates, SIF iterations),
the figure the cost model predicts the time from. On a shared machine the
CPU time is the better yardstick; the load average is printed before and after.

Measured 2026-11-25 (defaults: M = 100, 16 steps, 11 timed; 2 cores shared with
a data run, load 4.6-5.3), seconds of wall time per step and ratio to greedy:

=================  =================  =================  ===========================
policy             UNGM-UKF (G = 13)  CTM-UKF (G = 12)   spent/run/step UNGM / CTM
=================  =================  =================  ===========================
greedy             0.0008 (1)         0.0029 (1)         13 / 12
twostep-S4         0.034 (44)         0.131 (45)         702 / 588
rollout-H1-S4      0.028 (36)         0.172 (59)         702 / 588
rollout-H1-S16     0.104 (134)        0.747 (255)        2730 / 2316
rollout-H2-S4      0.048 (62)         0.284 (97)         1430 / 1164
rollout-H2-S16     0.209 (270)        1.122 (383)        5642 / 4620
rollout-H4-S4      0.094 (121)        0.481 (164)        2886 / 2316
=================  =================  =================  ===========================

``--experiments ctm-sif-nis --runs 50 --steps 8`` (unit: SIF iterations; 5
timed steps): greedy 0.026 s (30), twostep-S4 0.41 s (16x; 1110),
rollout-H1-S4 0.20 s (7.7x; 1110), rollout-H2-S4 0.31 s (12x; 2190).

The time follows the compute count: about 0.4 us per UKF update of one run
on UNGM (``nx = 1``) and 2.5-3 us on the CTM (``nx = 4``), so an episode
costs about ``spent * M * T`` times that (UNGM, ``H = 2``, ``S = 16``,
``M = 10^4``, ``T = 500``: about 3 hours on this machine). Greedy's small
batches are dominated by fixed overheads, hence ratios to greedy above the
ratios of the counts.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from adaptfilt.experiment_registry import get_experiment
from adaptfilt.lookahead import RolloutPolicy, TwoStepPolicy
from adaptfilt.policies import GreedyPolicy

DEFAULT_CONFIGS = ("greedy", "twostep:4", "rollout:1:4", "rollout:1:16", "rollout:2:4", "rollout:2:16", "rollout:4:4")


def make_policy(spec: str, grid):
    """``greedy``, ``twostep:S`` or ``rollout:H:S`` -> (policy, H)."""
    kind, *nums = spec.split(":")
    if kind == "greedy" and not nums:
        return GreedyPolicy(grid), 0
    if kind == "twostep" and len(nums) == 1:
        return TwoStepPolicy(grid, samples=int(nums[0])), 1
    if kind == "rollout" and len(nums) == 2:
        return RolloutPolicy(grid, horizon=int(nums[0]), samples=int(nums[1])), int(nums[0])
    raise SystemExit(f"bad config {spec!r}: greedy, twostep:S or rollout:H:S")


def time_policy(env, pol, traj, h_max: int) -> tuple[float, float, float]:
    """Mean wall and CPU seconds of ``pol.act`` per timed step, and its ``extra_spent`` per run and step."""
    d, walls, cpus, spent = env.reset(traj=traj), [], [], []
    while d is not None:
        timed = d.t + h_max < env.n_steps - 1
        w0, c0 = time.perf_counter(), time.process_time()
        a = pol.act(d)
        if timed:
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
            spent.append(d.extra_spent)
        d, *_ = env.step(a)
    if not walls:
        raise SystemExit(f"--steps too short: no step has a full look-ahead of {h_max}")
    return float(np.mean(walls)), float(np.mean(cpus)), float(np.mean(spent))


def load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg()) + f" on {os.cpu_count()} cpus"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--steps", type=int, default=16)
    ap.add_argument("--experiments", nargs="+", default=["ungm-ukf", "ctm-ukf"])
    ap.add_argument("--configs", nargs="+", default=list(DEFAULT_CONFIGS))
    args = ap.parse_args()
    print(load())
    for name in args.experiments:
        exp = get_experiment(name)
        env = exp.make_env(seed=0, n_steps=args.steps)
        traj = env.truth.simulate(args.runs, args.steps + 1, rng=np.random.default_rng(0))
        pols = [make_policy(s, exp.grid) for s in args.configs]
        h_max = max(h for _, h in pols)
        n_timed = sum(t + h_max < args.steps - 1 for t in range(args.steps))
        print(f"\n{name}: G = {len(exp.grid)}, M = {args.runs} runs, {n_timed} timed steps of {args.steps}, "
              f"unit: {env.filt.rule.compute_unit}")
        print(f"  {'policy':<16} {'wall s/step':>12} {'per 1000 runs':>14} {'CPU s/step':>11} {'x greedy (wall)':>16} "
              f"{'x greedy (CPU)':>15} {'spent/run/step':>15}")
        base = None
        for pol, _ in pols:
            wall, cpu, spent = time_policy(env, pol, traj, h_max)
            base = base or (wall, cpu)
            print(f"  {pol.name:<16} {wall:12.4f} {wall * 1000 / args.runs:14.3f} {cpu:11.4f} {wall / base[0]:16.1f} "
                  f"{cpu / base[1]:15.1f} {spent:15.0f}")
    print("\n" + load())


if __name__ == "__main__":
    main()
