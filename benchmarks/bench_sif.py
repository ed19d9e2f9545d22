"""The SIF variants of the authors' reference codes: cost, accuracy, filter quality.

Run with ``python benchmarks/bench_sif.py`` (``--quick`` for a smoke run).
Three parts, all on the paper's CTM (bearing-only coordinated turn):

1. **Cost per iteration** at ``M = 10^4`` runs: one moment computation of the
   CTM's first update (prior ``N(m0, P0)``) with 10 iterations of the degree-3
   rule (today's default) and of the degree-5 rule, interleaved, best of
   ``--repeat``; wall and process-CPU time per iteration and their ratio
   (the target set for the SIF's degree 5: within 2x of degree 3 per iteration).
   Then **per-run counts**: one moment computation where the runs pick their
   own ``n_iter`` as a learned policy does (most few, some many), against every
   run at the largest count and at the mean count: a draw is evaluated only for
   the runs still iterating, so the batch should cost about what its mean
   count costs, plus the random numbers of the largest count for all runs.
2. **Accuracy of the first update**: the RMS error, over ``M`` independent
   replicates, of ``z_pred``, ``Pzz`` and ``Pxz`` against a 2-D polar Gauss-Legendre
   reference (the bearing depends on ``px, py`` only, independent of the
   velocities under ``P0``; the reference integrates the same wrapped
   deviation ``wrap(h(x) - h(m))`` the rule does), for degree 3 and 5 and
   several iteration counts: the claim "one degree-5 iteration is about as
   accurate as ten degree-3 ones".
3. **Filter quality**, ``M = 2000`` runs x ``T = 150`` steps, the same
   trajectories for every filter: time-averaged RMSE and ANEES, the fraction of
   divergent runs (final error norm > 1e3 or non-finite), the repairs of
   indefinite covariances (``on_indefinite="clip"``, as the experiments run),
   for ``n_it = 1, 2, 3, 5, 10`` without and with the integration-error term,
   for the default rule (degree 3, one pass) and the references' structure
   (degree 5, two passes); and Stone Soup's full preset (``SIF.reference``:
   5..10 iterations by tolerance). Pooled over ``--seeds`` data-and-filter
   seeds (one divergent run dominates RMSE and ANEES, so seeds matter).

4. **The rule's implementation, before and after** (``--speed``: this part alone):
   CPU time (``time.process_time``, best of ``--speed-repeat``, the variants
   interleaved) of (a) training a SIF policy, ``train_policy("ctm-sif-nis",
   "fast", 0.5, 100, 0)``, (c) the moments at 256 runs (below), and (b) the default SIF (``on_indefinite="clip"``) on ``M = 10^4`` CTM runs,
   ``T = 150``, 10 iterations, under three implementations of the rule: the
   baseline (the methods of ``adaptfilt/rules/stochastic.py`` at
   ``--baseline``, a git revision, swapped in: numpy Gram-Schmidt, scattered
   sums), today's rule with the numpy Gram-Schmidt
   (``adaptfilt.linalg_kernels.BACKEND = "numpy"``: the bookkeeping alone)
   and today's rule with the compiled one (numba). All three must give the
   same numbers: the benchmark checks the policies' parameters and the runs'
   outputs bit for bit and says so. Measured (shared 2-core Intel Xeon, load
   about 6, best of 3): (a) 5.07 -> 3.79 (bookkeeping) -> 2.72 CPU-s
   (compiled), 1.86x; (b) 12.10 -> 12.04 -> 11.23 CPU-s, 1.08x (a fixed
   count has no subsets; what is left is the draws, about 38 %, the weighted
   sums and the bearing, outside the rule's own code). The compiled kernel
   costs about 0.25 CPU-s once per process (loading numba's cache).
   A fourth variant adds the compiled point construction and weighted sums
   (``_sif_kernels.points`` / ``weighted_sums``, bit for bit numpy's einsum;
   ``linalg_kernels.SUMS = False`` turns them off). Measured (same machine, load
   about 5, best of 3, the test suite running beside it during (a)): (a) 3.34
   (baseline) -> 2.81 -> 2.07 (compiled Gram-Schmidt) -> 2.17 CPU-s (with the
   sums: 0.95x, within the noise of that load; per call the kernels are 0.99x
   at 20 runs, 1.2x at 200, 1.4x at 1000); (b) 8.74 -> 8.49 -> 7.87 -> 7.13
   CPU-s, the sums 1.10x, 1.23x in all.
   The fourth variant is now the fused draw (``StochasticIntegrationRule._recursion_fused``: per draw one
   compiled call for the points, the model's ``h`` and residual, one compiled call for the sums and the
   recursion's state; degree 3, fixed counts), and (c) times the training's case alone: 20 moment
   computations at ``M = 256`` with per-run counts from the SIF grid, ``passes=2, integration_error="diag"``.
   Measured (load about 1.5-3.5, best of 3): (a) 3.63 -> 2.54 -> 1.86 -> 1.48 CPU-s (the fused draws
   alone 1.26x); (b) 9.90 -> 9.93 -> 9.51 -> 7.14 (1.33x); (c) 0.30 -> 0.25 -> 0.17 -> 0.12 (1.42x).
   Against the rule before the fused draws (the previous compiled points and sums, a checkout of that
   commit, same session): one such moment computation 8.7-8.9 -> 6.0-6.2 ms (145-149 -> 100-103 us per
   draw, of which the random draws themselves are 62-77 us).

5. **The random draws** (``--draws``: this part alone): one degree-3 draw's variates (``(5, 5, M)``
   normals and ``M`` chi-square radii) by numpy's two calls and by
   :func:`adaptfilt.rules._sif_kernels.rule3_draws` (numba's port of the same algorithms: the same
   bits and the same generator state, checked here), per draw and per block of 8 draws, at the
   training's ``M = 256`` and the evaluation's ``M = 10^4``, best of ``--repeat``, ns per normal.
   Measured (idle 2-core Xeon, best of 7): numpy about 13 ns a normal at M = 10^4, compiled about 4-5
   (in the evaluation, the default SIF at M = 10^4: draws 7.7 -> 3.5 s of 18.0 -> 14.4 CPU-s).

The benchmark imports ``adaptfilt`` as installed; from a checkout that is not
the installed one, run it as ``PYTHONPATH=. python benchmarks/bench_sif.py``.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import adaptfilt as af
from adaptfilt.linalg import wrap_angle
from adaptfilt.rules import StochasticIntegrationRule


def first_update_problem(M: int):
    """The CTM's first update for ``M`` runs: run-last ``m``, ``P``, ``L`` and the wrapped ``h``."""
    model = af.models.coordinated_turn()
    sif = af.SIF(model)
    m = np.repeat(model.m0[:, None], M, 1)
    P = np.repeat(model.P0[:, :, None], M, 2)
    L = np.repeat(np.linalg.cholesky(model.P0)[:, :, None], M, 2)
    return model, m, P, L, sif._wrap(model.h, 1), sif._residual_rl()


