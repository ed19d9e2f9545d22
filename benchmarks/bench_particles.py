"""Speed of the particle filter with a per-run, per-step particle count (adaptfilt.particles).

Run with ``python benchmarks/bench_particles.py`` (``--quick`` for M = 100, T = 100). One core
(``OMP_NUM_THREADS=1`` is set before numpy loads). Prints the wall and CPU time of UNGM with
M = 1000 runs, T = 500 steps and N = 1000 particles (5e8 particle-steps), the particle-steps per
CPU second, and the share spent drawing the per-run random streams, against the issue 24 target:
under 30 s on one core. A second row runs counts that differ per run and step (drawn from
50-2000, mean about 1000) to show what padding to the batch's largest count costs.
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import adaptfilt as af  # noqa: E402
from adaptfilt.particles import ParticleCountFilter  # noqa: E402


def timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    M, T, N = (100, 100, 1000) if args.quick else (1000, 500, 1000)
    model = af.models.ungm()
    traj = model.simulate(n_runs=M, n_steps=T, rng=0)
    pf = ParticleCountFilter(model, seed=0)
    rng_only = lambda: [pf._rngs(i, t)[1].standard_normal(N) for t in range(T) for i in range(M)]  # noqa: E731
    _, _, c_rng = timed(rng_only)
    counts = np.random.default_rng(1).integers(50, 2001, size=(M, T))
    print(f"UNGM, M = {M}, T = {T}  ({os.cpu_count()} cores visible, one used)")
    print(f"{'counts':>22} {'particle-steps':>15} {'wall s':>8} {'cpu s':>8} {'Mps/cpu-s':>10}")
    for label, n in ((f"fixed N = {N}", N), ("per run/step 50-2000", counts)):
        run, wall, cpu = timed(lambda: pf.run(traj.z, n))
        ps = run.params.sum()
        print(f"{label:>22} {ps:15.3g} {wall:8.1f} {cpu:8.1f} {ps / cpu / 1e6:10.1f}")
    print(f"drawing the streams alone (fixed N): {c_rng:.1f} cpu s")
    scale = 5e8 / (M * T * N)
    print(f"target: 5e8 particle-steps under 30 s on one core"
          + (f" (quick run: x{scale:.0f} to extrapolate)" if scale != 1 else ""))


if __name__ == "__main__":
    main()
