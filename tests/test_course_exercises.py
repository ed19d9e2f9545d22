"""The checkers of the implement-it-yourself exercises of chapters 1, 3, 4, 5, 6, 7 and 18
(adaptfilt.course.exercises): each accepts the right answer and rejects wrong ones, naming the
slip where it can (the course's rule)."""
import numpy as np
import pytest

from adaptfilt.course import exercises as ex


def _gauss(r, var):
    return np.exp(-0.5 * r * r / var) / np.sqrt(2 * np.pi * var)


def bayes_step(model, grid, prev, z, t, predict=True, like=True, normalise=True, Q=None, R=None, tf=0, th=1):
    dx = grid[1] - grid[0]
    Q = float(model.Q[0, 0]) if Q is None else Q(float(model.Q[0, 0]))
    R = float(model.R[0, 0]) if R is None else R(float(model.R[0, 0]))
    trans = _gauss(grid[:, None] - model.f(grid[:, None], t + tf)[:, 0][None, :], Q)
    pred = trans @ prev * dx if predict else prev
    post = (_gauss(z - model.h(grid[:, None], t + th)[:, 0], R) if like else 1.0) * pred
    return post / (post.sum() * dx) if normalise else post


def bayes_step_loop(model, grid, prev, z, t):
    """A correct alternative: scipy's normal density with the standard deviation, a loop over the grid
    points for the prediction and the trapezoid rule for the normalisation."""
    from scipy.stats import norm

    sq, sr = np.sqrt(model.Q[0, 0]), np.sqrt(model.R[0, 0])
    fx = model.f(grid[:, None], t)[:, 0]
    dx = grid[1] - grid[0]
    pred = np.array([np.sum(norm.pdf(x, loc=fx, scale=sq) * prev) * dx for x in grid])
    post = norm.pdf(z, loc=model.h(grid[:, None], t + 1)[:, 0], scale=sr) * pred
    return post / np.trapezoid(post, grid)


def test_bayes_step(capsys):
    for right in (bayes_step, bayes_step_loop):
        assert ex.check_bayes_step(right)
        assert "right" in capsys.readouterr().out
    wrong = {  # the three the readers found accepted when every case had Q = 1 and a fixed h
             "Q (here 2.5) is ignored": dict(Q=lambda q: 1.0),
             "Q is a variance, not a standard deviation": dict(Q=lambda q: q * q),
             "h is taken at step t": dict(th=0),
             # and the others
             "prediction step (3b) is missing": dict(predict=False),
             "predictive density": dict(like=False),
             "integrates to": dict(normalise=False),
             "R is a variance, not a standard deviation": dict(R=lambda r: r * r),
             "R (here 0.1) is ignored": dict(R=lambda r: 1.0),
             "f is taken at step t + 1": dict(tf=1),
             "f is taken at step t - 1": dict(tf=-1)}
    for says, kw in wrong.items():
        assert not ex.check_bayes_step(lambda *a, kw=kw: bayes_step(*a, **kw)), says
        assert says in capsys.readouterr().out
    # a slip the checker cannot name is still rejected
    assert not ex.check_bayes_step(lambda *a: bayes_step(*a, Q=np.sqrt))
    assert "not yet" in capsys.readouterr().out
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
    T = lambda c: c.shape[-1]  # noqa: E731
    wrong = {"the sum from t0 + 1": lambda c, t0, g: (c[:, :, t0 + 1:] * g ** np.arange(T(c) - t0 - 1)).sum(-1).argmin(0),
             "stops one step early": lambda c, t0, g: (c[:, :, t0:-1] * g ** np.arange(T(c) - t0 - 1)).sum(-1).argmin(0),
             "run backwards": lambda c, t0, g: (c[:, :, t0:] * g ** np.arange(T(c) - t0)[::-1]).sum(-1).argmin(0),
             "not yet": lambda c, t0, g: (c[:, :, t0:] * (1 - g) ** np.arange(T(c) - t0)).sum(-1).argmin(0)}
    for says, fn in wrong.items():
        assert not ex.check_discounted_choice(fn)
        assert says in capsys.readouterr().out
    # correct alternatives: weights that scale every value's sum alike, a weighted mean, a loop
    right = [lambda c, t0, g: (c[:, :, t0:] * g ** np.arange(1, T(c) - t0 + 1)).sum(-1).argmin(0),
             lambda c, t0, g: (c[:, :, t0:] * g ** np.arange(t0, T(c))).sum(-1).argmin(0),
             lambda c, t0, g: np.average(c[:, :, t0:], axis=-1, weights=g ** np.arange(T(c) - t0)).argmin(0),
             lambda c, t0, g: np.array([min(range(c.shape[0]), key=lambda i: sum(
                 g ** j * c[i, m, t0 + j] for j in range(T(c) - t0))) for m in range(c.shape[1])])]
    for fn in right:
        assert ex.check_discounted_choice(fn)
        assert "right" in capsys.readouterr().out


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
    wrong = {"Pzz itself, not its inverse": lambda nu, P: (np.einsum("mi,mij,mj->m", nu, P, nu) - nu.shape[1]) ** 2,
             "the trainers' transform": lambda nu, P: np.log1p((nis(nu, P) - nu.shape[1]) ** 2),
             "divided by n_z": lambda nu, P: (nis(nu, P) / nu.shape[1] - 1) ** 2,
             "one cost per run": lambda nu, P: ((nis(nu, P) - nu.shape[1]) ** 2).sum(keepdims=True),
             "not yet": lambda nu, P: (np.sqrt(nis(nu, P)) - nu.shape[1]) ** 2}
    for says, fn in wrong.items():
        assert not ex.check_nis_cost(fn)
        assert says in capsys.readouterr().out
    # correct alternatives: the transposed Pzz (symmetric), a Cholesky whitening
    assert ex.check_nis_cost(lambda nu, P: (np.einsum("mi,mi->m", nu, np.linalg.solve(np.swapaxes(P, 1, 2),
                                                                                     nu[..., None])[..., 0])
                                            - nu.shape[1]) ** 2)
    assert ex.check_nis_cost(lambda nu, P: ((np.linalg.solve(np.linalg.cholesky(P), nu[..., None])[..., 0] ** 2).sum(1)
                                            - nu.shape[1]) ** 2)
    assert "right" in capsys.readouterr().out