def cost_per_iteration(M: int, n_iter: int, repeat: int) -> dict:
    _, m, P, L, h, res = first_update_problem(M)
    rules = {"degree 3 (default)": StochasticIntegrationRule(order=3),
             "degree 5": StochasticIntegrationRule(order=5),
             "degree 5, two passes": StochasticIntegrationRule(order=5, passes=2)}
    wall = {k: np.inf for k in rules}
    cpu = {k: np.inf for k in rules}
    for rep in range(repeat):  # interleaved, so that load on a shared machine hits all alike
        for name, rule in rules.items():
            t0, c0 = time.perf_counter(), time.process_time()
            rule.moments(h, m, P, n_iter, residual=res, rng=np.random.default_rng(rep), L=L)
            per = rule.passes * n_iter
            wall[name] = min(wall[name], (time.perf_counter() - t0) / per)
            cpu[name] = min(cpu[name], (time.process_time() - c0) / per)
    return {"wall": wall, "cpu": cpu}


def arctan2_floor(points: int, M: int, repeat: int) -> float:
    """Best wall time of numpy's arctan2 on ``points x M`` values: what the bearing alone costs one
    degree-5 iteration, whatever the rule's own arithmetic costs."""
    rng = np.random.default_rng(0)
    y, x = rng.standard_normal((points, M)), rng.standard_normal((points, M))
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        np.arctan2(y, x)
        best = min(best, time.perf_counter() - t0)
    return best


