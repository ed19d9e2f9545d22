"""The compiled kernels of the scalar unscented filter (:mod:`adaptfilt.rules.scalar_kernels`) give the
numbers of numpy's form bit for bit: the rule's moments and the filter's update, on values over many
decades with signed zeros, scalar and per-run kappa, through whole filter runs; where numpy's form raises
or repairs, the kernels hand the step back to it and the error or repair is the same."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt import linalg_kernels
from adaptfilt.gaf import FilterError
from adaptfilt.rules import scalar_kernels as _scalar_kernels

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)

needs_kernels = pytest.mark.skipif(not _scalar_kernels.available(),
                                   reason="numba missing, or numpy's einsum fuses multiply-adds (see linalg_kernels.einsum_is_plain)")


def _wide(rng, shape, positive=False):
    """Values over 12 decades, both signs, with signed zeros (positive: no zeros, no signs)."""
    a = rng.standard_normal(shape) * 10.0 ** rng.uniform(-6, 6, shape)
    if positive:
        return np.abs(a) + 1e-300
    flat = a.reshape(-1)
    flat[rng.integers(0, flat.size, max(1, flat.size // 50))] = -0.0
    flat[rng.integers(0, flat.size, max(1, flat.size // 50))] = 0.0
    return a


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and np.array_equal(np.ascontiguousarray(a).view(np.int64),
                                                 np.ascontiguousarray(b).view(np.int64))


def _kernels_off(monkeypatch):
    monkeypatch.setattr(linalg_kernels, "SUMS", False)


@needs_kernels
@pytest.mark.parametrize("M", [2, 3, 37, 1000])
@pytest.mark.parametrize("cross", [True, False])
@pytest.mark.parametrize("kappa_kind", ["scalar", "runs"])
def test_the_rules_moments_are_numpys_bit_for_bit(monkeypatch, M, cross, kappa_kind):
    rng = np.random.default_rng(M + 10 * cross)
    m = _wide(rng, (1, M))
    P = _wide(rng, (1, 1, M), positive=True)
    kappa = 2.0 if kappa_kind == "scalar" else rng.uniform(-0.9, 50.0, M)

    def g(X):  # a scalar nonlinearity whose rounding shows, strided like a model wrapper's output
        return np.ascontiguousarray(np.moveaxis(np.sin(X) * X + X * X / 20.0, 1, 0)).transpose(1, 0, 2)

    calls = []
    real = _scalar_kernels.moments
    monkeypatch.setattr(_scalar_kernels, "moments", lambda *a: calls.append(1) or real(*a))
    on = af.rules.UnscentedRule().moments(g, m, P, kappa, cross=cross)
    assert calls  # the kernel made them
    _kernels_off(monkeypatch)
    off = af.rules.UnscentedRule().moments(g, m, P, kappa, cross=cross)
    for f in ("mean", "cov", "cross"):
        assert _same(getattr(on, f), getattr(off, f)), f


@needs_kernels
@pytest.mark.parametrize("M", [2, 5, 64, 1001])
def test_the_update_is_numpys_bit_for_bit(monkeypatch, M):
    """The update from moments made up over many decades (NIS and the log-likelihood over huge ranges,
    innovations of both signs and zero), with ``P_filt`` kept positive so that numpy's form carries on."""
    rng = np.random.default_rng(M)
    ukf = af.UKF(af.models.ungm())
    S = _wide(rng, (1, 1, M), positive=True)
    Pzz = S + ukf._R
    Pxz = _wide(rng, (1, 1, M)) * 1e-3
    P = Pxz[0] * Pxz[0] / Pzz[0] * 2.0 + _wide(rng, (1, M), positive=True)  # P - Pxz^2 / Pzz > 0
    m, z, z_pred = _wide(rng, (1, M)), _wide(rng, (1, M)), _wide(rng, (1, M))
    made = []
    real = _scalar_kernels.update
    monkeypatch.setattr(_scalar_kernels, "update", lambda *a: (lambda r: made.append(r is not None) or r)(real(*a)))
    on = ukf._finish_update(m, P[None], z, 3, z_pred, S, Pxz, None)
    assert made == [True]  # the kernel made it
    _kernels_off(monkeypatch)
    off = ukf._finish_update(m, P[None], z, 3, z_pred, S, Pxz, None)
    for f in ("z_pred", "Pzz", "Pxz", "K", "innovation", "nis", "loglik", "x_filt", "P_filt"):
        assert _same(getattr(on, f), getattr(off, f)), f
    assert _same(on.L_filt, off.L_filt)


