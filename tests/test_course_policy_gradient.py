"""adaptfilt.course.policy_gradient: chapter 6's policy gradient derived on toys, against finite
differences, Monte Carlo and policy evaluation by iteration."""
import numpy as np
import pytest


def test_exact_policy_gradient_is_the_finite_difference_of_the_expected_cost():
    from adaptfilt.course import policy_gradient as pg

    rng = np.random.default_rng(0)
    for K in (2, 3, 5):
        theta, c = rng.standard_normal(K), rng.standard_normal(K) * 3
        J = lambda th: pg.softmax(th) @ c
        fd = np.array([(J(theta + 1e-6 * e) - J(theta - 1e-6 * e)) / 2e-6 for e in np.eye(K)])
        assert np.allclose(pg.exact_gradient(theta, c), fd, atol=1e-8)


def test_reinforce_is_unbiased_for_every_baseline_and_the_value_baseline_shrinks_it():
    """The mean of many estimates lies within 4 standard errors of the exact gradient, whatever the
    baseline; the baseline at the expected cost has a smaller spread than none, a far one a larger."""
    from adaptfilt.course import policy_gradient as pg

    theta, c = np.array([0.3, -0.2, 0.5]), np.array([1.0, 0.0, 2.0])
    J = pg.softmax(theta) @ c
    sd = {}
    for b in (0.0, J, 5.0):
        s = pg.estimator_spread(theta, c, n=8, repeats=3000, seed=1, baseline=b)
        assert np.all(np.abs(s["mean"] - s["exact"]) < 4 * s["sd"] / np.sqrt(3000) + 1e-12), b
        sd[b] = s["sd"].sum()
    assert sd[J] < sd[0.0] < sd[5.0]
    with pytest.raises(ValueError, match="one length"):
        pg.score_function_estimate(theta, np.array([0, 1]), np.array([1.0]))


def test_trap_values_solve_the_bellman_equations_and_the_td_error_is_the_advantage():
    """trap_values against policy evaluation by iteration; one step of TrapEnv with that exact critic
    gives TD errors equal to the advantages, for several discounts and policies."""
    from adaptfilt.course import policy_gradient as pg
    from adaptfilt.toy import TrapEnv

    for gamma, p in ((0.5, 0.5), (0.9, 0.2), (0.0, 0.7), (0.3, 1.0)):
        v_good, v_bad = 0.0, 0.0
        for _ in range(2000):  # iterative policy evaluation, an independent computation
            v_good, v_bad = (p * (0.25 + gamma * v_good) + (1 - p) * (0.0 + gamma * v_bad), 1.0 + gamma * v_bad)
        v = pg.trap_values(gamma, p)
        assert np.isclose(v["V_good"], v_good) and np.isclose(v["V_bad"], v_bad)
        assert np.isclose(p * v["Q_safe"] + (1 - p) * v["Q_trap"], v["V_good"])
        td = pg.trap_td_errors(TrapEnv(), gamma, p, n_runs=200, seed=3)
        for a, name in ((0, "trap"), (1, "safe")):
            assert np.allclose(td["delta"][td["actions"] == a], v[f"A_{name}"])
    with pytest.raises(ValueError, match="gamma"):
        pg.trap_values(1.0, 0.5)