def cost_per_run_counts(M: int, repeat: int, seed: int = 0) -> dict:
    """Wall time of one degree-3 moment computation with per-run counts (80 % of the runs at 2,
    15 % at 5, 5 % at 30, as a learned SIF policy spreads them) against all runs at 30 and at the
    rounded mean count, best of ``repeat``."""
    _, m, P, L, h, res = first_update_problem(M)
    its = np.random.default_rng(seed).choice([2.0, 5.0, 30.0], size=M, p=[0.8, 0.15, 0.05])
    cases = {"per-run (mean %.2f, max 30)" % its.mean(): its, "all at 30": 30.0, "all at %d" % round(its.mean()): float(round(its.mean()))}
    rule = StochasticIntegrationRule(order=3)
    best = {k: np.inf for k in cases}
    for rep in range(repeat):
        for name, n_it in cases.items():
            t0 = time.perf_counter()
            rule.moments(h, m, P, n_it, residual=res, rng=np.random.default_rng(rep), L=L)
            best[name] = min(best[name], time.perf_counter() - t0)
    return best


def reference_first_update(order: int = 400):
    """Moments of the wrapped bearing deviation under the CTM prior, by Gauss-Legendre quadrature in
    polar coordinates about the sensor (2-D in ``px, py``; the velocities are independent of them
    under ``P0``). In polar coordinates the wrapped deviation ``theta - h(m)`` is smooth inside
    ``(-pi, pi)``, so the quadrature converges fast (a Cartesian rule would straddle its jump)."""
    model = af.models.coordinated_turn()
    m0, P0 = model.m0, model.P0
    g0 = np.arctan2(m0[2], m0[0])
    sx, sy = np.sqrt(P0[0, 0]), np.sqrt(P0[2, 2])
    R = np.hypot(m0[0], m0[2]) + 14 * max(sx, sy)
    u, wu = np.polynomial.legendre.leggauss(order)
    r, wr = (u + 1) * R / 2, wu * R / 2
    th, wt = g0 + np.pi * u, wu * np.pi  # theta - g0 in (-pi, pi): the wrapped deviation
    px, py = r[:, None] * np.cos(th[None]), r[:, None] * np.sin(th[None])
    dens = np.exp(-0.5 * (((px - m0[0]) / sx) ** 2 + ((py - m0[2]) / sy) ** 2)) / (2 * np.pi * sx * sy)
    W = wr[:, None] * wt[None] * r[:, None] * dens
    D = np.broadcast_to(th[None] - g0, W.shape)
    mass = W.sum()
    mean = (W * D).sum() / mass
    var = (W * (D - mean) ** 2).sum() / mass
    cross = np.array([(W * (px - m0[0]) * (D - mean)).sum(), 0.0, (W * (py - m0[2]) * (D - mean)).sum(), 0.0]) / mass
    return g0 + mean, var, cross


def accuracy(M: int, seed: int = 0) -> list[tuple]:
    zr, vr, cr = reference_first_update()
    z2, v2, c2 = reference_first_update(300)
    ref_err = max(abs(zr - z2), abs(vr - v2) / vr, np.abs(cr - c2).max() / np.abs(cr).max())
    _, m, P, L, h, res = first_update_problem(M)
    rows = []
    for order, its in ((3, (1, 2, 5, 10, 20)), (5, (1, 2, 5))):
        for n_it in its:
            mo = StochasticIntegrationRule(order=order).moments(h, m, P, n_it, residual=res, rng=np.random.default_rng(seed), L=L)
            ez = np.sqrt(((mo.mean[0] - zr) ** 2).mean())
            ev = np.sqrt(((mo.cov[0, 0] / vr - 1) ** 2).mean())
            ec = np.sqrt(((mo.cross[:, 0] - cr[:, None]) ** 2).sum(0).mean()) / np.linalg.norm(cr)
            rows.append((order, n_it, ez, ev, ec))
    return rows, ref_err


