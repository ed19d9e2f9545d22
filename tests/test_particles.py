"""The particle filter with a particle count per run and step, and KLD-sampling's count (adaptfilt.particles).

References: the point-mass filter (the exact posterior of UNGM up to its grid), the same filter run
alone (common random numbers), the chi-square quantile and Fox's formula written out."""
from __future__ import annotations

import re

import numpy as np
import pytest
from scipy import stats

import adaptfilt as af
from adaptfilt.particles import ParticleCountFilter, kld_bound, kld_count
from same_numbers import assert_same_numbers  # tests/same_numbers.py


@pytest.fixture(scope="module")
def ungm_runs():
    model = af.models.ungm()
    return model, model.simulate(n_runs=30, n_steps=40, rng=4)


def test_many_particles_reach_the_point_mass_posterior_on_ungm(ungm_runs):
    model, traj = ungm_runs
    pmf = af.PointMassFilter(model, grid=np.linspace(-45, 45, 1801)).run(traj.z)
    pf = ParticleCountFilter(model, seed=1).run(traj.z, n_particles=4000)
    m, v = pmf.mean[..., 0], pmf.cov[..., 0, 0]
    # the particle mean's Monte-Carlo error is about sqrt(var / ESS): its squared size relative to the
    # posterior variance is ~1/ESS (ESS ~ 10^3 here); a wrong filter (or a biased one) is at ~1
    ratio = np.mean((pf.mean[..., 0] - m) ** 2 / v)
    assert ratio < 0.02, ratio
    np.testing.assert_allclose(pf.cov[..., 0, 0].mean(), v.mean(), rtol=0.05)
    rmse = lambda run: np.sqrt(((run.mean[..., 0] - traj.x[..., 0]) ** 2).mean())  # noqa: E731
    assert abs(rmse(pf) / rmse(pmf) - 1) < 0.03
    # the likelihood estimate is unbiased but heavy-tailed in the log (a step where few particles sit
    # in the right mode): its typical error is small, its worst one not
    assert np.median(np.abs(pf.loglik.sum(axis=1) - pmf.loglik.sum(axis=1))) < 0.5
    few = ParticleCountFilter(model, seed=1).run(traj.z, n_particles=20)
    assert np.mean((few.mean[..., 0] - m) ** 2 / v) > 5 * ratio  # the check can tell 20 particles from 4000


def test_a_run_in_a_batch_is_the_same_run_filtered_alone(ungm_runs):
    model, traj = ungm_runs
    z = traj.z[:4, :15]
    counts = np.random.default_rng(0).integers(5, 400, size=(4, 15))
    counts[2] = 1000  # one run far above the others: the rest are padded
    pf = ParticleCountFilter(model, seed=7)
    batch = pf.run(z, counts)
    np.testing.assert_array_equal(batch.params, counts)
    for i in range(4):
        alone = pf.run(z[i:i + 1], counts[i:i + 1], run_ids=[i])
        np.testing.assert_array_equal(alone.mean[0], batch.mean[i])
        np.testing.assert_array_equal(alone.cov[0], batch.cov[i])
        np.testing.assert_array_equal(alone.loglik[0], batch.loglik[i])
    other = ParticleCountFilter(model, seed=8).run(z, counts)
    assert not np.array_equal(other.mean, batch.mean)


def test_kld_bound_is_the_chi_square_quantile_of_fox_2003():
    k = np.arange(2, 2000)
    eps, delta = 0.05, 0.01
    z = stats.norm.ppf(1 - delta)
    fox = (k - 1) / (2 * eps) * (1 - 2 / (9 * (k - 1)) + np.sqrt(2 / (9 * (k - 1))) * z) ** 3
    np.testing.assert_allclose(kld_bound(k, eps, delta), fox, rtol=1e-12)
    exact = stats.chi2.ppf(1 - delta, k - 1) / (2 * eps)  # what Wilson-Hilferty approximates
    big = k >= 10
    assert np.max(np.abs(kld_bound(k[big], eps, delta) / exact[big] - 1)) < 0.01
    assert float(kld_bound(1)) == 1.0 and np.all(np.diff(kld_bound(k)) > 0)
    with pytest.raises(ValueError, match="epsilon"):
        kld_bound(5, epsilon=0.0)


