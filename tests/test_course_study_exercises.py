"""The checkers of the implement-it-yourself exercises of chapters 8-17 (adaptfilt.course.study_exercises):
each accepts the right answer and a correct alternative, rejects at least three wrong ones and names the
slip; where the checker's reference is not a library function, it is checked against the library (greedy's
closed form against GreedyPolicy on the UKF, the two-level interval against seed_stats, the mismatched NIS
against a Kalman filter on mismatched data, the rollout value against RolloutPolicy)."""
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

import adaptfilt as af
from adaptfilt.course import study_exercises as sx


def _verdicts(capsys, check, right, wrong):
    """``check`` accepts every answer of ``right`` and rejects every ``(answer, says)`` of ``wrong``, printing
    ``says``."""
    assert len(wrong) >= 3 and right
    for fn in right:
        assert check(fn), fn
        assert "right" in capsys.readouterr().out
    for fn, says in wrong:
        assert not check(fn), says
        out = capsys.readouterr().out
        assert "not yet" in out and says in out, (says, out)
    assert not check(lambda *a: None)
    assert "returned None" in capsys.readouterr().out
    assert not check(lambda *a: 1 / 0)
    assert "ZeroDivisionError" in capsys.readouterr().out


# ------------------------------------------------------------------ chapter 8
def switch(probs, grid, feature, at_least, n_bins, op=np.greater_equal, x_of=np.abs, mid=np.median):
    share = probs[:, op(grid, at_least)].sum(axis=1)
    x = x_of(feature)
    parts = np.array_split(np.argsort(x), n_bins)
    return np.array([mid(x[p]) for p in parts]), np.array([share[p].mean() for p in parts])


def switch_by_edges(probs, grid, feature, at_least, n_bins):
    """A correct alternative: quantile edges and np.digitize (equal counts when N is a multiple of n_bins)."""
    x = np.abs(feature)
    edges = np.quantile(x, np.linspace(0, 1, n_bins + 1))
    b = np.clip(np.digitize(x, edges[1:-1], right=True), 0, n_bins - 1)
    share = probs[:, grid >= at_least].sum(1)
    return np.array([np.median(x[b == i]) for i in range(n_bins)]), np.array([share[b == i].mean() for i in range(n_bins)])


def test_switch_curve(capsys):
    argmax = lambda p, g, f, a, n: switch((p == p.max(1, keepdims=True)).astype(float), g, f, a, n)  # noqa: E731
    _verdicts(capsys, sx.check_switch_curve, [switch, switch_by_edges], [
        (lambda *a: switch(*a, op=np.greater), "the grid values > at_least"),
        (argmax, "most probable value is large"),
        (lambda *a: switch(*a, x_of=lambda f: f), "binned by the signed feature"),
        (lambda *a: switch(*a, mid=np.mean), "the bins' means of |feature|"),
        (lambda *a: (switch(*a)[0], 1 - switch(*a)[1]), "the complement")])


# ------------------------------------------------------------------ chapter 9
def greedy(grid, m, P, z, R, z_hat=lambda m, P: (m * m + P) / 20, with_R=True, kP2=True, cost=lambda nis: (nis - 1) ** 2):
    pzz = (4 * m * m * P + grid[:, None] * (P * P if kP2 else P)) / 400 + (R if with_R else 0)
    nis = (z - z_hat(m, P)) ** 2 / pzz
    return grid[np.argmin(cost(nis), axis=0)]


def test_greedy_kappa(capsys):
    _verdicts(capsys, sx.check_greedy_kappa, [greedy, lambda *a: greedy(*a, cost=lambda nis: np.abs(nis - 1))], [
        (lambda *a: greedy(*a, z_hat=lambda m, P: m * m / 20), "the predicted measurement m^2 / 20"),
        (lambda *a: greedy(*a, with_R=False), "P^zz without R"),
        (lambda *a: greedy(*a, kP2=False), "P^zz with kappa P"),
        (lambda *a: greedy(*a, cost=lambda nis: nis), "the kappa of the least NIS"),
        (lambda g, *a: np.searchsorted(g, greedy(g, *a)), "grid indices")])
    assert "exactly where NIS0 < 1" in (sx.check_greedy_kappa(greedy) and capsys.readouterr().out)