def filter_quality(M: int, T: int, seeds: tuple[int, ...], seeds_deg5: tuple[int, ...]) -> list[tuple]:
    """Pooled over ``seeds`` (each seed: its own trajectories and the filter's own random numbers),
    ``M`` runs per seed. A single divergent run dominates RMSE and ANEES, so several seeds say
    more than one large ``M``."""
    model = af.models.coordinated_turn()
    trajs = {s: model.simulate(M, T, rng=s) for s in set(seeds) | set(seeds_deg5)}
    configs = []
    for label, kw, ss in (("deg 3, 1 pass", dict(order=3, passes=1), seeds), ("deg 5, 2 passes", dict(order=5, passes=2), seeds_deg5)):
        for n_it in (1, 2, 3, 5, 10):
            for ie in (False, "diag"):
                configs.append((label, n_it, ie, ss, lambda s, n_it=n_it, kw=kw, ie=ie: af.SIF(
                    model, n_iter=n_it, seed=s, integration_error=ie, on_indefinite="clip", **kw)))
    configs.append(("SIF.reference", "5..10", "diag", seeds_deg5, lambda s: af.SIF.reference(model, seed=s, on_indefinite="clip")))
    rows = []
    for label, n_it, ie, ss, make in configs:
        se, ne, final, repairs, spent, secs, failed = [], [], [], 0, [], 0.0, []
        for s in ss:
            traj = trajs[s]
            t0 = time.perf_counter()
            try:
                run = make(s).run(traj.z)
            except af.FilterError as e:  # a documented failure (non-finite mean): reported, not hidden
                failed.append(f"seed {s}: {e}"[:80])
                continue
            secs += time.perf_counter() - t0
            se.append(af.metrics.squared_error(traj.x, run.mean))
            with np.errstate(over="ignore", invalid="ignore"):
                ne.append(af.metrics.nees(traj.x, run.mean, run.cov))
            final.append(np.linalg.norm(traj.x[:, -1] - run.mean[:, -1], axis=-1))
            repairs += run.n_repairs
            spent.append(run.info["n_iter_spent"].mean())
        if not se:
            rows.append((label, n_it, ie, len(ss), np.nan, np.nan, np.nan, 0, -1, "; ".join(failed), secs))
            continue
        se, ne, final = np.concatenate(se), np.concatenate(ne), np.concatenate(final)
        divergent = ~np.isfinite(final) | (final > 1e3)
        with np.errstate(over="ignore", invalid="ignore"):
            rmse = af.metrics.time_average(np.sqrt(se.mean(axis=0)))
            anees = af.metrics.time_average(ne.mean(axis=0))
        note = f"{np.mean(spent):.1f} it/step" + (f"; {len(failed)} seed(s) failed" if failed else "")
        rows.append((label, n_it, ie, len(ss), rmse, anees, divergent.mean(), int(divergent.sum()), repairs, note, secs))
    return rows


#: the revision whose ``stochastic.py`` is the baseline of part 4: the parent of the commit that compiled
#: the Gram-Schmidt and removed the scattering of per-draw sums
BASELINE = "e42052d^"


def baseline_rule_methods(rev: str) -> dict:
    """The methods of ``StochasticIntegrationRule`` as ``adaptfilt/rules/stochastic.py`` defines them at
    git revision ``rev``, loaded as a module of their own (their globals: that revision's helpers)."""
    root = Path(__file__).resolve().parents[1]
    src = subprocess.run(["git", "show", f"{rev}:adaptfilt/rules/stochastic.py"], cwd=root, capture_output=True,
                         text=True, check=True).stdout
    name = "adaptfilt.rules._stochastic_baseline"
    spec = importlib.util.spec_from_loader(name, loader=None)
    mod = importlib.util.module_from_spec(spec)
    mod.__file__ = f"<{rev}:adaptfilt/rules/stochastic.py>"
    sys.modules[name] = mod
    exec(compile(src, mod.__file__, "exec"), mod.__dict__)
    return {k: v for k, v in vars(mod.StochasticIntegrationRule).items() if k in vars(StochasticIntegrationRule)
            and (callable(v) or isinstance(v, (staticmethod, property)))}


