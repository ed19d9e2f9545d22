"""Feature sets and scaling (adaptfilt.features) and the time-limit end of an episode."""
import numpy as np
import pytest

import adaptfilt as af
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.features import FeatureScaler, FeatureSet, feature_names, fit_scaler, visited_states
from adaptfilt.mdp import Cost, FilterEnv
from adaptfilt.policies import GreedyPolicy


def test_parse_and_names():
    assert FeatureSet.parse("paper") == FeatureSet() and FeatureSet.parse(None).name == "paper"
    fs = FeatureSet.parse("paper+cand+time")
    assert fs.name == "paper+time+cand"
    ungm, ctm = af.models.ungm(), af.models.coordinated_turn()
    assert FeatureSet().names(ungm) == feature_names(1, 1)
    assert FeatureSet.parse("paper+time").names(ungm)[-2:] == ["time[cos 0.05k]", "time[sin 0.05k]"]
    assert FeatureSet.parse("paper+time").size(ctm) == FeatureSet().size(ctm)  # CTM is time-invariant
    assert FeatureSet.parse("paper+circ").names(ctm)[4:8] == ["tr P_pred", "logdet P_pred", "sin z[0]", "cos z[0]"]
    assert FeatureSet.parse("paper+cand").size(ungm, grid=[0, 1, 2]) == 5 + 3
    with pytest.raises(ValueError, match="unknown feature token"):
        FeatureSet.parse("paper+tiem")
    with pytest.raises(ValueError, match="must start with 'paper'"):
        FeatureSet.parse("time")
    with pytest.raises(ValueError, match="need the parameter grid"):
        FeatureSet.parse("paper+cand").names(ungm)


def test_observed_blocks_are_what_they_say():
    exp = get_experiment("ctm-ukf")
    env = exp.make_env(n_steps=6)
    d = env.reset(n_runs=5, rng=np.random.default_rng(0))
    for _ in range(3):
        d, *_ = env.step(np.full(5, d.default_index))
    paper = d.features
    circ = d.observe("paper+circ")
    np.testing.assert_array_equal(circ[:, :6], paper[:, :6])
    np.testing.assert_allclose(circ[:, 6], np.sin(d.z[:, 0]))
    np.testing.assert_allclose(circ[:, 7], np.cos(d.z[:, 0]))
    np.testing.assert_array_equal(circ[:, 8], paper[:, 7])  # the (wrapped) innovation is unchanged
    np.testing.assert_allclose(paper[:, 4], np.trace(d.P_pred, axis1=1, axis2=2))
    np.testing.assert_allclose(paper[:, 5], np.linalg.slogdet(d.P_pred)[1])
    # candidate features: their argmin is the greedy choice
    cand = d.observe("paper+cand")[:, 8:]
    np.testing.assert_array_equal(np.argmin(cand, axis=1), GreedyPolicy().act(d))
    np.testing.assert_allclose(cand, np.log1p(d.candidates()["cost"]).T)
    # likelihood features: each candidate's log-likelihood less the largest; 0 at ML's choice
    from adaptfilt.policies import MaxLikelihoodPolicy

    fs = FeatureSet.parse("paper+circ+lik+cand")
    assert fs.name == "paper+circ+cand+lik" and fs.names(exp.make_model(), exp.grid)[-1] == f"loglik - max[{exp.grid[-1]:g}]"
    both = d.observe(fs)
    G = len(exp.grid)
    np.testing.assert_array_equal(both[:, -2 * G:-G], d.observe("paper+cand")[:, 8:])
    lik = both[:, -G:]
    ll = d.candidates()["loglik"].T
    np.testing.assert_allclose(lik, ll - ll.max(axis=1, keepdims=True), rtol=0, atol=1e-12)
    assert (lik <= 0).all() and np.array_equal(np.argmax(lik, axis=1), MaxLikelihoodPolicy().act(d))
    assert not np.array_equal(np.argmax(lik, axis=1), GreedyPolicy().act(d))  # ML is not greedy here


def test_time_features_follow_the_ungm_phase():
    env = get_experiment("ungm-ukf").make_env(n_steps=4)
    d = env.reset(n_runs=2, rng=np.random.default_rng(1))
    for t in range(3):
        f = d.observe("paper+time")
        np.testing.assert_allclose(f[:, -2:], [[np.cos(0.05 * (t + 1)), np.sin(0.05 * (t + 1))]] * 2)
        d, *_ = env.step(np.zeros(2, dtype=int))


