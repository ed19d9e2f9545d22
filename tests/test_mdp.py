"""The MDP environment (adaptfilt.mdp) and the baseline policies: the env
reproduces the plain filters, costs are what Section V-E says, the ML and
greedy baselines are the brute-force argmax/argmin, bad input is refused."""
import numpy as np
import pytest

import adaptfilt as af
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.mdp import Cost, FilterEnv, rollout
from adaptfilt.metrics import chi2_bounds
from adaptfilt.policies import FixedPolicy, GreedyPolicy, MaxLikelihoodPolicy


def traj_of(model, M, T, seed=0):
    return model.simulate(M, T, rng=np.random.default_rng(seed))


# ------------------------------------------------- env == plain filter runs
@pytest.mark.parametrize("model_fn, kappa", [(af.models.ungm, 10.0), (af.models.coordinated_turn, -0.5)])
def test_fixed_policy_reproduces_ukf_run_exactly(model_fn, kappa):
    model = model_fn()
    traj = traj_of(model, 40, 30)
    grid = [-0.5, 0.0, 2.0, 10.0] if model.nx == 4 else [0.0, 2.0, 10.0]
    env = FilterEnv(af.UKF(model), grid, cost=Cost("nis"), n_steps=30)
    run, cost = rollout(env, FixedPolicy(kappa, "kappa"), traj=traj)
    ref = af.UKF(model).run(traj.z, params=kappa)
    for f in ("mean", "cov", "nis", "loglik", "params"):
        np.testing.assert_array_equal(getattr(run, f), getattr(ref, f), err_msg=f)
    np.testing.assert_array_equal(cost, (ref.nis - 1.0) ** 2)


def test_fixed_n_iter_reproduces_sif_run_with_same_seed():
    model = af.models.coordinated_turn()
    traj = traj_of(model, 30, 20, seed=3)
    env = FilterEnv(af.SIF(model, seed=7), [1.0, 3.0, 10.0], n_steps=20)
    run, _ = rollout(env, FixedPolicy(3, "n_iter"), traj=traj)
    ref = af.SIF(model, seed=7).run(traj.z, params=3)
    for f in ("mean", "cov", "nis", "loglik"):
        np.testing.assert_array_equal(getattr(run, f), getattr(ref, f), err_msg=f)
    # a different seed gives different numbers: the comparison above can fail
    other = af.SIF(model, seed=8).run(traj.z, params=3)
    assert not np.array_equal(other.mean, ref.mean)


def test_features_are_lazy_and_stay_with_their_decision():
    model = af.models.ungm()
    env = FilterEnv(af.UKF(model), [0.0, 2.0, 10.0], cost=Cost("nis"), n_steps=5)
    d0 = env.reset(traj=traj_of(model, 6, 5))
    d1, *_ = env.step(np.zeros(6, dtype=int))
    assert d0._obs == {} and d0.extra_spent == 0  # nobody asked: no extra default-parameter update was run
    f0 = d0.features  # read after the env moved on: still the state of step 0
    np.testing.assert_array_equal(f0[:, 0], model.m0[0])
    np.testing.assert_array_equal(f0[:, 1], model.P0[0, 0])
    assert not np.array_equal(d1.features[:, 0], f0[:, 0])


# ------------------------------------------------------------------- costs
def _one_step(filt, grid, cost, M=8, seed=1, t_steps=3, action=1):
    """Advance the env ``t_steps`` with the default, then step once with ``action``;
    returns (cost from the env, the public Update with the same parameter)."""
    model = filt.model
    env = FilterEnv(filt, grid, cost=cost, n_steps=t_steps + 1)
    d = env.reset(traj=traj_of(model, M, t_steps + 1, seed))
    for _ in range(t_steps):
        d, *_ = env.step(np.full(M, d.default_index))
    a = np.arange(M) % len(grid)  # a different value per run
    x_pred, P_pred, z, t = d.x_pred.copy(), d.P_pred.copy(), d.z.copy(), d.t
    _, c, done, info = env.step(a)
    assert done
    u = filt.update(x_pred, P_pred, z, t, param=np.asarray(grid)[a])
    np.testing.assert_array_equal(info["nis"], u.nis)
    return c, u, np.asarray(grid)[a]


def test_nis_cost_by_hand():
    c, u, _ = _one_step(af.UKF(af.models.ungm()), [0.0, 2.0, 50.0], Cost("nis"))
    innov, Pzz = u.innovation[:, 0], u.Pzz[:, 0, 0]
    np.testing.assert_allclose(c, (innov**2 / Pzz - 1.0) ** 2, rtol=1e-12)


def test_logmaxnis_cost_by_hand():
    c, u, _ = _one_step(af.UKF(af.models.coordinated_turn()), [-0.5, 0.0, 5.0], Cost("logmaxnis"))
    nis = u.innovation[:, 0] ** 2 / u.Pzz[:, 0, 0]
    np.testing.assert_allclose(c, np.log(1.0 + np.maximum(0.0, nis - 1.0)), rtol=1e-12)


def test_stateinnov_plus_iterations_cost_by_hand():
    c, u, theta = _one_step(af.SIF(af.models.coordinated_turn(), seed=2), [1.0, 3.0, 10.0], Cost("stateinnov", 1 / 50))
    dx = np.stack([u.K[l] @ u.innovation[l] for l in range(len(c))])
    np.testing.assert_allclose(c, np.linalg.norm(dx, axis=1) + theta / 50.0, rtol=1e-12)
    assert set(theta) == {1.0, 3.0, 10.0}