def test_greedy_kappa_is_the_greedy_policy_of_the_ukf():
    """The closed form the checker holds answers are what GreedyPolicy chooses on the real UKF of UNGM."""
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.mdp import rollout
    from adaptfilt.policies import GreedyPolicy

    exp = get_experiment("ungm-ukf")
    env = exp.make_env()
    traj = exp.make_model().simulate(n_runs=40, n_steps=501, rng=np.random.default_rng(0))
    run, _ = rollout(env, GreedyPolicy(grid=env.grid), traj=traj, keep_pred=True)
    m, P = run.x_pred[..., 0], run.P_pred[..., 0, 0]
    T = m.shape[1]
    mine = sx.greedy_kappa(np.asarray(env.grid), m.ravel(), P.ravel(), traj.z[:, :T, 0].ravel(),
                           float(env.filt.model.R[0, 0]))
    np.testing.assert_array_equal(mine, run.params.ravel())


# ------------------------------------------------------------------ chapter 10
def los(x, mean, cov, pos=(0, 2), u_of="x", sqrt=True, flip=1.0):
    p, e = x[..., list(pos)], x[..., list(pos)] - mean[..., list(pos)]
    d = p if u_of == "x" else mean[..., list(pos)]
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    v = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    Ppp = cov[..., list(pos), :][..., list(pos)]
    sd = lambda a: np.einsum("...i,...ij,...j->...", a, Ppp, a) ** (0.5 if sqrt else 1.0)  # noqa: E731
    return flip * (e * u).sum(-1), flip * (e * v).sum(-1), sd(u), sd(v)


def test_line_of_sight(capsys):
    _verdicts(capsys, sx.check_line_of_sight, [los, lambda *a: los(*a, flip=-1.0)], [   # either sign of the error
        (lambda *a: los(*a, u_of="mean"), "the line of sight of the estimate"),
        (lambda *a: los(*a, sqrt=False), "variances, not standard deviations"),
        (lambda x, m, c: los(x, m, c, pos=(0, 1)), "the components 0 and 1"),
        (lambda x, m, c: los(x, m, np.linalg.inv(c)), "the inverse covariance")])


# ------------------------------------------------------------------ chapter 11
def break_even(a, b, look=lambda c: c["n_iter_spent"] - c["mean_n_iter"]):
    la, lb = look(a), look(b)
    return np.inf if np.isclose(la, lb) else (b["cost"] - a["cost"]) / (la - lb)


def test_break_even(capsys):
    nan_if_equal = lambda a, b: np.nan if np.isinf(break_even(a, b)) else break_even(a, b)  # noqa: E731
    _verdicts(capsys, sx.check_break_even, [break_even, nan_if_equal], [
        (lambda a, b: break_even(a, b, look=lambda c: c["n_iter_spent"]), "every iteration spent"),
        (lambda a, b: break_even(a, b, look=lambda c: c["mean_n_iter"]), "the update's iterations"),
        (lambda a, b: -break_even(a, b), "the sign flipped"),
        (lambda a, b: 50 * break_even(a, b), "a factor 50 off")])


def test_break_even_price_equalises_the_charged_costs():
    for _, a, b in sx._break_even_cases()[:3]:
        p = sx.break_even(a, b)
        charged = [c["cost"] + p * (c["n_iter_spent"] - c["mean_n_iter"]) for c in (a, b)]
        assert charged[0] == pytest.approx(charged[1], rel=1e-12)


# ------------------------------------------------------------------ chapter 12
def pendulum(Q=(1e-4, 1e-2), R=0.01, shift=0, dt=0.1, swap=False, batched=True):
    def f(x, k):
        x = x[..., ::-1] if swap else x
        th, om = (x[..., 0], x[..., 1]) if batched else (x[0], x[1])
        y = np.stack([th + dt * om, om - dt * 9.81 / 2 * np.sin(th) + dt * 0.5 * np.cos(0.3 * (k + shift))], axis=-1)
        return y[..., ::-1] if swap else y

    return af.StateSpaceModel(f=f, h=lambda x, k: 2.0 * np.sin(x[..., :1]), Q=np.diag(Q), R=[[R]], m0=[0.5, 0.0],
                              P0=np.diag([0.1, 0.1]), n_steps=100)