def test_extra_spent_counts_features_and_candidates():
    env = get_experiment("ctm-sif-nis").make_env(n_steps=3)
    d = env.reset(n_runs=4, rng=np.random.default_rng(0))
    assert d.extra_spent == 0
    d.features
    assert d.extra_spent == 10  # the innovation feature: one SIF update at the default n_iter = 10
    d.observe("paper+circ")  # same innovation: not computed (nor counted) twice
    assert d.extra_spent == 10
    d.candidates()  # every n_iter from one pass of max(grid) draws (prefix averages)
    assert d.extra_spent == 10 + max(env.grid)
    _, _, _, info = env.step(np.zeros(4, dtype=int))
    # the chosen candidate (grid[0] = 1 iteration) is the update that happens, not extra
    np.testing.assert_array_equal(info["extra_spent"], 10 + max(env.grid) - env.grid[0])
    env.filt.candidate_prefixes = False  # the tiled path pays every candidate
    d = env.reset(n_runs=4, rng=np.random.default_rng(0))
    d.candidates()
    assert d.extra_spent == sum(env.grid)


def test_ukf_compute_is_counted_in_updates_not_kappa_values():
    """A UKF update costs one set of sigma points whatever kappa: greedy's candidates on UNGM are 13
    updates (not the 14,102 that a sum of the kappa values would say), the innovation feature one."""
    env = get_experiment("ungm-ukf").make_env(n_steps=3)
    d = env.reset(n_runs=4, rng=np.random.default_rng(0))
    d.features
    assert d.extra_spent == 1
    d.candidates()
    assert d.extra_spent == 1 + env.grid.size == 14
    _, _, _, info = env.step(np.full(4, env.grid.size - 1))  # kappa = 10^4 chosen: one of the 13, not extra
    np.testing.assert_array_equal(info["extra_spent"], 13)
    assert env.filt.rule.compute_unit == "update" and get_experiment("ctm-sif-nis").make_filter().rule.compute_unit == "iteration"


def test_repairs_made_only_to_decide_are_not_counted():
    """A policy that reads the one-iteration innovation feature and then chooses n_iter = 1 runs the same
    filter as the fixed n_iter = 1 (the feature's update is the chosen update's draws): it reports the
    same repairs, not twice as many."""
    from adaptfilt.mdp import rollout
    from adaptfilt.policies import FixedPolicy

    class LooksThenOne:
        name, grid = "looks", None

        def act(self, d):
            d.observe("paper+circ+innov@1")
            return np.zeros(d.n_runs, dtype=int)

    exp = get_experiment("ctm-sif-logmaxnis")
    env = exp.make_env(n_steps=60)
    traj = env.truth.simulate(300, 61, rng=np.random.default_rng(0))
    looks, _ = rollout(env, LooksThenOne(), traj=traj)
    fixed, _ = rollout(env, FixedPolicy(1.0, "n_iter", grid=env.grid), traj=traj)
    np.testing.assert_array_equal(looks.mean, fixed.mean)
    assert fixed.n_repairs > 0 and looks.n_repairs == fixed.n_repairs
    np.testing.assert_array_equal(looks.info["extra_spent"], 1.0)  # but it did pay for looking
    np.testing.assert_array_equal(looks.info["spent"], 2.0)


def test_final_decision_is_the_next_state_of_a_longer_episode():
    """At the horizon the env predicts one step on: exactly the state a longer episode sees."""
    exp = get_experiment("ctm-sif-logmaxnis")
    T = 5
    traj = exp.make_model().simulate(6, T + 1, rng=np.random.default_rng(3))
    short, long = exp.make_env(n_steps=T), exp.make_env(n_steps=T + 1)
    ds, dl = short.reset(traj=traj, stream=7), long.reset(traj=traj, stream=7)
    for t in range(T):
        a = np.arange(6) % len(exp.grid)
        ds, _, done_s, info = short.step(a)
        dl, _, _, _ = long.step(a)
    assert done_s and ds is None and info["truncated"] and not info["terminated"]
    final = info["final_decision"]
    assert final.t == T == dl.t
    np.testing.assert_array_equal(final.observe("paper+circ"), dl.observe("paper+circ"))
    # replayed trajectories of exactly T steps have no next measurement: no final state
    ev = exp.make_env(n_steps=T)
    d = ev.reset(traj=af.models.Trajectory(traj.x[:, :T], traj.z[:, :T]))
    for _ in range(T):
        d, _, _, info = ev.step(np.zeros(6, dtype=int))
    assert info["final_decision"] is None and info["truncated"]


