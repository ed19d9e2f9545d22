"""Speed of the actor-critic training loop (Algorithm 2) on UNGM-UKF.

    python benchmarks/bench_train.py [--episodes 5] [--batches 10] [--parallel 100]

* paper-faithful mode (``parallel=1``): milliseconds per environment step,
  including the filter update/predict, the three network evaluations, one
  backward pass, two Adam steps and the Polyak update. Target <= 1 ms/step
  (1000 episodes x 500 steps in < ~9 min).
* vectorised mode (``parallel=B``): wall time per 5x10^5 transitions
  (= 1000 episodes of 500 steps), extrapolated from ``--batches`` batches.
  Target < 60 s.

Both with 1 and 2 torch threads (``train`` defaults to 1).
"""
from __future__ import annotations

import argparse
import time

from adaptfilt.actor_critic import train


def timed(**kw) -> float:
    t0 = time.perf_counter()
    train("ungm-ukf", progress=False, **kw)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=5, help="faithful-mode episodes to time")
    ap.add_argument("--batches", type=int, default=10, help="vectorised-mode batches to time")
    ap.add_argument("--parallel", type=int, nargs="+", default=[10, 100], help="vectorised batch sizes B")
    args = ap.parse_args()
    T = 500
    # the scaler fit (a 64-run default rollout) is part of every call: time it once and subtract
    base = timed(episodes=1, parallel=1, n_steps=2)
    print(f"setup (scaler fit, networks): {base:.2f} s (subtracted below)")
    for threads in (1, 2):
        wall = timed(episodes=args.episodes, parallel=1, torch_threads=threads) - base
        ms = 1e3 * wall / (args.episodes * T)
        print(f"faithful  threads={threads}: {ms:.3f} ms/step -> 1000 episodes x {T} steps: {ms * 5e2:.0f} s")
        for B in args.parallel:
            wall = timed(episodes=args.batches * B, parallel=B, torch_threads=threads) - base
            per = wall / (args.batches * B * T) * 5e5
            print(f"vectorised B={B:<4d} threads={threads}: {1e3 * wall / (args.batches * T):.3f} ms/batched step "
                  f"-> 5e5 transitions: {per:.1f} s ({5e5 / (B * T) * T:.0f} updates)")


if __name__ == "__main__":
    main()