def pendulum_scipy_style():
    """A correct alternative: f written with a matrix for the linear part, sin through a helper."""
    A = np.array([[1.0, 0.1], [0.0, 1.0]])

    def f(x, k):
        drive = np.zeros(x.shape)
        drive[..., 1] = -0.1 * 4.905 * np.sin(x[..., 0]) + 0.05 * np.cos(0.3 * k)
        return x @ A.T + drive

    return af.StateSpaceModel(f=f, h=lambda x, k: 2 * np.sin(x[..., 0:1]), Q=[[1e-4, 0], [0, 1e-2]], R=[[1e-2]],
                              m0=np.array([0.5, 0.0]), P0=0.1 * np.eye(2), n_steps=100, name="my pendulum")


def test_model(capsys):
    _verdicts(capsys, sx.check_model, [pendulum, pendulum_scipy_style], [
        (lambda: pendulum(Q=(1e-2, 1e-1)), "the standard deviations: the model takes variances"),
        (lambda: pendulum(shift=1), "the push at step k + 1"),
        (lambda: pendulum(dt=1.0), "no time step dt"),
        (lambda: pendulum(swap=True), "swaps theta and omega"),
        (lambda: pendulum(R=0.1), "R is [[0.1]]")])
    assert not sx.check_model(lambda: "a model")
    assert "not an af.StateSpaceModel" in capsys.readouterr().out


# ------------------------------------------------------------------ chapter 13
def two_level(values, boot, idx, stat=lambda a, axis=None: stats.trim_mean(a, 0.25, axis=axis), which="both"):
    B = idx.shape[0]
    rep = {"both": boot[idx, np.arange(B)[:, None]], "runs": boot.T, "seeds": values[idx]}[which]
    return stat(values), *np.quantile(stat(rep, axis=1), [0.025, 0.975])


def two_level_sorted(values, boot, idx):
    """A correct alternative: the IQM by sorting (middle half) and the interval as order statistics."""
    n, B = len(values), idx.shape[0]
    q = n // 4 if n % 4 == 0 else None
    iqm = (lambda a: stats.trim_mean(a, 0.25, axis=-1)) if q is None else (lambda a: np.sort(a, axis=-1)[..., q:n - q].mean(-1))
    rep = np.sort(iqm(boot[idx, np.arange(B)[:, None]]))
    return iqm(values), rep[int(0.025 * B)], rep[int(0.975 * B) - 1]


def test_two_level_iqm(capsys):
    _verdicts(capsys, sx.check_two_level_iqm, [two_level, two_level_sorted], [
        (lambda *a: two_level(*a, stat=lambda a, axis=None: np.mean(a, axis=axis)), "the mean over seeds"),
        (lambda *a: two_level(*a, stat=lambda a, axis=None: np.median(a, axis=axis)), "the median over seeds"),
        (lambda *a: two_level(*a, which="runs"), "the runs alone"),
        (lambda *a: two_level(*a, which="seeds"), "the seeds alone")])


def test_two_level_iqm_is_seed_stats():
    """The checker's reference with the seed draws seed_stats makes is seed_stats.aggregate's IQM interval."""
    from adaptfilt import seed_stats

    _, values, boot, _ = sx._iqm_cases()[0]
    names = [f"g-s{i}" for i in range(len(values))]
    results = {n: SimpleNamespace(rmse=v, boot_rmse=b) for n, v, b in zip(names, values, boot)}
    agg = seed_stats.aggregate(results, names, "rmse", seed=3)
    idx = np.random.default_rng([0xA66, 3]).integers(0, len(values), size=(boot.shape[1], len(values)))
    np.testing.assert_allclose(sx.two_level_iqm(values, boot, idx), [agg.iqm, *agg.iqm_ci], rtol=1e-12)


# ------------------------------------------------------------------ chapter 14
def candidates(filt, m, P, z, t, grid, cost=lambda nis, nz: np.log1p((nis - nz) ** 2), default=False):
    return np.stack([cost(filt.update(m, P, z, t, param=None if default else g).nis, z.shape[1]) for g in grid], axis=1)