class _Implementation:
    """Select one implementation of the rule for every instance, old and new, while in the ``with``."""

    def __init__(self, methods: dict | None, backend: str, sums: bool = True):
        self.methods, self.backend, self.sums = methods, backend, sums

    def __enter__(self):
        from adaptfilt import linalg_kernels

        self._saved = {k: vars(StochasticIntegrationRule)[k] for k in (self.methods or {})}
        self._backend, self._sums = linalg_kernels.BACKEND, linalg_kernels.SUMS
        for k, v in (self.methods or {}).items():
            setattr(StochasticIntegrationRule, k, v)
        linalg_kernels.BACKEND, linalg_kernels.SUMS = self.backend, self.sums
        return self

    def __exit__(self, *exc):
        from adaptfilt import linalg_kernels

        for k, v in self._saved.items():
            setattr(StochasticIntegrationRule, k, v)
        linalg_kernels.BACKEND, linalg_kernels.SUMS = self._backend, self._sums


def speed(repeat: int, episodes: int, M: int, T: int, baseline: str) -> None:
    """Part 4: CPU time of a SIF training and a large SIF run under the baseline, the numpy and the
    compiled implementation of the rule, interleaved, best of ``repeat``; outputs compared bit for bit."""
    from adaptfilt.trainers import train_policy
    try:
        old = baseline_rule_methods(baseline)
    except (subprocess.CalledProcessError, ImportError, OSError) as err:  # no git, no such revision, helpers gone
        print(f"(baseline {baseline} unavailable: {str(err).strip()[:200]})")
        old = None
    variants = {"baseline " + baseline: (old, "numpy"), "numpy Gram-Schmidt": (None, "numpy"),
                "compiled Gram-Schmidt": (None, "auto", False), "compiled, fused draws": (None, "auto")}
    if old is None:
        del variants["baseline " + baseline]
    model = af.models.coordinated_turn()
    z = model.simulate(M, T, rng=1).z
    # the work: (a) a training; (b) a run; each returns what must be equal across the variants
    def train():
        pol = train_policy("ctm-sif-nis", "fast", 0.5, episodes, 0, progress=False)
        return _policy_arrays(pol)

    def run():
        r = af.SIF(model, seed=0, on_indefinite="clip").run(z, params=10)
        return [r.mean, r.cov, r.nis, r.loglik]

    # (c) the training's case: one update's moments at 256 runs, per-run counts from the SIF grid, the experiments'
    # form (2 passes, diag), 20 calls
    sif = af.SIF(model, seed=0)
    g, res = sif._wrap(model.h, 1), sif._residual_rl()
    m256, P256 = sif.initial(256)
    counts = np.random.default_rng(1).choice([1, 2, 3, 5, 7, 10, 15, 20, 30], 256).astype(float)
    rule = StochasticIntegrationRule(passes=2, integration_error="diag")

    def moments256():
        out = []
        for i in range(20):
            mo = rule.moments(g, m256, P256, counts, residual=res, rng=np.random.default_rng(i))
            out += [mo.mean, mo.cov, mo.cross, mo.mean_var, mo.n_iter]
        return out

    with _Implementation(None, "auto"):
        af.SIF(model, seed=0, passes=2, integration_error="diag").run(z[:4, :2], params=np.array([1.0, 2, 3, 2]))  # compile (or load) the kernels outside the timings
    for label, work in ((f"(a) train_policy('ctm-sif-nis', 'fast', 0.5, {episodes}, 0)", train),
                        (f"(b) SIF(ctm, seed=0, on_indefinite='clip').run(z, params=10), M = {M}, T = {T}", run),
                        ("(c) 20 x rule.moments at M = 256, per-run counts (grid, max 30), passes=2, diag", moments256)):
        best = {k: np.inf for k in variants}
        outputs = {}
        for _ in range(repeat):
            for name, spec in variants.items():
                with _Implementation(*spec):
                    c0 = time.process_time()
                    out = work()
                    best[name] = min(best[name], time.process_time() - c0)
                outputs.setdefault(name, out)
        ref = next(iter(outputs.values()))
        same = all(len(o) == len(ref) and all(np.array_equal(a, b, equal_nan=True) for a, b in zip(o, ref))
                   for o in outputs.values())
        first = next(iter(best.values()))
        print(label + ("   outputs bit for bit equal: yes" if same else "   OUTPUTS DIFFER"))
        for name, sec in best.items():
            print(f"  {name:32s} {sec:8.2f} CPU-s   {first / sec:5.2f}x")
        if "compiled Gram-Schmidt" in best:
            print(f"  (the fused draws alone: {best['compiled Gram-Schmidt'] / best['compiled, fused draws']:.2f}x)")