def test_simulating_one_step_more_keeps_the_first_steps():
    model = af.models.ungm()
    a = model.simulate(3, 7, rng=np.random.default_rng(5))
    b = model.simulate(3, 8, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(a.x, b.x[:, :7])
    np.testing.assert_array_equal(a.z, b.z[:, :7])


def test_scaler_fits_and_squashes():
    rng = np.random.default_rng(0)
    f = np.c_[rng.normal(3, 2, 4000), rng.lognormal(0, 3, 4000)]
    s = FeatureScaler.fit(f, squash="asinh")
    assert abs(s.center[0] - 3) < 0.15 and abs(s.scale[0] - 2) < 0.15
    u = s(np.array([[s.center[0], 1e12]]))
    assert u[0, 0] == 0 and 20 < u[0, 1] < 40  # asinh: logarithmic, never clipped
    c = FeatureScaler(s.center, s.scale, clip=10.0)
    assert c(np.array([[3.0, 1e12]]))[0, 1] == 10.0  # clip saturates
    assert FeatureScaler.from_dict(s.to_dict()).squash == "asinh"
    with pytest.raises(ValueError, match="squash"):
        FeatureScaler(np.zeros(1), np.ones(1), squash="tanh")
    with pytest.raises(ValueError, match="scale"):
        FeatureScaler(np.zeros(1), np.zeros(1))


def test_new_scaler_keeps_the_tail_that_the_old_one_clipped():
    """UNGM's tr P_pred sits near Q = 1 in most steps and reaches 50-60 in 5-25 %: the default-fitted,
    clipped scaler maps that whole tail to +10 (the network cannot tell 1.3 from 60); mix + asinh keeps order."""
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=60)
    old = fit_scaler(env, visit="default", squash="clip", runs=64, seed=0)
    new = fit_scaler(env, visit="mix", squash="asinh", runs=64, seed=0)
    d = env.reset(n_runs=200, rng=np.random.default_rng(9))
    k200 = list(exp.grid).index(200.0)
    feats = []
    while d is not None:
        feats.append(d.features)
        d, *_ = env.step(np.full(200, k200))
    f = np.concatenate(feats)
    tail = f[:, 1] > 10
    assert 0.05 < tail.mean() < 0.5
    assert np.all(old(f[tail])[:, 1] == 10.0)
    u = new(f[tail])[:, 1]
    order = np.argsort(f[tail, 1])
    assert np.all(np.diff(u[order]) >= 0) and u.max() - u.min() > 0.5 and u.max() < 15


def test_visited_states_are_what_the_scaler_is_fitted_on():
    """``visited_states`` is one seeded episode (runs x T rows); ``fit_scaler`` is a robust fit on
    its finite rows, and reproduces the scaler stored with a trained policy (same seed, same features)."""
    from adaptfilt.experiments import artefacts

    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=30)
    f = visited_states(env, "paper+time", runs=13, seed=2)
    assert f.shape == (13 * 30, 7)
    assert np.array_equal(f, visited_states(env, "paper+time", runs=13, seed=2))
    fitted = fit_scaler(env, "paper+time", runs=13, seed=2)
    ref = FeatureScaler.fit(f[np.isfinite(f).all(axis=1)])
    assert np.array_equal(fitted.center, ref.center) and np.array_equal(fitted.scale, ref.scale)
    if artefacts.seeds("ungm-ukf", "adaptive"):
        pol = artefacts.stored_policy("ungm-ukf", "adaptive", 3)
        again = fit_scaler(exp.make_env(seed=3), "paper+time", seed=3)
        assert np.allclose(again.center, pol.scaler.center) and np.allclose(again.scale, pol.scaler.scale)
    with pytest.raises(ValueError, match="visit"):
        visited_states(env, runs=2, visit="greedy")


