"""adaptfilt.course.ctm_ukf: chapter 10's analyses (reach, position and velocity, the line of sight),
against direct computations and the chi-square law of a consistent filter."""
from course_stand_ins import close_figures  # noqa: F401 (fixtures: tests/course_stand_ins.py)

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

import adaptfilt as af
from adaptfilt.course import ctm_ukf
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.mdp import Cost, FilterEnv
from adaptfilt.policies import FixedPolicy, GreedyPolicy

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


def test_position_rmse_share_is_the_ratio_of_the_position_rmses_with_a_paired_interval():
    model = af.models.coordinated_turn(n_steps=20)
    traj = model.simulate(n_runs=60, rng=np.random.default_rng(2))
    ukf, ukf50 = af.UKF(model).run(traj.z), af.UKF(model).run(traj.z, params=50.0)
    rmse = lambda r: float(np.sqrt(((traj.x[..., [0, 2]] - r.mean[..., [0, 2]]) ** 2).sum(-1).mean(0)).mean())
    share, lo, hi = ctm_ukf.position_rmse_share(traj.x, ukf50, ukf, n_boot=500, seed=3)
    assert share == pytest.approx(1 - rmse(ukf) / rmse(ukf50), rel=1e-12)
    assert lo < share < hi and hi - lo > 0.01  # 60 runs: a real interval around the point estimate
    assert ctm_ukf.position_rmse_share(traj.x, ukf50, ukf, n_boot=500, seed=3) == (share, lo, hi)
    # the share of the better filter's error that the worse one lacks is negative
    assert ctm_ukf.position_rmse_share(traj.x, ukf, ukf50, n_boot=500)[0] < 0


def test_reach_on_a_linear_model_is_nothing_and_greedy_on_ungm_pushes_to_the_ends():
    # a linear measurement: every kappa gives the Kalman Pzz, so the grid reaches nothing
    lin = af.models.linear_gaussian(F=[[0.9]], H=[[1.0]], Q=[[1.0]], R=[[0.5]], m0=[0.0], P0=[[2.0]], n_steps=20)
    grid = (0.0, 2.0, 5.0)  # the default kappa (2 for nx = 1) must be in the grid
    env = FilterEnv(af.UKF(lin), grid, Cost("nis"))
    traj = lin.simulate(n_runs=30, n_steps=21, rng=np.random.default_rng(1))
    a = ctm_ukf.reach_anatomy(env, FixedPolicy(5.0, "kappa", grid=grid), traj)
    np.testing.assert_allclose(a.pzz_hi / a.pzz_lo, 1.0, rtol=1e-9)
    assert a.choice.shape == (30, 20) and (a.choice == 5.0).all() and a.inside.mean() < 0.01
    # UNGM: Pzz grows with kappa, so greedy takes the smallest kappa whenever the default NIS is below 1
    # at kappa_min (chapter 9's gate) and the largest when even kappa_max leaves the NIS above 1
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=40)
    traj = exp.make_model().simulate(n_runs=30, n_steps=41, rng=np.random.default_rng(2))
    g = ctm_ukf.reach_anatomy(env, GreedyPolicy(grid=env.grid), traj)
    assert (g.pzz_hi > g.pzz_lo).all()
    assert (g.choice[g.nu2 <= g.pzz_lo] == env.grid.min()).all() and (g.choice[g.nu2 >= g.pzz_hi] == env.grid.max()).all()
    assert "reachable at" in ctm_ukf.reach_table([g])
    with pytest.raises(ValueError, match="scalar measurement"):
        two = af.models.linear_gaussian(F=[[1.0]], H=[[1.0], [2.0]], Q=[[1.0]], R=np.eye(2), m0=[0.0], P0=[[1.0]])
        ctm_ukf.reach_anatomy(FilterEnv(af.UKF(two), grid, Cost("nis"), n_steps=3), FixedPolicy(5.0, "kappa", grid=grid),
                               two.simulate(2, 4, rng=0))


