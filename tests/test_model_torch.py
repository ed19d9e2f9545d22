"""The models' torch forms (``f_torch``, ``h_torch``, ``residual_torch``): equal to the numpy functions, their
autograd derivatives equal to the analytic ones, and a model without them, or with a wrong one, handled by the
learned filter that uses them (:mod:`adaptfilt.kalmannet`)."""
import numpy as np
import pytest
import torch

import adaptfilt as af
from adaptfilt.kalmannet import KalmanNet
from adaptfilt.models import wrap_angle, wrap_angle_torch

torch.set_num_threads(1)


def states(model, n=400, seed=0):
    """States over the models' ranges and beyond (wide spread around the prior), incl. zero."""
    rng = np.random.default_rng(seed)
    x = model.m0 + 3.0 * rng.standard_normal((n, model.nx)) @ np.linalg.cholesky(model.P0).T
    x[0] = 0.0
    return x


@pytest.mark.parametrize("make", [af.models.ungm, af.models.coordinated_turn])
def test_torch_forms_equal_the_numpy_functions_to_1e_12(make):
    model = make()
    x = states(model)
    for k in (1, 2, 37, 500):
        for fn, tfn in ((model.f, model.f_torch), (model.h, model.h_torch)):
            want = fn(x, k)
            got = tfn(torch.from_numpy(x), k)
            assert isinstance(got, torch.Tensor) and got.dtype == torch.float64 and got.shape == want.shape
            np.testing.assert_allclose(got.numpy(), want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    if model.name == "ungm":  # the same arithmetic on the same numbers: bit for bit
        assert np.array_equal(model.f_torch(torch.from_numpy(x), 9).numpy(), model.f(x, 9))
        assert np.array_equal(model.h_torch(torch.from_numpy(x), 9).numpy(), model.h(x, 9))


def test_ctm_residual_and_wrap_in_torch_equal_numpy_including_the_edges():
    a = np.concatenate([np.linspace(-20, 20, 4001), [np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 0.0, 1e-300]])
    np.testing.assert_allclose(wrap_angle_torch(torch.from_numpy(a)).numpy(), wrap_angle(a), rtol=0, atol=1e-12)
    assert wrap_angle_torch(torch.tensor([np.pi, -np.pi], dtype=torch.float64)).tolist() == [np.pi, np.pi]  # (-pi, pi]
    inside = np.array([0.3, -3.0, np.pi])
    assert np.array_equal(wrap_angle_torch(torch.from_numpy(inside)).numpy(), inside)  # unchanged exactly
    model = af.models.coordinated_turn()
    rng = np.random.default_rng(1)
    z1, z2 = rng.uniform(-4, 4, (300, 1)), rng.uniform(-4, 4, (300, 1))
    np.testing.assert_allclose(model.residual_torch(torch.from_numpy(z1), torch.from_numpy(z2)).numpy(),
                               model.residual(z1, z2), rtol=0, atol=1e-12)


def test_autograd_through_the_torch_forms_is_the_analytic_jacobian():
    ungm = af.models.ungm()
    x = torch.tensor([[-3.0], [0.1], [0.0], [2.0], [25.0]], dtype=torch.float64, requires_grad=True)
    ungm.f_torch(x, 7).sum().backward()
    xn = x.detach().numpy()[:, 0]
    np.testing.assert_allclose(x.grad.numpy()[:, 0], 0.5 + 25 * (1 - xn**2) / (1 + xn**2) ** 2, rtol=1e-13)
    x.grad = None
    ungm.h_torch(x, 7).sum().backward()
    np.testing.assert_allclose(x.grad.numpy()[:, 0], xn / 10, rtol=1e-13)
    ctm = af.models.coordinated_turn()
    X = torch.from_numpy(states(ctm, 7)[1:]).requires_grad_(True)  # not the origin, where the bearing has none
    J = torch.autograd.functional.jacobian(lambda v: ctm.h_torch(v, 1).sum(0), X)[0]  # d bearing / d state, per run
    px, py = X.detach().numpy()[:, 0], X.detach().numpy()[:, 2]
    r2 = px**2 + py**2
    np.testing.assert_allclose(J[:, 0].numpy(), -py / r2, rtol=1e-12)
    np.testing.assert_allclose(J[:, 2].numpy(), px / r2, rtol=1e-12)
    np.testing.assert_allclose(J[:, [1, 3]].numpy(), 0.0, atol=0)
    Jf = torch.autograd.functional.jacobian(lambda v: ctm.f_torch(v, 1), X[:1])[0, :, 0, :]
    np.testing.assert_allclose(Jf.numpy(), ctm.F, rtol=0, atol=0)


def test_kalmannet_uses_the_torch_forms_and_falls_back_without_them():
    """UNGM with its torch forms and UNGM rebuilt without them filter to the same numbers; the gradient of a
    training loss agrees (exact against forward differences, to their accuracy)."""
    ungm = af.models.ungm()
    bare = af.StateSpaceModel(f=ungm.f, h=ungm.h, Q=ungm.Q, R=ungm.R, m0=ungm.m0, P0=ungm.P0, name="ungm",
                              n_steps=ungm.n_steps)
    z = ungm.simulate(6, 40, rng=4).z
    a, b = KalmanNet(ungm, seed=1, feature_norm="scale"), KalmanNet(bare, seed=1, feature_norm="scale")
    assert a._f_torch is not None and b._f_torch is None
    assert np.array_equal(a.run(z).mean, b.run(z).mean)
    grads = []
    for knet in (a, b):
        out, _ = knet._window(z, knet._z_prev(z), 0, knet._start(6))
        (out["mean"] ** 2).mean().backward()
        grads.append(np.concatenate([p.grad.numpy().ravel() for p in knet.net.parameters()]))
    np.testing.assert_allclose(grads[0], grads[1], rtol=1e-4, atol=1e-6 * np.abs(grads[0]).max())


def test_a_wrong_torch_form_is_an_error_naming_it():
    ungm = af.models.ungm()
    bad = af.StateSpaceModel(f=ungm.f, h=ungm.h, Q=ungm.Q, R=ungm.R, m0=ungm.m0, P0=ungm.P0, name="ungm-bad",
                             f_torch=lambda x, k: 0.5 * x)
    with pytest.raises(ValueError, match="'ungm-bad': f_torch does not equal its numpy form f"):
        KalmanNet(bad)
    KalmanNet(bad, model_grad="finite-difference")  # the numpy path does not use it
    with pytest.raises(ValueError, match="f_torch must be a callable"):
        af.StateSpaceModel(f=ungm.f, h=ungm.h, Q=ungm.Q, R=ungm.R, m0=ungm.m0, P0=ungm.P0, f_torch=3)
    # a model copied with another f keeps the old torch form: the filter refuses it by name
    import dataclasses

    with pytest.raises(ValueError, match="f_torch does not equal its numpy form f"):
        KalmanNet(dataclasses.replace(ungm, f=lambda x, k: 0.9 * x))
