"""The checkers of the implement-it-yourself exercises of chapters 1, 3, 4, 5, 6, 7 and 18
(adaptfilt.course.exercises): each accepts the right answer and rejects wrong ones, naming the
slip where it can (issue 37, item 6)."""
import numpy as np
import pytest

from adaptfilt.course import exercises as ex


def _gauss(r, var):
    return np.exp(-0.5 * r * r / var) / np.sqrt(2 * np.pi * var)


def bayes_step(model, grid, prev, z, t, predict=True, like=True, normalise=True):
    dx = grid[1] - grid[0]
    Q, R = float(model.Q[0, 0]), float(model.R[0, 0])
    trans = _gauss(grid[:, None] - model.f(grid[:, None], t)[:, 0][None, :], Q)
    pred = trans @ prev * dx if predict else prev
    post = (_gauss(z - model.h(grid[:, None], t + 1)[:, 0], R) if like else 1.0) * pred
    return post / (post.sum() * dx) if normalise else post


def test_bayes_step(capsys):
    assert ex.check_bayes_step(bayes_step)
    assert "right" in capsys.readouterr().out
    for kw, says in ((dict(predict=False), "prediction step (3b) is missing"),
                     (dict(like=False), "predictive density"),
                     (dict(normalise=False), "integrates to")):
        assert not ex.check_bayes_step(lambda *a, kw=kw: bayes_step(*a, **kw))
        assert says in capsys.readouterr().out
    assert not ex.check_bayes_step(lambda *a: None)
    assert "returned None" in capsys.readouterr().out
    assert not ex.check_bayes_step(lambda m, g, p, z, t: bayes_step(m, g, p, z, t + 1))   # off by a step
    assert not ex.check_bayes_step(lambda *a: 1 / 0)
    assert "ZeroDivisionError" in capsys.readouterr().out


def discounted(costs, t0, gamma):
    T = costs.shape[-1]
    return (costs[:, :, t0:] * gamma ** np.arange(T - t0)).sum(-1).argmin(0)


def test_discounted_choice(capsys):
    assert ex.check_discounted_choice(discounted)
    capsys.readouterr()
    wrong = {"myopic choice": lambda c, t0, g: c[:, :, t0].argmin(0),
             "sum from step 0": lambda c, t0, g: (c * g ** np.arange(c.shape[-1])).sum(-1).argmin(0),
             "undiscounted": lambda c, t0, g: c[:, :, t0:].sum(-1).argmin(0),
             "argmax": lambda c, t0, g: (c[:, :, t0:] * g ** np.arange(c.shape[-1] - t0)).sum(-1).argmax(0)}
    for says, fn in wrong.items():
        assert not ex.check_discounted_choice(fn)
        assert says in capsys.readouterr().out
    assert not ex.check_discounted_choice(lambda c, t0, g: discounted(c, t0, g)[:-1])   # a run short


def nis_cost(nu, Pzz):
    nis = np.einsum("mi,mi->m", nu, np.linalg.solve(Pzz, nu[..., None])[..., 0])
    return (nis - nu.shape[1]) ** 2


def test_nis_cost(capsys):
    assert ex.check_nis_cost(nis_cost)
    assert ex.check_nis_cost(lambda nu, P: (np.einsum("mi,mij,mj->m", nu, np.linalg.inv(P), nu) - nu.shape[1]) ** 2)
    capsys.readouterr()
    nis = lambda nu, P: np.einsum("mi,mi->m", nu, np.linalg.solve(P, nu[..., None])[..., 0])  # noqa: E731
    wrong = {"the NIS itself": nis,
             "mean n_z, not 1": lambda nu, P: (nis(nu, P) - 1) ** 2,
             "diagonal of Pzz only": lambda nu, P: ((nu ** 2 / np.diagonal(P, axis1=1, axis2=2)).sum(1)
                                                    - nu.shape[1]) ** 2,
             "without the square": lambda nu, P: nis(nu, P) - nu.shape[1]}
    for says, fn in wrong.items():
        assert not ex.check_nis_cost(fn)
        assert says in capsys.readouterr().out
    # the transpose of the inverse is the same for a symmetric Pzz: only a genuinely wrong form fails
    assert not ex.check_nis_cost(lambda nu, P: (np.einsum("mi,mi->m", nu, nu) - nu.shape[1]) ** 2)


def paired(a, b, counts):
    rep = counts @ (a - b) / len(a)
    lo, hi = np.quantile(rep, [0.025, 0.975])
    return np.mean(a - b), lo, hi