def candidates_loop(filt, m, P, z, t, grid):
    """A correct alternative: run by run, with the NIS from the innovation and P^zz."""
    out = np.empty((len(m), len(grid)))
    for j, g in enumerate(grid):
        u = filt.update(m, P, z, t, param=g)
        for i in range(len(m)):
            nis = u.innovation[i] @ np.linalg.solve(u.Pzz[i], u.innovation[i])
            out[i, j] = np.log(1 + (nis - z.shape[1]) ** 2)
    return out


def test_candidate_costs(capsys):
    _verdicts(capsys, sx.check_candidate_costs, [candidates, candidates_loop], [
        (lambda *a: candidates(*a, cost=lambda nis, nz: nis), "the NIS itself"),
        (lambda *a: candidates(*a, cost=lambda nis, nz: (nis - nz) ** 2), "the raw cost"),
        (lambda *a: candidates(*a, cost=lambda nis, nz: np.log1p((nis - 1) ** 2)), "subtracts n_z, not 1"),
        (lambda *a: candidates(*a, default=True), "the default's NIS for every candidate")])


# ------------------------------------------------------------------ chapter 15
def nis_mean(F, H, Q, R, q, r, filter_noise=False):
    P = Q
    for _ in range(3000):
        P = F * F * P * R / (H * H * P + R) + Q
    K = P * H / (H * H * P + R)
    if filter_noise:    # the slip: the filter's own noise in the true error variance
        q, r = 1.0, 1.0
    sigma = (q * Q + F * F * K * K * r * R) / (1 - F * F * (1 - K * H) ** 2)
    return (H * H * sigma + r * R) / (H * H * P + R)


def nis_mean_lyapunov(F, H, Q, R, q, r):
    """A correct alternative: the joint steady state from scipy's Riccati and Lyapunov solvers."""
    from scipy import linalg

    P = linalg.solve_discrete_are(np.array([[F]]), np.array([[H]]), np.array([[Q]]), np.array([[R]]))[0, 0]
    K = P * H / (H * H * P + R)
    A = np.array([[F * (1 - K * H)]])
    sigma = linalg.solve_discrete_lyapunov(A, np.array([[q * Q + F * F * K * K * r * R]]))[0, 0]
    return (H * H * sigma + r * R) / (H * H * P + R)


def test_mismatched_nis(capsys):
    _verdicts(capsys, sx.check_mismatched_nis, [nis_mean, nis_mean_lyapunov], [
        (lambda *a: 1.0, "the NIS the filter expects of itself"),
        (lambda *a: 1.0 / nis_mean(*a), "the inverse ratio"),
        (lambda F, H, Q, R, q, r: nis_mean(F, H, Q, R, r, q), "the other way round"),
        (lambda *a: nis_mean(*a) * 1.01, "not yet")])


@pytest.mark.parametrize("case", sx._mismatch_cases()[:3], ids=lambda c: c[0])
def test_mismatched_nis_by_simulation(case):
    """The closed form against the library's Kalman filter on data from the mismatched truth."""
    _, F, H, Q, R, q, r = case
    from adaptfilt.models import linear_gaussian

    kw = dict(F=[[F]], H=[[H]], m0=[0.0])
    truth = linear_gaussian(Q=[[q * Q]], R=[[r * R]], P0=[[q * Q]], **kw)
    filt = af.KalmanFilter(linear_gaussian(Q=[[Q]], R=[[R]], P0=[[q * Q]], **kw))
    nis = filt.run(truth.simulate(4000, 80, rng=np.random.default_rng(15)).z).nis[:, 40:]
    ref = sx.mismatched_nis(F, H, Q, R, q, r)
    se = nis.mean(1).std() / np.sqrt(nis.shape[0])
    assert abs(nis.mean() - ref) < 4 * se


# ------------------------------------------------------------------ chapter 16
def rollout(L0, C, gamma, reduce=lambda C: C.min(axis=1).mean(axis=1), discount_L0=False):
    return (gamma if discount_L0 else 1.0) * L0 + gamma * reduce(C)


def rollout_loop(L0, C, gamma):
    """A correct alternative: loops over candidates and continuations."""
    G, _, S, M = C.shape
    Q = L0.copy()
    for g in range(G):
        for s in range(S):
            Q[g] += gamma * C[g, :, s].min(axis=0) / S
    return Q