def test_fixed_in_both_steps_changes_the_predict_too():
    """predict_param: on UNGM (nonlinear dynamics) the predict uses it; the update-only run differs."""
    model = af.models.ungm()
    traj = model.simulate(20, 8, rng=np.random.default_rng(2))
    env = FilterEnv(af.UKF(model), [2.0, 10.0], cost=Cost("nis"), n_steps=8)
    from adaptfilt.mdp import rollout
    from adaptfilt.policies import FixedPolicy

    both = FixedPolicy(10.0, "kappa")
    both.predict_param = 10.0
    run_both, _ = rollout(env, both, traj=traj)
    ref = af.UKF(model, kappa=10.0).run(traj.z)  # kappa = 10 in predict and update
    np.testing.assert_allclose(run_both.mean, ref.mean, rtol=1e-12, atol=1e-12)
    run_upd, _ = rollout(env, FixedPolicy(10.0, "kappa"), traj=traj)
    assert not np.allclose(run_upd.mean, ref.mean)


def test_fixed_in_both_steps_baselines_only_where_the_predict_is_nonlinear():
    ungm, ctm = get_experiment("ungm-ukf").baselines(), get_experiment("ctm-ukf").baselines()
    assert "fixed-both-kappa=200" in [p.name for p in ungm]
    assert not any(p.name.startswith("fixed-both-") for p in ctm)  # CTM's predict is the exact linear one
    exp = get_experiment("ungm-ukf")
    from adaptfilt.evaluation import evaluate
    from adaptfilt.policies import FixedPolicy

    env = exp.make_env(n_steps=10)
    pols = [FixedPolicy(200.0, "kappa", both_steps=True), FixedPolicy(200.0, "kappa")]
    res = evaluate(env, pols, n_runs=50, progress=False)
    traj = exp.make_model().simulate(50, 10, rng=np.random.default_rng([0xE7A1, 0]))
    ref = af.UKF(exp.make_model(), kappa=200.0).run(traj.z)
    assert res["fixed-both-kappa=200"].rmse == pytest.approx(af.metrics.rmse(traj.x, ref.mean).mean(), rel=1e-12)
    assert res["fixed-both-kappa=200"].rmse != res["fixed-kappa=200"].rmse
    assert res.best_fixed("rmse", both_steps=True) == "fixed-both-kappa=200"


def test_cheap_innovation_feature():
    fs = FeatureSet.parse("paper+circ+innov@1")
    assert fs.innovation == 1.0 and fs.name == "paper+circ+innov@1"
    env = get_experiment("ctm-sif-nis").make_env(n_steps=2)
    d = env.reset(n_runs=3, rng=np.random.default_rng(0))
    f = d.observe(fs)
    assert d.extra_spent == 1  # one SIF iteration, not the default's ten
    assert fs.names(env.model)[-1] == "innov@1[0]"
    u = env.filt.update(d.x_pred, d.P_pred, d.z, 0, param=1.0)  # the same draws (stream None, step 0)
    np.testing.assert_allclose(f[:, -1], u.innovation[:, 0])
    with pytest.raises(ValueError, match="innov@"):
        FeatureSet.parse("paper+innov@x")


def test_repaired_runs_are_reported_per_step():
    """SIF with one iteration repairs some covariances on the CTM: the env reports which runs, per step,
    consistently with the filter's repair counter; a UKF with kappa = 0 repairs nothing."""
    exp = get_experiment("ctm-sif-logmaxnis")
    env = exp.make_env(n_steps=60)
    d = env.reset(n_runs=300, rng=np.random.default_rng(0))
    before, flagged = env.filt.n_repairs, 0
    while d is not None:
        d, _, _, info = env.step(np.zeros(300, dtype=int))  # n_iter = 1
        assert info["repaired"].shape == (300,) and info["repaired"].dtype == bool
        flagged += int(info["repaired"].sum())
    repairs = env.filt.n_repairs - before
    assert 0 < flagged <= repairs
    ukf = get_experiment("ctm-ukf").make_env(n_steps=20)
    d = ukf.reset(n_runs=50, rng=np.random.default_rng(0))
    while d is not None:
        d, _, _, info = ukf.step(np.full(50, d.default_index))
        assert not info["repaired"].any()