def test_paired_ci(capsys):
    assert ex.check_paired_ci(paired)
    capsys.readouterr()

    def unpaired(a, b, counts):
        ia = np.quantile(counts @ a / len(a), [0.025, 0.975])
        ib = np.quantile(counts @ b / len(b), [0.025, 0.975])
        return np.mean(a - b), ia[0] - ib[1], ia[1] - ib[0]

    def ninety(a, b, counts):
        rep = counts @ (a - b) / len(a)
        return (np.mean(a - b), *np.quantile(rep, [0.05, 0.95]))

    def independent(a, b, counts):   # b resampled with other counts: unpaired, wide, named by its width
        rep = (counts @ a - counts[::-1] @ b) / len(a)
        return (np.mean(a - b), *np.quantile(rep, [0.025, 0.975]))

    for fn, says in ((unpaired, "unpaired"), (ninety, "90 %"), (lambda a, b, c: paired(b, a, c), "b - a"),
                     (independent, "times as wide")):
        assert not ex.check_paired_ci(fn)
        assert says in capsys.readouterr().out
    def normal(a, b, counts):        # a normal approximation: close, not the percentile interval
        d = a - b
        s = d.std(ddof=1) / np.sqrt(len(d))
        return d.mean(), d.mean() - 1.96 * s, d.mean() + 1.96 * s

    assert not ex.check_paired_ci(normal)
    assert not ex.check_paired_ci(lambda a, b, c: (0.0, 0.0))
    assert "three numbers" in capsys.readouterr().out


def kalmannet_step(model, gain, t, z_t, z_prev, x_filt, x_filt_prev, x_pred, wrap=True, first=True, f4="prev"):
    diff = model.diff_z if wrap else (lambda a, b: a - b)
    m0 = np.broadcast_to(model.m0, x_filt.shape).copy()
    x_pred_new = m0 if (t == 0 and first) else model.f(x_filt, t)
    innov = diff(z_t, model.h(x_pred_new, t + 1))
    F4 = x_filt - (x_pred if f4 == "prev" else x_pred_new)
    K = gain(diff(z_t, z_prev), innov, x_filt - x_filt_prev, F4)
    return x_pred_new, x_pred_new + (K @ innov[..., None])[..., 0]


def test_kalmannet_step(capsys):
    assert ex.check_kalmannet_step(kalmannet_step)
    assert "right" in capsys.readouterr().out
    for kw, says in ((dict(wrap=False), "must be wrapped"),
                     (dict(first=False), "at the first step the prediction is the prior mean"),
                     (dict(f4="new"), "F4 = x_{t-1|t-1} - x_{t-1|t-2}")):
        assert not ex.check_kalmannet_step(lambda *a, kw=kw: kalmannet_step(*a, **kw))
        assert says in capsys.readouterr().out
    assert not ex.check_kalmannet_step(lambda *a: None)
    assert "returned None" in capsys.readouterr().out
    assert not ex.check_kalmannet_step(lambda *a: (1, 2))
    assert "expected two of" in capsys.readouterr().out


def score_gradient(theta, actions, costs, baseline):
    """A correct alternative to the library's: autograd through log softmax, one sample at a time."""
    import torch

    th = torch.tensor(theta, dtype=torch.float64, requires_grad=True)
    logp = torch.log_softmax(th, dim=0)[torch.as_tensor(actions)]
    ((torch.as_tensor(costs) - baseline) * logp).mean().backward()
    return th.grad.numpy()


def test_score_gradient(capsys):
    assert ex.check_score_gradient(score_gradient)
    assert "right" in capsys.readouterr().out
    from adaptfilt.course.policy_gradient import softmax

    def loop(theta, a, c, b, sign=1.0, minus_pi=True, times_pi=False, base=True, mean=True):
        pi, g = softmax(theta), np.zeros(len(theta))
        for an, cn in zip(a, c):
            score = np.eye(len(theta))[an] - (pi if minus_pi else 0.0)
            g += sign * (cn - (b if base else 0.0)) * (pi[an] if times_pi else 1.0) * score
        return g / len(a) if mean else g

    assert ex.check_score_gradient(loop)
    capsys.readouterr()
    for says, kw in (("a reward", dict(sign=-1.0)), ("without -pi", dict(minus_pi=False)),
                     ("grad pi_a, not grad log pi_a", dict(times_pi=True)), ("without the baseline", dict(base=False)),
                     ("a sum over the batch", dict(mean=False))):
        assert not ex.check_score_gradient(lambda *a, kw=kw: loop(*a, **kw))
        assert says in capsys.readouterr().out
    assert not ex.check_score_gradient(lambda th, a, c, b: np.zeros(2))
    assert "shape" in capsys.readouterr().out


def test_gae_checker_of_chapter_7(capsys):
    """ppo_step.check_gae (chapter 7): a correct alternative in matrix form is accepted; three slips
    are rejected and named (tests/test_ppo_step.py has the rest)."""
    from adaptfilt.course.ppo_step import check_gae

    def matrix_form(c, v, last, gamma, lam, weight=None, boot=1.0, sign=1.0):
        K = c.shape[0]
        delta = c + gamma * np.vstack([v[1:], boot * last[None]]) - v
        w = gamma * lam if weight is None else weight(gamma, lam)
        upper = np.triu(w ** (np.arange(K)[None, :] - np.arange(K)[:, None]).clip(0))   # A = U delta
        return sign * upper @ delta

    assert check_gae(matrix_form)
    capsys.readouterr()
    for says, kw in (("lambda alone", dict(weight=lambda g, lam: lam)), ("a reward's sign", dict(sign=-1.0)),
                     ("no bootstrap", dict(boot=0.0))):
        assert not check_gae(lambda *a, kw=kw: matrix_form(*a, **kw))
        assert says in capsys.readouterr().out
