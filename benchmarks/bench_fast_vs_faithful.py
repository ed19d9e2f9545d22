"""Fast trainer (SB3 PPO with large batches, through adaptfilt.gym) vs Algorithm 2 as printed, at the seed level.

Prints, from the stored evaluation in data/ (``adaptfilt reproduce``): for UNGM-UKF and CTM-UKF, the
8 fast-mode policies (``adaptive-s*``) against the 8 paper-faithful ones (``adaptive-faithful-s*``) on the
same 10^4 paired runs: IQM over seeds with two-level (seeds x runs) 95 % intervals, the difference and the
verdict (target: not worse on cost, RMSE and ANEES). Then times the training of one policy of each kind
on one core, in this run (the target: <= 30 s wall per UNGM policy for the fast mode):

    python benchmarks/bench_fast_vs_faithful.py [--faithful-episodes 20] [--no-timing]

The faithful time is measured on ``--faithful-episodes`` episodes and scaled to 1000 (its cost is linear
in episodes: one Adam step per time step). Compare the two times measured in the same run only.
"""
from __future__ import annotations

import argparse
import os
import time

import torch


def timing(faithful_episodes: int) -> None:
    from adaptfilt.trainers import train_policy

    torch.set_num_threads(1)
    load = os.getloadavg()[0]
    for exp in ("ungm-ukf", "ctm-ukf"):
        t, c = time.perf_counter(), time.process_time()
        train_policy(exp, "fast", 0.5, episodes=1000, seed=0, progress=False)
        fw, fc = time.perf_counter() - t, time.process_time() - c
        t, c = time.perf_counter(), time.process_time()
        train_policy(exp, "faithful", 0.5, episodes=faithful_episodes, seed=0, progress=False)
        scale = 1000 / faithful_episodes
        aw, ac = (time.perf_counter() - t) * scale, (time.process_time() - c) * scale
        print(f"{exp}: fast (1000 episodes) {fw:.1f} s wall, {fc:.1f} s CPU | faithful (1000 episodes, "
              f"scaled from {faithful_episodes}) {aw:.0f} s wall, {ac:.0f} s CPU | CPU ratio {ac / fc:.0f}x")
    print(f"(load average at the start: {load:.2f}, one torch thread)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faithful-episodes", type=int, default=20)
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args()
    from adaptfilt.experiments import artefacts
    from adaptfilt.experiments.fast_vs_faithful import comparison, comparison_md

    results = {e: artefacts.load_results(e) for e in ("ungm-ukf", "ctm-ukf")}
    comp = comparison(results)
    if comp:
        print(comparison_md(comp))
    else:
        print("data/ holds no adaptive-faithful-s* policies: run `adaptfilt reproduce --out data --faithful` first")
    if not args.no_timing:
        timing(args.faithful_episodes)


if __name__ == "__main__":
    main()