def test_kld_count_stops_where_the_bound_is_met():
    one_bin = np.zeros((500, 1))
    assert kld_count(one_bin, bin_size=1.0, n_min=10) == 10
    two_bins = (np.arange(500) % 2).reshape(-1, 1).astype(float)  # k = 2 from the second particle on
    assert kld_count(two_bins, bin_size=1.0) == 1  # Fox's loop stops at once while one bin is occupied
    assert kld_count(two_bins, bin_size=1.0, n_min=2) == int(np.ceil(kld_bound(2)))
    spread = np.arange(300, dtype=float).reshape(-1, 1)  # every particle a new bin: the bound runs away
    assert kld_count(spread, bin_size=1.0, n_min=2) == 300
    grid2d = np.random.default_rng(0).normal(size=(20000, 2))
    n = kld_count(grid2d, bin_size=[0.5, 0.5], n_min=2)
    k = len(np.unique(np.floor(grid2d[:n] / 0.5), axis=0))
    assert 2 < n < 20000 and n >= kld_bound(k) and n - 1 < kld_bound(len(np.unique(np.floor(grid2d[:n - 1] / 0.5), axis=0)))


def test_bad_input_is_named(ungm_runs):
    model, traj = ungm_runs
    pf = ParticleCountFilter(model)
    with pytest.raises(ValueError, match="n_particles must be a scalar"):
        pf.run(traj.z, np.ones((3, 3)))
    with pytest.raises(ValueError, match="integers >= 1"):
        pf.run(traj.z, 0)
    with pytest.raises(ValueError, match="integers >= 1"):
        pf.run(traj.z, 10.5)
    z = traj.z.copy()
    z[0, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        pf.run(z, 10)
    with pytest.raises(ValueError, match="run_ids"):
        pf.run(traj.z, 10, run_ids=[0, 1])



@pytest.mark.parametrize("fn", ["kld_count", "kld_counts"])
def test_the_kld_counts_name_a_bad_bin_size_x_or_bound(fn):
    """Before, a bin size of 0 or NaN gave a count (after a RuntimeWarning), a non-finite particle a
    count, a wrong number of bin sizes numpy's broadcasting error, n_min = 0 a count."""
    from adaptfilt.particles import kld_counts

    count = (lambda x, *a, **k: kld_count(x[0], *a, **k)) if fn == "kld_count" else kld_counts  # noqa: E731
    x = np.random.default_rng(0).normal(size=(2, 50, 2))
    for bad in (0.0, -1.0, np.nan, np.inf, [0.5, 0.0], [0.5, np.nan]):
        want = f"bin_size must be finite and > 0, got {np.asarray(bad).tolist()}"
        with pytest.raises(ValueError, match=re.escape(want)):
            count(x, bad)
    with pytest.raises(ValueError, match=r"bin_size must be a scalar or one per state dimension \(2,\), got "
                                         r"shape \(3,\)"):
        count(x, [0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="bin_size .* is too small for x"):
        count(x, 1e-300)  # x / bin_size beyond int64: the bins would wrap
    y = x.copy()
    y[0, 7, 1] = np.nan
    where = "particle 7" if fn == "kld_count" else "run 0, particle 7"
    with pytest.raises(ValueError, match=re.escape(f"x has non-finite values (first at {where})")):
        count(y, 0.5)
    for name, value in (("n_min", 0), ("n_min", 2.5), ("n_min", np.nan)):
        with pytest.raises(ValueError, match=f"{name} must be an integer >= 1, got"):
            count(x, 0.5, n_min=value)
    with pytest.raises(ValueError, match="epsilon must be finite and > 0, got nan"):
        count(x, 0.5, epsilon=np.nan)
    with pytest.raises(ValueError, match=r"delta must be in \(0, 1\), got nan"):
        count(x, 0.5, delta=np.nan)
    with pytest.raises(ValueError, match="at least one particle"):
        count(x[:, :0], 0.5)
    np.testing.assert_array_equal(count(x, [0.5, 0.5]), count(x, 0.5))  # one per dimension or a scalar: the same
    if fn == "kld_count":
        with pytest.raises(ValueError, match="n_max must be an integer >= 1, got 0"):
            kld_count(x[0], 0.5, n_max=0)


def test_kld_bound_names_a_non_finite_epsilon():
    for eps in (np.nan, np.inf):  # before: NaN gave NaN counts, inf a bound of 0 particles
        with pytest.raises(ValueError, match="epsilon must be finite and > 0"):
            kld_bound(5, epsilon=eps)
    with pytest.raises(ValueError, match=r"delta must be in \(0, 1\)"):
        kld_bound(5, delta=1.0)


@pytest.mark.parametrize("ids, shown", [([0, -1], "-1 for run 1"), ([1.5, 0], "1.5 for run 0"),
                                        (np.array([True, False]), "True for run 0"), ([0, 2**64], f"{2**64} for run 1"),
                                        ([0, np.nan], "nan for run 1"), (["a", 1], "'a' for run 0")])
def test_run_ids_must_be_integers_that_fit_a_philox_key(ungm_runs, ids, shown):
    """Before, -1 was accepted (a key numpy cannot set, or a wrapped one), 1.5 truncated to 1 (run 0 and 1
    drew the same numbers), a mask read as ids 1 and 0, 2**64 an OverflowError."""
    model, traj = ungm_runs
    with pytest.raises(ValueError, match=r"run_ids must be integers in \[0, 2\*\*64\) \(they key the random "
                                         r"streams\), got " + shown.replace("(", r"\(")):
        ParticleCountFilter(model).run(traj.z[:2, :3], 10, run_ids=ids)


def test_run_ids_take_the_whole_uint64_key_range(ungm_runs):
    model, traj = ungm_runs
    pf = ParticleCountFilter(model, seed=2, backend="numpy")
    batch = pf.run(traj.z[:2, :5], 30, run_ids=[2**64 - 1, 3.0])  # an integral float is an integer
    alone = pf.run(traj.z[:1, :5], 30, run_ids=[2**64 - 1])
    np.testing.assert_array_equal(batch.mean[0], alone.mean[0])
    np.testing.assert_array_equal(batch.mean[1], pf.run(traj.z[1:2, :5], 30, run_ids=[3]).mean[0])


@pytest.mark.parametrize("backend", ["numpy", "auto"])
@pytest.mark.parametrize("count", [10**12, 10**13, 2**70])
def test_a_count_beyond_memory_is_refused_before_allocating(ungm_runs, backend, count):
    """Before, 10**12 particles ended in numpy's MemoryError for a (1, 10**12, 1) array (7.3 TiB), after the
    smaller arrays; 2**70 overflowed int64. The refusal names the count and the bytes, and allocates nothing
    (it returns at once)."""
    import time

    from adaptfilt.particles import ParticleMemoryError

    model, traj = ungm_runs
    pf = ParticleCountFilter(model, backend=backend)
    start = time.perf_counter()
    with pytest.raises(ParticleMemoryError) as err:
        pf.run(traj.z[:3, :5], [20, count, 20])
    assert time.perf_counter() - start < 0.5
    msg = str(err.value)
    assert re.fullmatch(rf"n_particles up to {count} needs about \S+ [TP]iB \(\S+ [TP]iB for one run's particle "
                        rf"arrays, \d+ B for the results\), more than (this machine's|the) \S+ [KMGTP]iB .*", msg), msg
    assert err.value.count == count and err.value.needed >= 8 * count > err.value.available
    assert isinstance(err.value, MemoryError) and isinstance(err.value, ValueError)  # the CLI's user error


def test_the_results_count_towards_the_memory_too(ungm_runs, monkeypatch):
    """(M, T, nx, nx) covariances for many runs and steps: refused as the particle arrays are."""
    from adaptfilt import particles

    model, traj = ungm_runs
    pf = ParticleCountFilter(model, backend="numpy")
    monkeypatch.setattr(particles, "_memory_bytes", lambda: (40_000, "this machine's {} of memory"))
    # 30 runs x 40 steps x (nx + nx^2 + 4 = 6) x 8 B = 56.2 KiB of results; 30 x 10 particles at once x 120 B
    with pytest.raises(particles.ParticleMemoryError, match=re.escape(
            "n_particles = 10 needs about 91.4 KiB (35.2 KiB for the particle arrays of 30 runs at once, "
            "56.2 KiB for the results), more than this machine's 39.1 KiB of memory")):
        pf.run(traj.z, 10)
    monkeypatch.setattr(particles, "_memory_bytes", lambda: (1 << 20, "this machine's {} of memory"))
    assert pf.run(traj.z, 10).mean.shape == (30, 40, 1)


def test_the_environment_and_kld_policy_name_their_bad_input():
    from adaptfilt.particle_env import KLDSamplingPolicy, ParticleCountEnv
    from adaptfilt.particles import ParticleMemoryError

    model = af.models.ungm()
    for bad, match in ((np.nan, "bin_size must be finite and > 0, got nan"), ([[1.0]], "bin_size must be a scalar")):
        with pytest.raises(ValueError, match=match):
            KLDSamplingPolicy(bin_size=bad)
    with pytest.raises(ValueError, match="epsilon must be finite and > 0, got nan"):  # before: at the first step
        KLDSamplingPolicy(bin_size=1.0, epsilon=np.nan)
    with pytest.raises(ValueError, match="n_min must be an integer >= 1, got 0"):
        KLDSamplingPolicy(bin_size=1.0, n_min=0)
    env = ParticleCountEnv(model, n_steps=3)
    for stream in (-1, 2**31, 1.5):  # before: -1 failed in numpy's Philox, 2**31 overflowed int64 ids
        with pytest.raises(ValueError, match=r"stream must be an integer in \[0, 2\*\*31\)"):
            env.reset(n_runs=2, rng=0, stream=stream)
    d = env.reset(n_runs=2, rng=0, stream=2**31 - 1)
    with pytest.raises(ValueError, match=r"bin_size must be a scalar or one per state dimension \(1,\)"):
        KLDSamplingPolicy(bin_size=[1.0, 1.0]).act(d)
    big = ParticleCountEnv(model, grid=(10, 10**13), default=10, n_steps=3)
    with pytest.raises(ParticleMemoryError, match=f"the grid's n_particles = {10**13} needs about"):
        big.reset(n_runs=2, rng=0)

def test_the_batched_kld_count_is_the_stopping_rule_run_by_run():
    from adaptfilt.particles import kld_counts

    rng = np.random.default_rng(5)
    for nx, bins in ((1, 0.3), (2, [0.5, 2.0]), (4, [5.0, 1.0, 5.0, 1.0])):
        x = rng.standard_normal((7, 3000, nx)) * rng.uniform(0.2, 8, size=(7, 1, 1))
        want = [kld_count(x[i], bins, n_min=50) for i in range(7)]
        assert kld_counts(x, bins, n_min=50).tolist() == want
        assert len(set(want)) > 1  # the runs differ: the batch cannot pass by repeating one count


def test_the_streams_are_those_of_fresh_philox_generators():
    pf = ParticleCountFilter(af.models.ungm(), seed=3)
    for run_id, t in ((7, 11), (0, 0), (2**40 + 5, 499)):
        gu, gw = pf._rngs(run_id, t)
        u, w = gu.random(9), gw.standard_normal(9)
        fresh = [np.random.Generator(np.random.Philox(key=[3, run_id], counter=[0, t, s, 0])) for s in (0, 1)]
        np.testing.assert_array_equal(u, fresh[0].random(9))
        np.testing.assert_array_equal(w, fresh[1].standard_normal(9))


def test_no_stream_overlaps_another_steps_or_runs():
    """Each (run, step, stream) gets its own draws: a draw advances Philox's lowest counter word, so a
    step counter there would make step t + 1's stream step t's shifted by four draws (the regression)."""
    pf = ParticleCountFilter(af.models.ungm(), seed=0)
    draws = {}
    for run_id in (0, 1):
        for t in (3, 4, 5):
            gu, gw = pf._rngs(run_id, t)
            draws[run_id, t, 0], draws[run_id, t, 1] = gu.random(5000), gw.random(5000)
    values = np.concatenate(list(draws.values()))
    assert np.unique(values).size == values.size  # 60,000 doubles, no value twice


# --- the compiled backend (adaptfilt.particle_kernels): the same numbers as the numpy reference --------------

kernels = pytest.importorskip("adaptfilt.particle_kernels")
needs_numba = pytest.mark.skipif(not kernels.AVAILABLE, reason="the optional extra 'fast' (numba) is not installed")


@needs_numba
@pytest.mark.parametrize("seed, run_id, t, stream", [(3, 7, 11, 0), (0, 0, 0, 1), (5, 2**40 + 5, 499, 1),
                                                     (2**31 - 1, 999, 10**6, 0)])
def test_the_kernel_streams_are_numpys_philox_draws(seed, run_id, t, stream):
    """Uniforms and ziggurat normals bit for bit (300,000 normals reach the ziggurat's wedges and its tail
    beyond 3.654), with a word buffer small enough to be refilled mid-normal."""
    fresh = lambda: np.random.Generator(np.random.Philox(key=[seed, run_id], counter=[0, t, stream, 0]))  # noqa: E731
    np.testing.assert_array_equal(kernels.philox_uniforms(seed, run_id, t, stream, 4099), fresh().random(4099))
    want = fresh().standard_normal(300_000)
    assert np.abs(want).max() > 3.66  # the tail branch ran
    for scratch in (4, 64, 400_000):
        np.testing.assert_array_equal(kernels.philox_normals(seed, run_id, t, stream, 300_000, scratch), want)


@needs_numba
def test_the_kernel_resampling_is_the_reference_searchsorted():
    """Every ancestor, for flat, peaked, degenerate and zero-padded weights and any two counts."""
    rng = np.random.default_rng(0)
    cases = [rng.random(500), np.exp(-0.5 * (rng.standard_normal(500) * 6) ** 2), np.eye(1, 500, 123)[0],
             np.r_[rng.random(300), np.zeros(200)], np.r_[np.zeros(250), np.ones(250)]]
    for w in cases:
        w = w / w.sum()
        for n_old, n in ((500, 700), (500, 37), (1, 5)):
            if w[:n_old].sum() == 0:
                continue
            cdf = np.cumsum(w)
            u = rng.random(n)
            u[:3] = [0.0, 1 - 2**-53, 0.5]
            x_old = np.arange(float(len(w)))[:, None]
            x_new = np.full((n + 5, 1), -1.0)
            kernels._resample(cdf, n_old, u, n, x_old, x_new, np.empty(4 * len(w) + 1, np.int64),
                              np.empty(n, np.int64))
            c = cdf[:n_old]
            want = np.minimum(np.searchsorted(c, u * c[-1], side="right"), n_old - 1)
            np.testing.assert_array_equal(x_new[:n, 0], want)
            np.testing.assert_array_equal(x_new[n:, 0], 0.0)  # the padding is particle 0, as the reference's


@needs_numba
@pytest.mark.parametrize("model_name", ["ungm", "ctm"])
@pytest.mark.crosscpu
def test_both_backends_and_any_block_size_give_the_same_numbers(model_name):
    """Whole runs with counts per run and step (padding included), UNGM and the bearing-only CTM (4-D state,
    a wrapped bearing), under the compiled and the numpy backend and blocks of 1, 3 and all runs."""
    model = af.models.ungm() if model_name == "ungm" else af.models.coordinated_turn()
    traj = model.simulate(n_runs=7, n_steps=25, rng=3)
    counts = np.random.default_rng(1).integers(5, 600, size=(7, 25))
    runs = []
    for backend, block in (("numpy", 1 << 16), ("numba", 1 << 16), ("numba", 1), ("numba", 3 * 600 * model.nx)):
        runs.append(ParticleCountFilter(model, seed=4, backend=backend, block_particles=block).run(traj.z, counts))
    for r in runs[2:]:  # the compiled backend's block sizes: bit for bit on any CPU (the same exp, same order)
        for key in ("mean", "cov", "loglik"):
            np.testing.assert_array_equal(getattr(r, key), getattr(runs[1], key))
        np.testing.assert_array_equal(r.info["ess"], runs[1].info["ess"])
    for key in ("mean", "cov", "loglik"):  # the backends: bit for bit where numpy's exp is the C library's
        assert_same_numbers(getattr(runs[1], key), getattr(runs[0], key), err_msg=key)
    assert_same_numbers(runs[1].info["ess"], runs[0].info["ess"])
    assert runs[1].info["ess"].min() < runs[1].params.min()  # the weights were uneven: resampling mattered


def test_the_backend_is_named_and_checked(monkeypatch):
    model = af.models.ungm()
    assert ParticleCountFilter(model, backend="numpy").backend == "numpy"
    with pytest.raises(ValueError, match="backend must be one of"):
        ParticleCountFilter(model, backend="cuda")
    with pytest.raises(ValueError, match="block_particles must be a positive integer"):
        ParticleCountFilter(model, block_particles=0)
    monkeypatch.setattr(kernels, "AVAILABLE", False)  # as without the extra: auto falls back, numba says why
    assert ParticleCountFilter(model).backend == "numpy"
    with pytest.raises(ImportError, match=r"adaptfilt\[fast\]"):
        ParticleCountFilter(model, backend="numba")