def test_position_and_velocity_are_split_and_seed_groups_summarised():
    exp = get_experiment("ctm-ukf")
    env = exp.make_env(n_steps=15)
    traj = exp.make_model().simulate(n_runs=40, n_steps=16, rng=np.random.default_rng(1))
    pols = [FixedPolicy(0, "kappa", grid=env.grid), FixedPolicy(50, "kappa", grid=env.grid)]
    pols[1].name = "group-s0"
    pv = ctm_ukf.position_velocity_rmse(env, pols, traj)
    run = af.UKF(exp.make_model()).run(traj.z[:, :15])
    e = traj.x[:, :15] - run.mean
    r = lambda i: np.sqrt((e[..., i] ** 2).sum(-1).mean(axis=0)).mean()
    assert pv["fixed-kappa=0"]["position"] == pytest.approx(r([0, 2]))
    assert pv["fixed-kappa=0"]["velocity"] == pytest.approx(r([1, 3]))
    p = pv["fixed-kappa=0"]  # Minkowski: sqrt(pos^2 + vel^2) <= full <= pos + vel
    assert np.hypot(p["position"], p["velocity"]) - 1e-9 <= p["full"] <= p["position"] + p["velocity"]
    md = ctm_ukf.position_velocity_md(pv, ["fixed-kappa=0", "group"])
    assert "| group |" in md and "position (m)" in md
    with pytest.raises(KeyError, match="no policy"):
        ctm_ukf.position_velocity_md(pv, ["nothing"])


class _Stored(dict):
    """The two things position_velocity_md reads of a Results: ``config`` and ``[name].rmse``."""
    config = {"n_runs": 10000}

    def __getitem__(self, n):
        return SimpleNamespace(rmse=dict.__getitem__(self, n))


def test_position_velocity_table_sets_the_stored_rmse_beside():
    pv = {"a": {"full": 3.0, "position": 2.0, "velocity": 1.0},
          **{f"g-s{i}": {"full": 4.0 + i, "position": 3.0, "velocity": 1.0} for i in range(3)}}
    stored = _Stored({"a": 9.0, "g-s0": 1.0, "g-s1": 2.0, "g-s2": 7.0})
    md = ctm_ukf.position_velocity_md(pv, ["a", "g"], stored=stored)
    assert "RMSE full state, stored (M = 10000)" in md
    assert "| a | 3.0 | 2.0 | 1.0 | 9.0 |" in md and md.rstrip().endswith("| 2.0 (1.0-7.0) |")
    assert "stored" not in ctm_ukf.position_velocity_md(pv, ["a"])


# ---------------------------------------------------------------- CTM: line of sight


def test_line_of_sight_of_a_consistent_filter_is_chi_square():
    # errors drawn from the claimed covariance: each normalised direction is chi2(1), the NEES chi2(4)
    rng = np.random.default_rng(7)
    M, T = 4000, 3
    x = rng.normal(0.0, 50.0, size=(M, T, 4)) + np.array([80.0, 0.0, 40.0, 0.0])
    A = rng.normal(size=(M, T, 4, 4))
    cov = A @ np.swapaxes(A, -1, -2) + 0.5 * np.eye(4)
    mean = x - (np.linalg.cholesky(cov) @ rng.standard_normal((M, T, 4, 1)))[..., 0]
    run = SimpleNamespace(mean=mean, cov=cov)
    los = ctm_ukf.line_of_sight(x, run)
    p = x[..., [0, 2]]
    u = p / np.linalg.norm(p, axis=-1, keepdims=True)
    np.testing.assert_allclose(los.err_range, ((p - mean[..., [0, 2]]) * u).sum(-1))
    np.testing.assert_allclose(los.sd_range ** 2, np.einsum("...i,...ij,...j->...", u, cov[..., [0, 2], :][..., [0, 2]], u))
    for e, sd in ((los.err_range, los.sd_range), (los.err_cross, los.sd_cross)):
        assert np.median((e / sd) ** 2) == pytest.approx(stats.chi2.median(1), abs=0.04)
    head, cols, line = ctm_ukf.line_of_sight_table(x, {"consistent": run}).splitlines()
    assert "0.455 (chi2_1)" in head and "3.36 (chi2_4)" in head and "pos RMSE" in cols
    assert float(line.rsplit("|", 1)[1]) == pytest.approx(stats.chi2.median(4), abs=0.15)
    e = x - mean
    pos_rmse = np.sqrt((e[..., [0, 2]] ** 2).sum(-1).mean(axis=0)).mean()
    assert float(line.split("|")[0].split()[2]) == pytest.approx(pos_rmse, abs=0.06)
    assert ctm_ukf.plot_line_of_sight(x, {"consistent": run}).axes[0].get_ylabel() == "position error (m)"