@needs_kernels
def test_filter_runs_are_numpys_bit_for_bit(monkeypatch):
    """UNGM's UKF over 200 steps (its round-off grows over the run): one kappa, one per run, one per run
    and step, and the modified form (numpy's form, the kernels declining), through ``run``."""
    model = af.models.ungm()
    z = model.simulate(n_runs=64, n_steps=200, rng=4).z
    rng = np.random.default_rng(1)
    params = [None, rng.uniform(0.0, 50.0, 64), rng.uniform(0.0, 50.0, (64, 200))]

    def runs():
        out = [af.UKF(model, kappa=2.0).run(z, params=p, keep_pred=True) for p in params]
        out.append(af.UKF(model, kappa=0.5, form="modified").run(z))
        return [getattr(r, f) for r in out for f in ("mean", "cov", "nis", "loglik", "x_pred", "P_pred") if
                getattr(r, f) is not None]

    made, moments = [], []
    real, real_moments = _scalar_kernels.update, _scalar_kernels.moments
    monkeypatch.setattr(_scalar_kernels, "update", lambda *a: (lambda r: made.append(r is not None) or r)(real(*a)))
    monkeypatch.setattr(_scalar_kernels, "moments", lambda *a: (lambda r: moments.append(r is not None) or r)(
        real_moments(*a)))
    on = runs()
    assert made.count(True) == 4 * 200  # every update (the update's arithmetic is the same for every rule)
    assert moments.count(True) == 3 * (200 + 199)  # the moments of every step of the standard form
    _kernels_off(monkeypatch)
    off = runs()
    assert len(on) == len(off) == 22
    assert all(_same(a, b) for a, b in zip(on, off))


@needs_kernels
def test_a_step_numpys_form_would_reject_is_handed_back_to_it(monkeypatch):
    """An indefinite ``P_filt`` (a negative centre weight can make one): the kernel declines, and numpy's form
    raises the same FilterError, or repairs the same runs with ``on_indefinite="clip"``."""
    model = af.models.ungm()
    M = 8
    m, z = np.zeros((1, M)), np.full((1, M), 3.0)
    P, S, Pxz = np.ones((1, 1, M)), np.full((1, 1, M), 0.5), np.full((1, 1, M), 0.1)
    Pxz[0, 0, [2, 5]] = 5.0  # K Pzz K = Pxz^2 / Pzz = 41.7 > P = 1 in runs 2 and 5
    assert _scalar_kernels.update(m, P, z, np.zeros((1, M)), S, Pxz, af.UKF(model)._R, np.log(2 * np.pi)) is None
    with pytest.raises(FilterError, match=r"P_filt is not positive definite at step t=7 .* run\(s\) 2, 5"):
        af.UKF(model)._finish_update(m, P, z, 7, np.zeros((1, M)), S, Pxz, None)
    clip = af.UKF(model, on_indefinite="clip")
    on = clip._finish_update(m, P, z, 7, np.zeros((1, M)), S, Pxz, None)
    assert clip.n_repairs == 2
    _kernels_off(monkeypatch)
    ref = af.UKF(model, on_indefinite="clip")
    off = ref._finish_update(m, P, z, 7, np.zeros((1, M)), S, Pxz, None)
    assert ref.n_repairs == 2
    assert all(_same(getattr(on, f), getattr(off, f)) for f in ("x_filt", "P_filt", "nis", "loglik"))


def test_the_kernels_decline_what_they_do_not_compute():
    """One run, another dtype, a state or measurement of more than one dimension: None (numpy's form)."""
    L = np.ones((1, 1, 4))
    g = lambda X: X * X  # noqa: E731
    assert _scalar_kernels.moments(g, np.zeros((1, 1)), np.zeros((1, 1)), L[..., :1], 1.0, 0.25, True) is None
    assert _scalar_kernels.moments(g, np.zeros((2, 4)), np.zeros((2, 4)), np.ones((2, 2, 4)), 1.0, 0.25, True) is None
    assert _scalar_kernels.moments(g, np.zeros((1, 4), dtype=np.float32), np.zeros((1, 4)), L, 1.0, 0.25, True) is None
    assert _scalar_kernels.moments(g, np.zeros((1, 4)), np.zeros((1, 4)), L, np.ones(3), 0.25, True) is None
    one = np.ones((1, 1, 4))
    R = np.full((1, 1, 1), 0.1)
    assert _scalar_kernels.update(np.zeros((1, 1)), one[..., :1], np.zeros((1, 1)), np.zeros((1, 1)), one[..., :1],
                                  one[..., :1], R, 1.0) is None
    assert _scalar_kernels.update(np.zeros((2, 4)), np.ones((2, 2, 4)), np.zeros((1, 4)), np.zeros((1, 4)), one, one,
                                  R, 1.0) is None


def test_importing_the_filters_does_not_import_numba():
    code = "import sys, adaptfilt; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