def paired(a, b, counts):
    rep = counts @ (a - b) / len(a)
    lo, hi = np.quantile(rep, [0.025, 0.975])
    return np.mean(a - b), lo, hi


def paired_sorted(a, b, counts, lo_hi=(24, 974)):
    """The percentile interval as order statistics of the sorted replicates (a textbook convention)."""
    rep = np.sort(counts @ (a - b) / len(a))
    return np.mean(a - b), rep[lo_hi[0]], rep[lo_hi[1]]


def test_paired_ci(capsys):
    assert ex.check_paired_ci(paired)
    assert "up to the percentile convention" not in capsys.readouterr().out
    # correct alternatives: the readers' 25th and 975th of 1000 sorted replicates (rejected before at rtol
    # 1e-9), sorted[int(B a)], the (B + 1) a-th and numpy's other conventions
    for right in (paired_sorted, lambda a, b, c: paired_sorted(a, b, c, (25, 975)),
                  lambda a, b, c: paired_sorted(a, b, c, (int(0.025 * 1001) - 1, int(0.975 * 1001) - 1)),
                  lambda a, b, c: (np.mean(a - b), *np.quantile(c @ (a - b) / len(a), [0.025, 0.975],
                                                               method="inverted_cdf"))):
        assert ex.check_paired_ci(right)
        assert "up to the percentile convention" in capsys.readouterr().out

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

    def normal(a, b, counts):        # a normal approximation: close, not the percentile interval
        d = a - b
        s = d.std(ddof=1) / np.sqrt(len(d))
        return d.mean(), d.mean() - 1.96 * s, d.mean() + 1.96 * s

    def basic(a, b, counts):         # the reflected interval: on a skewed difference, lopsided the other way
        m, lo, hi = paired(a, b, counts)
        return m, 2 * m - hi, 2 * m - lo

    for fn, says in ((unpaired, "unpaired"), (ninety, "90 %"), (lambda a, b, c: paired(b, a, c), "b - a"),
                     (independent, "times as wide"), (normal, "normal approximation (diff +- 1.96 standard "
                                                              "errors, ddof = 1)"),
                     (basic, "basic (reflected)"),
                     (lambda a, b, c: paired_sorted(a, b, c, (22, 977)), "not yet")):   # three replicates off
        assert not ex.check_paired_ci(fn)
        assert says in capsys.readouterr().out
    assert not ex.check_paired_ci(lambda a, b, c: (0.0, 0.0))
    assert "three numbers" in capsys.readouterr().out


