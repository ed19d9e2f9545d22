"""Speed of the batched filters against filterpy's UKF, on the paper's two models.

Run with ``python benchmarks/bench_filters.py`` (``--quick`` for a smoke run).
Prints a table of run-steps per second (one filter step of one Monte-Carlo run)
and the speed-up over filterpy's ``UnscentedKalmanFilter`` with
``JulierSigmaPoints`` (the same kappa, the same simulated data):

* UNGM, UKF: ours on M = 10^4 runs x T = 500 steps; filterpy on a subset of
  runs (its cost per step does not depend on M), extrapolated per step.
* CTM, UKF: M = 10^4, T = 150. Our CTM model declares its dynamics linear
  (``model.F``), so our predict is the exact Kalman predict while filterpy
  pushes sigma points through ``f``; for fairness the table also reports ours
  on a copy of the model without ``F`` (generic unscented predict).
* CTM, SIF with 10 iterations, M = 10^4: wall time.

Timing: ours is timed once cold (the first full-size run in the process, which
pays for first-touch memory) and then as the best of ``--repeat`` runs; the
speed-up uses the best time, as ``timeit`` does. filterpy is timed as the best
of ``--repeat`` loops too. The ``cpu s`` column is the process CPU time of
the best run: on a shared machine wall time exceeds it, and the ``(cpu)``
speed-up (ratio of CPU times) is the steadier figure. Before timing, the script checks that both filters
give the same estimates on the filterpy subset (max relative difference shown).

Targets (set when the filters were first written): UKF >= 1000x filterpy on UNGM and >= 500x on CTM; SIF-10 on
CTM with M = 10^4 under 10 s.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import time

import numpy as np

import adaptfilt as af
from adaptfilt.linalg import wrap_angle


def filterpy_loop(model, z, kappa, bearing):
    """filterpy's UKF over the runs of ``z (m, T, nz)``, one run after another.

    The natural filterpy loop (predict, update) plus the bridges to our
    conventions: the first step is an update of the prior (no predict), the
    model functions get the paper's time index, and for bearings the residual
    wraps and the predicted bearing is the circular mean about the centre
    sigma point (as in :mod:`adaptfilt.rules`).
    """
    import filterpy
    from filterpy.kalman import JulierSigmaPoints, UnscentedKalmanFilter

    # filterpy >= 2 redraws sigma points from (x_pred, P_pred) at the end of
    # predict, as Algorithm 1 does; 1.4.x keeps the propagated ones, so redraw here
    redraw = int(filterpy.__version__.split(".")[0]) < 2
    n, nz = model.nx, model.nz
    points = JulierSigmaPoints(n, kappa=kappa)
    kw = {}
    if bearing:

        def z_mean(sigmas, Wm):
            z0 = sigmas[0]
            return z0 + Wm @ wrap_angle(sigmas - z0)

        kw = dict(z_mean_fn=z_mean, residual_z=lambda a, b: wrap_angle(a - b))
    ukf = UnscentedKalmanFilter(n, nz, 1.0, hx=model.h, fx=lambda x, dt, k: model.f(x, k), points=points, **kw)
    m, T = z.shape[:2]
    mean, cov = np.empty((m, T, n)), np.empty((m, T, n, n))
    for r in range(m):
        ukf.x, ukf.P, ukf.Q, ukf.R = model.m0.copy(), model.P0.copy(), model.Q, model.R
        ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)  # first step: update of the prior
        for t in range(T):
            if t:
                ukf.predict(k=t)
                if redraw:
                    ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)
            ukf.update(z[r, t], k=t + 1)
            mean[r, t], cov[r, t] = ukf.x, ukf.P
    return mean, cov


def best_time(fn, repeat):
    """Best wall time of ``repeat`` calls (and the CPU time of that call)."""
    best, out = (np.inf, np.inf), None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        best = min(best, (wall, cpu))
    return best, out


def rel_diff(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=10_000, help="Monte-Carlo runs M for ours (default 10^4)")
    ap.add_argument("--fp-runs", type=int, default=20, help="runs for filterpy (default 20)")
    ap.add_argument("--repeat", type=int, default=3, help="timed repetitions; the best counts (default 3)")
    ap.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    args = ap.parse_args(argv)
    M, mfp, rep = args.runs, args.fp_runs, args.repeat
    if args.quick:
        M, mfp, rep = 500, 3, 1

    print(f"adaptfilt {af.__version__}, numpy {np.__version__}, python {platform.python_version()}, "
          f"{os.cpu_count()} CPUs; M = {M}, filterpy runs = {mfp}, best of {rep}")
    rows = []

    def bench_ukf(label, model, kappa, T, bearing, fp_result=None):
        traj = model.simulate(n_runs=M, n_steps=T, rng=np.random.default_rng(0))
        ukf = af.UKF(model, kappa=kappa)
        t0 = time.perf_counter()
        run = ukf.run(traj.z)
        cold = time.perf_counter() - t0
        (best, cpu), _ = best_time(lambda: ukf.run(traj.z), rep)
        if fp_result is None:
            (t_fp, c_fp), fp_result = best_time(lambda: filterpy_loop(model, traj.z[:mfp], kappa, bearing), rep)
            fp_result = (t_fp, c_fp, fp_result)
        t_fp, c_fp, (fp_mean, fp_cov) = fp_result
        diff = max(rel_diff(run.mean[:mfp], fp_mean), rel_diff(run.cov[:mfp], fp_cov))
        ours = M * T / best
        fp = mfp * T / t_fp
        rows.append((label, f"{M}x{T}", f"{cold:.2f}", f"{best:.2f}", f"{cpu:.2f}", f"{ours:,.0f}", f"{fp:,.0f}", f"{ours / fp:,.0f}x",
                     f"{(M * T / cpu) / (mfp * T / c_fp):,.0f}x", f"{diff:.1e}"))
        return fp_result

    ungm, ctm = af.models.ungm(), af.models.coordinated_turn()
    T_ungm, T_ctm = (500, 150) if not args.quick else (100, 50)
    bench_ukf("UNGM  UKF kappa=2", ungm, 2.0, T_ungm, False)
    fp = bench_ukf("CTM   UKF kappa=0 (F: exact predict)", ctm, 0.0, T_ctm, True)
    ctm_generic = dataclasses.replace(ctm, F=None, name="ctm-generic")
    bench_ukf("CTM   UKF kappa=0 (no F: unscented predict)", ctm_generic, 0.0, T_ctm, True, fp_result=fp)

    head = ("filter", "M x T", "cold s", "best s", "cpu s", "ours steps/s", "filterpy steps/s", "speed-up", "(cpu)", "max rel diff")
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    line = lambda cells: "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))
    print()
    print(line(head))
    print(line(["-" * w for w in widths]))
    for r in rows:
        print(line(r))

    traj = ctm.simulate(n_runs=M, n_steps=T_ctm, rng=np.random.default_rng(0))
    print()
    # the generic-predict SIF is slow (10 stochastic predicts per step): timed once
    for label, model, r in (("F: exact predict", ctm, rep), ("no F: SI predict", ctm_generic, 1)):
        sif = af.SIF(model, n_iter=10, seed=0)
        (cold, cold_cpu), _ = best_time(lambda: sif.run(traj.z), 1)
        (best, cpu), _ = best_time(lambda: sif.run(traj.z), r - 1) if r > 1 else ((cold, cold_cpu), None)
        print(f"CTM   SIF n_iter=10 ({label}), M x T = {M}x{T_ctm}: cold {cold:.2f} s, best {best:.2f} s "
              f"(cpu {cpu:.2f} s), {M * T_ctm / best:,.0f} steps/s")
    print("\ntargets: UKF >= 1000x filterpy on UNGM, >= 500x on CTM; SIF-10 CTM M=10^4 < 10 s")
    if hasattr(os, "getloadavg"):
        print(f"load average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs "
              "(wall times above the cpu times mean the machine was shared)")


if __name__ == "__main__":
    main()
