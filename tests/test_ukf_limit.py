"""The UKF's fast paths: the benchmark's hand-fused kernel (benchmarks/bench_ukf_limit.py) gives the
library's numbers, and the shortcuts of ``GaussianAssumedFilter.run`` (the update's Cholesky factor
reused by the next predict, one parameter kept as a broadcast view) change no bit."""
import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import adaptfilt as af


@pytest.fixture(scope="module")
def bench():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_ukf_limit.py"
    spec = importlib.util.spec_from_file_location("bench_ukf_limit", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("kappa", [2.0, 0.5])
def test_the_benchmark_kernel_gives_the_library_numbers(bench, kappa):
    model = af.models.ungm()
    z = model.simulate(n_runs=200, n_steps=100, rng=3).z
    run = af.UKF(model, kappa=kappa).run(z)
    out = bench.kernel(z[:, :, 0], kappa)
    for ours, theirs in ((run.mean[:, :, 0], out[0]), (run.cov[:, :, 0, 0], out[1]), (run.nis, out[2]),
                         (run.loglik, out[3])):
        assert bench.rel_diff(theirs.T, ours) < 1e-10


def test_a_predict_from_the_updates_factor_is_the_predict_that_factors_again():
    model = dataclasses.replace(af.models.coordinated_turn(), F=None, name="ctm-generic")
    ukf = af.UKF(model, kappa=1.0)
    z = model.simulate(n_runs=50, n_steps=2, rng=0).z
    m, P = ukf.initial(50)
    u = ukf.update_rl(m, P, np.ascontiguousarray(z[:, 0].T), 0)
    assert u.L_filt is not None
    for a, b in zip(ukf.predict_rl(u.x_filt, u.P_filt, 0, L=u.L_filt), ukf.predict_rl(u.x_filt, u.P_filt, 0)):
        np.testing.assert_array_equal(a, b)


def test_one_parameter_is_a_read_only_schedule_with_the_full_ones_numbers():
    model = af.models.ungm()
    z = model.simulate(n_runs=30, n_steps=20, rng=1).z
    ukf = af.UKF(model, kappa=2.0)
    one, full = ukf.run(z, params=1.5), ukf.run(z, params=np.full((30, 20), 1.5))
    np.testing.assert_array_equal(one.params, full.params)
    assert not one.params.flags.writeable
    for f in ("mean", "cov", "nis", "loglik"):
        np.testing.assert_array_equal(getattr(one, f), getattr(full, f))
    with pytest.raises(ValueError, match=r"n \+ kappa > 0"):
        ukf.run(z, params=-1.0)