def kalmannet_step(model, gain, t, z_t, z_prev, x_filt, x_filt_prev, x_pred, wrap=True, wrap_f1=True, first=True,
                   f4="prev", tf=0, th=1, signs=False, swap34=False):
    diff = model.diff_z if wrap else (lambda a, b: a - b)
    diff1 = diff if wrap_f1 else (lambda a, b: a - b)
    m0 = np.broadcast_to(model.m0, x_filt.shape).copy()
    x_pred_new = m0 if (t == 0 and first) else model.f(x_filt, t + tf)
    innov = diff(z_t, model.h(x_pred_new, t + th))
    F3, F4 = x_filt - x_filt_prev, x_filt - (x_pred if f4 == "prev" else x_pred_new)
    feats = (diff1(z_t, z_prev), innov, *((F4, F3) if swap34 else (F3, F4)))
    K = gain(*(np.sign(F) if signs else F for F in feats))
    return x_pred_new, x_pred_new + (K @ innov[..., None])[..., 0]


def kalmannet_step_einsum(model, gain, t, z_t, z_prev, x_filt, x_filt_prev, x_pred):
    """A correct alternative: the prior mean by np.tile, the gain applied with einsum."""
    x_new = np.tile(model.m0, (len(x_filt), 1)) if t == 0 else model.f(x_filt, t)
    innov = model.diff_z(z_t, model.h(x_new, t + 1))
    K = gain(model.diff_z(z_t, z_prev), innov, x_filt - x_filt_prev, x_filt - x_pred)
    return x_new, x_new + np.einsum("mij,mj->mi", K, innov)


def test_kalmannet_step_cases_tell_the_slips_apart():
    """The checker's cases can show the slips: the CTM runs cross +-pi, its own recursion without a slip
    is the library's KalmanNet.run, and its network is not L2-normalised."""
    cases = {name.split(",")[0]: (model, z) for name, model, z in ex._kalmannet_cases()}
    model, z = cases["bearing-only CTM"]
    assert (np.abs(np.diff(z[..., 0], axis=1)) > np.pi).any(1).all()      # every run crosses
    for model, z in cases.values():
        knet = ex._kalmannet_net(model)
        assert knet.options["feature_norm"] != "l2"
        np.testing.assert_allclose(ex._kalmannet_variant(model, z, z.shape[1] - 1), knet.run(z).mean[:, -1],
                                   rtol=1e-10, atol=1e-10)


def test_kalmannet_step(capsys):
    for right in (kalmannet_step, kalmannet_step_einsum):
        assert ex.check_kalmannet_step(right)
        assert "right" in capsys.readouterr().out
    wrong = [  # the three the readers found accepted (time indices, F1 unwrapped alone, signs) first
        (dict(tf=-1), "f taken at step t - 1"), (dict(th=0), "h taken at step t: "),
        (dict(tf=-1, th=0), "h taken at step t: "),  # the reader's answer had both: f(x, t - 1), h(x, t)
        (dict(wrap_f1=False), "F1 = z_t - z_prev unwrapped"), (dict(signs=True), "passed as their signs"),
        (dict(wrap=False, wrap_f1=False), "the bearing's differences unwrapped"),
        (dict(first=False), "at t = 0 the prediction is the prior mean"),
        (dict(f4="new"), "F4 taken against the new prediction"),
        (dict(swap34=True), "F3 and F4 swapped"), (dict(tf=1), "f taken at step t + 1")]
    for kw, says in wrong:
        assert not ex.check_kalmannet_step(lambda *a, kw=kw: kalmannet_step(*a, **kw)), kw
        assert says in capsys.readouterr().out, kw
    # the readers' form: only F1 and F2 as their signs (an L2-normalised network could not tell)
    signs12 = lambda m, g, *a: kalmannet_step(m, lambda F1, F2, F3, F4: g(np.sign(F1), np.sign(F2), F3, F4), *a)  # noqa: E731
    assert not ex.check_kalmannet_step(signs12)
    assert "not yet" in capsys.readouterr().out
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