def test_nis_of_a_consistent_linear_filter_averages_nz():
    model = af.models.linear_gaussian(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=0.1 * np.eye(2), R=[[0.5]],
                                      m0=[0.0, 1.0], P0=np.eye(2), n_steps=40)
    gaf = af.GaussianAssumedFilter(model, af.rules.UnscentedRule(), param=1.0)
    env = FilterEnv(gaf, [0.5, 1.0, 3.0], cost=Cost("nis"))
    M = 500
    run, cost = rollout(env, FixedPolicy(1.0), n_runs=M, rng=np.random.default_rng(4))
    lo, hi = chi2_bounds(model.nz, M * model.n_steps)
    assert lo < run.nis.mean() < hi
    np.testing.assert_allclose(cost, (run.nis - 1.0) ** 2)
    # an inflated R makes the filter pessimistic: the same check then fails
    model2 = af.models.linear_gaussian(model.F, model.H, model.Q, 3.0 * model.R, model.m0, model.P0, n_steps=40)
    traj = traj_of(model, M, 40, seed=4)
    nis2 = af.GaussianAssumedFilter(model2, af.rules.UnscentedRule(), param=1.0).run(traj.z).nis
    assert not lo < nis2.mean() < hi


# ------------------------------------------------ ML and greedy = brute force
@pytest.mark.parametrize("name", ["ungm-ukf", "ctm-ukf"])
def test_ml_and_greedy_pick_brute_force_argmax_argmin(name):
    exp = get_experiment(name)
    env = exp.make_env(n_steps=6)
    M, grid = 25, np.asarray(exp.grid)
    d = env.reset(traj=exp.make_model().simulate(M, 6, rng=np.random.default_rng(5)))
    for _ in range(5):
        brute_ll = np.empty((grid.size, M))
        brute_cost = np.empty((grid.size, M))
        for i, g in enumerate(grid):
            u = env.filt.update(d.x_pred, d.P_pred, d.z, d.t, param=g)
            brute_ll[i], brute_cost[i] = u.loglik, (u.nis - env.nz) ** 2
        a_ml, a_gr = MaxLikelihoodPolicy().act(d), GreedyPolicy().act(d)
        np.testing.assert_array_equal(a_ml, np.argmax(brute_ll, axis=0))
        np.testing.assert_array_equal(a_gr, np.argmin(brute_cost, axis=0))
        np.testing.assert_allclose(d.candidates()["cost"], brute_cost, rtol=1e-9, atol=1e-12)
        assert len(set(a_gr.tolist())) > 1  # a real choice, not a constant
        d, c, done, info = env.step(a_gr)
        np.testing.assert_allclose(c, brute_cost[a_gr, np.arange(M)], rtol=1e-9, atol=1e-12)


# ----------------------------------------------------------------- bad input
@pytest.fixture
def small_env():
    model = af.models.ungm()
    env = FilterEnv(af.UKF(model), [0.0, 2.0, 10.0], cost=Cost("nis"), n_steps=4)
    env.reset(n_runs=5, rng=np.random.default_rng(0))
    return env


def test_action_index_out_of_range(small_env):
    with pytest.raises(ValueError, match=r"action index 3 out of range: the grid has 3 values"):
        small_env.step(np.array([0, 1, 2, 3, 0]))
    with pytest.raises(ValueError, match=r"action index -1 out of range"):
        small_env.step(np.array([0, -1, 2, 1, 0]))


def test_wrong_size_action_array(small_env):
    with pytest.raises(ValueError, match=r"one grid index per run, shape \(5,\); got shape \(4,\)"):
        small_env.step(np.zeros(4, dtype=int))


def test_grid_with_invalid_kappa():
    model = af.models.coordinated_turn()
    with pytest.raises(ValueError, match=r"n \+ kappa > 0 \(n = 4\)"):
        FilterEnv(af.UKF(model), [-4.0, 0.0, 2.0])


def test_grid_without_the_default():
    with pytest.raises(ValueError, match="must contain the filter's default kappa = 2"):
        FilterEnv(af.UKF(af.models.ungm()), [0.0, 5.0])


def test_unknown_experiment_name():
    with pytest.raises(KeyError, match="unknown experiment 'ungm-ekf'; known: ungm-ukf"):
        get_experiment("ungm-ekf")


def test_indefinite_p_pred_is_repaired_once_and_counted_even_when_features_are_read():
    """kappa = -3 on CTM (n = 4, centre weight -3) loses definiteness; with
    on_indefinite="clip" the features must not crash and each repair counts once."""
    model = af.models.coordinated_turn()

    class Curious(FixedPolicy):  # a policy that looks at the information state
        def act(self, d):
            assert np.isfinite(d.features).all()
            return super().act(d)

    def repairs(policy, clip=True):
        env = FilterEnv(af.UKF(model, on_indefinite="clip" if clip else "raise"), [-3.0, 0.0], cost=Cost("nis"), n_steps=60)
        run, _ = rollout(env, policy, n_runs=100, rng=np.random.default_rng(0))
        return run.n_repairs

    n = repairs(FixedPolicy(-3.0, "kappa"))
    assert n > 0
    assert repairs(Curious(-3.0, "kappa")) == n
    with pytest.raises(af.FilterError, match="not positive definite at step"):
        repairs(Curious(-3.0, "kappa"), clip=False)