def _policy_arrays(policy) -> list:
    """The arrays that define a trained policy (network, scaler, training curve), sorted by name."""
    arrays = policy.to_arrays()[0]
    return [arrays[k] for k in sorted(arrays)]


def draws(repeat: int) -> None:
    """Part 5: one draw's variates (and a block of 8) by numpy's calls and by the compiled port, CPU time."""
    from adaptfilt.rules import _sif_kernels

    def numpy_draws(rng, n, M, count):
        return [(rng.standard_normal((n, n, M)), rng.chisquare(n + 2, size=M)) for _ in range(count)]

    if not _sif_kernels._build_draws():
        print("the compiled draws are not available here (numba missing, or ADAPTFILT_SIF_BACKEND=numpy)")
        return
    print(f"{'M':>6s} {'draws':>6s} {'numpy us':>10s} {'compiled us':>12s} {'numpy ns/normal':>16s} "
          f"{'compiled ns/normal':>19s} {'ratio':>6s} same")
    n = 5
    for M, count in ((256, 1), (256, 8), (10_000, 1), (10_000, 8)):
        a, b = np.random.default_rng(1), np.random.default_rng(1)
        mine = _sif_kernels.rule3_draws(a, n, M, count)
        ref = numpy_draws(b, n, M, count)
        same = all(np.array_equal(mine[0][k], ref[k][0]) and np.array_equal(mine[1][k], ref[k][1]) for k in range(count))
        same = same and a.bit_generator.state == b.bit_generator.state
        reps = max(3, 200_000 // (n * n * M * count))
        best = {}
        for name, fn in (("numpy", lambda: numpy_draws(b, n, M, count)),
                         ("compiled", lambda: _sif_kernels.rule3_draws(a, n, M, count, scratch=True))):
            t = []
            for _ in range(repeat):
                c0 = time.process_time()
                for _ in range(reps):
                    fn()
                t.append((time.process_time() - c0) / reps)
            best[name] = min(t)
        normals = n * n * M * count
        print(f"{M:6d} {count:6d} {1e6 * best['numpy']:10.1f} {1e6 * best['compiled']:12.1f} "
              f"{1e9 * best['numpy'] / normals:16.2f} {1e9 * best['compiled'] / normals:19.2f} "
              f"{best['numpy'] / best['compiled']:6.2f} {'yes' if same else 'NO'}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run, not the figures)")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--seeds", type=int, default=3, help="seeds pooled in part 3 (degree 3)")
    ap.add_argument("--seeds-deg5", type=int, default=1, help="seeds pooled in part 3 (degree 5; slow)")
    ap.add_argument("--speed", action="store_true", help="part 4 alone: the rule's implementation before and after")
    ap.add_argument("--speed-repeat", type=int, default=3, help="part 4: best of this many")
    ap.add_argument("--baseline", default=BASELINE, help="part 4: the git revision of the baseline stochastic.py")
    ap.add_argument("--draws", action="store_true", help="part 5 alone: the random draws, numpy against compiled")
    args = ap.parse_args(argv)
    if args.draws:
        print(f"# bench_sif --draws  python {platform.python_version()}  numpy {np.__version__}  cpus {os.cpu_count()}  "
              f"load {os.getloadavg()[0]:.1f}\n")
        draws(args.repeat)
        return
    if args.speed:
        episodes, M_speed, T_speed = (20, 1000, 30) if args.quick else (100, 10_000, 150)
        print(f"# bench_sif --speed  python {platform.python_version()}  numpy {np.__version__}  cpus {os.cpu_count()}  "
              f"{platform.processor() or platform.machine()}  load {os.getloadavg()[0]:.1f}\n")
        print(f"## 4. the rule's implementation: CPU time, best of {args.speed_repeat}, interleaved")
        speed(args.speed_repeat, episodes, M_speed, T_speed, args.baseline)
        return
    M_cost, M_acc, M_filt, T = (2000, 500, 200, 40) if args.quick else (10_000, 2000, 2000, 150)
    print(f"# bench_sif  python {platform.python_version()}  numpy {np.__version__}  "
          f"cpus {os.cpu_count()}  {platform.machine()}{'  (quick)' if args.quick else ''}\n")

    print(f"## 1. cost per iteration, CTM first update, M = {M_cost}, 10 iterations, best of {args.repeat}")
    c = cost_per_iteration(M_cost, 10, args.repeat)
    base = "degree 3 (default)"
    print(f"{'rule':24s} {'wall ms/it':>11s} {'cpu ms/it':>10s} {'ratio (wall)':>13s} {'ratio (cpu)':>12s}")
    for name in c["wall"]:
        print(f"{name:24s} {1e3 * c['wall'][name]:11.2f} {1e3 * c['cpu'][name]:10.2f} "
              f"{c['wall'][name] / c['wall'][base]:13.2f} {c['cpu'][name] / c['cpu'][base]:12.2f}")
    pts3, pts5 = StochasticIntegrationRule(order=3).points_per_draw(4), StochasticIntegrationRule(order=5).points_per_draw(4)
    print(f"(function evaluations per iteration: degree 3 {pts3}, degree 5 {pts5}, ratio {pts5 / pts3:.1f}; "
          f"target: degree 5 within 2x of degree 3)")
    print(f"per function evaluation, degree 5 / degree 3: "
          f"{(c['wall']['degree 5'] / pts5) / (c['wall'][base] / pts3):.2f} (wall)")
    atan = arctan2_floor(pts5, M_cost, args.repeat)
    print(f"the bearing's arctan2 alone on degree 5's {pts5} x {M_cost} points: {1e3 * atan:.2f} ms, "
          f"{atan / c['wall'][base]:.2f} x the whole degree-3 iteration (a floor for the ratio)\n")

    print(f"## 1b. per-run counts, degree 3, M = {M_cost}, best of {args.repeat}")
    pr = cost_per_run_counts(M_cost, args.repeat)
    ref = pr["all at 30"]
    for name, sec in pr.items():
        print(f"{name:30s} {1e3 * sec:9.1f} ms   {sec / ref:5.2f} of all-at-30")
    print()

    print(f"## 2. accuracy of the first update: RMS error over {M_acc} replicates (polar Gauss-Legendre reference)")
    rows, ref_err = accuracy(M_acc)
    print(f"(reference converged to {ref_err:.1e}: Gauss-Legendre order 400 vs 300)")
    print(f"{'order':>5s} {'n_it':>5s} {'z_pred (rad)':>13s} {'Pzz (rel)':>10s} {'Pxz (rel)':>10s}")
    for order, n_it, ez, ev, ec in rows:
        print(f"{order:5d} {n_it:5d} {ez:13.2e} {ev:10.2e} {ec:10.2e}")
    r = {(o, n): (ez, ev, ec) for o, n, ez, ev, ec in rows}
    ratio = [a / b for a, b in zip(r[(5, 1)], r[(3, 10)])]
    print("degree 5 x 1 iteration / degree 3 x 10 iterations, error ratio (z_pred, Pzz, Pxz): "
          + ", ".join(f"{x:.2f}" for x in ratio))
    w = c["wall"]
    print(f"cost of that: degree 5 x 1 = {1e3 * w['degree 5']:.1f} ms, degree 3 x 10 = {1e3 * 10 * w[base]:.1f} ms "
          f"(M = {M_cost})\n")

    seeds = tuple(range(1, args.seeds + 1))
    seeds5 = seeds[: args.seeds_deg5]
    print(f"## 3. filter quality, CTM, M = {M_filt} runs x seeds {seeds} (degree 5: seeds {seeds5}), T = {T}, "
          f"on_indefinite='clip'")
    print(f"{'filter':16s} {'n_it':>6s} {'V term':>6s} {'seeds':>5s} {'RMSE':>10s} {'ANEES':>10s} {'divergent (n)':>14s} "
          f"{'repairs':>7s} {'iterations':>16s} {'s':>6s}")
    for label, n_it, ie, ns, rmse, anees, div, ndiv, rep, note, secs in filter_quality(M_filt, T, seeds, seeds5):
        print(f"{label:16s} {str(n_it):>6s} {('yes' if ie else 'no'):>6s} {ns:5d} {rmse:10.4g} {anees:10.4g} "
              f"{100 * div:7.3f}% ({ndiv:3d}) {rep:7d} {note:>16s} {secs:6.1f}")


if __name__ == "__main__":
    main()