def test_rollout_value(capsys):
    _verdicts(capsys, sx.check_rollout_value, [rollout, rollout_loop], [
        (lambda *a: rollout(*a, reduce=lambda C: C.mean(axis=2).min(axis=1)), "chosen once for all continuations"),
        (lambda L0, C, g: rollout(L0, C, 1.0), "no discount"),
        (lambda *a: rollout(*a, reduce=lambda C: C.mean(axis=(1, 2))), "a random base policy"),
        (lambda *a: rollout(*a, discount_L0=True), "the discount on L0 as well"),
        (lambda *a: rollout(*a, reduce=lambda C: C.min(axis=0).mean(axis=1)), "the wrong axis")])


def test_rollout_value_is_the_rollout_policy():
    """On a real UNGM decision, the reference of the checker applied to the look-ahead's own costs is
    RolloutPolicy(horizon=1).q."""
    from adaptfilt import lookahead as la
    from adaptfilt.costs import Cost
    from adaptfilt.mdp import FilterEnv

    model = af.models.ungm()
    env = FilterEnv(af.UKF(model), (0.0, 2.0, 20.0, 200.0), cost=Cost("nis"), n_steps=20)
    d = env.reset(traj=model.simulate(6, 20, rng=np.random.default_rng(16)))
    for _ in range(3):
        d, *_ = env.step(np.full(d.n_runs, env.default_index))
    pol = la.RolloutPolicy(env.grid, horizon=1, samples=5, gamma=0.5, seed=2)
    q = pol.q(d)
    look = la.lookahead_model(d)
    L0, Y0 = look.root()
    G, M = L0.shape
    noise = look.noise(pol._rng(d, la._NOISE), 1, 5)[0]
    Y = look.take(Y0, np.arange(G * M))
    C, _ = look.expand(Y, 1, noise, pol._rng(d, la._DRAWS, 1, 0), tile=G)
    C = C.reshape(G, G, 5, M).transpose(1, 0, 2, 3)     # [theta', (theta, s, m)] -> [theta, theta', s, m]
    np.testing.assert_allclose(sx.rollout_value(L0, C, 0.5), q, rtol=1e-12)


# ------------------------------------------------------------------ chapter 17
def kld(x, b, eps, delta, n_min, dof=1, z=lambda d: 1 - d, two=2.0, all_bins=False, use_n_min=True, strict=False):
    cells = np.floor(x / b)
    _, first = np.unique(cells, axis=0, return_index=True)
    new = np.zeros(len(x))
    new[first] = 1
    k = np.full(len(x), new.sum()) if all_bins else np.cumsum(new)
    n = np.arange(1, len(x) + 1)
    km1 = np.maximum(k - dof, 1)
    a = 2 / (9 * km1)
    bound = np.where(k > 1, km1 / (two * eps) * (1 - a + np.sqrt(a) * stats.norm.ppf(z(delta))) ** 3, 1)
    ok = ((n > bound) if strict else (n >= bound)) & ((n >= n_min) if use_n_min else True)
    return int(n[ok.argmax()]) if ok.any() else len(x)


def kld_chi2(x, b, eps, delta, n_min):
    """A correct alternative (the chapter shows it agrees to a particle): the exact chi-square quantile, one
    particle at a time with a set of bins."""
    seen = set()
    for n, p in enumerate(np.floor(x / b).astype(int), start=1):
        seen.add(tuple(np.atleast_1d(p)))
        k = len(seen)
        if n >= n_min and n >= (stats.chi2.ppf(1 - delta, k - 1) / (2 * eps) if k > 1 else 1):
            return n
    return len(x)


def test_kld_count(capsys):
    _verdicts(capsys, sx.check_kld_count, [kld, kld_chi2, lambda *a: kld(*a, strict=True)], [
        (lambda *a: kld(*a, dof=0), "k, not k - 1"),
        (lambda *a: kld(*a, z=lambda d: 1 - d / 2), "z_{1 - delta/2}"),
        (lambda *a: kld(*a, two=1.0), "without the factor 2"),
        (lambda *a: kld(*a, all_bins=True), "the bins of all the particles"),
        (lambda *a: kld(*a, use_n_min=False), "n_min left out")])
