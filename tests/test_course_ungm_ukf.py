"""adaptfilt.course.ungm_ukf: chapter 9's analyses (the NIS gate, the fixed conventions, the floor per
step), against the UKF and the point-mass filter."""
from course_stand_ins import close_figures, ungm_res  # noqa: F401 (fixtures: tests/course_stand_ins.py)

import copy

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt.course import ctm_ukf, ungm_ukf
from adaptfilt.experiments import claims
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.seed_stats import aggregate
from adaptfilt.policies import FixedPolicy, GreedyPolicy, MaxLikelihoodPolicy

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


# ---------------------------------------------------------------- UNGM: the gate


def test_ungm_nis_is_the_ukfs_nis_for_every_kappa():
    env = get_experiment("ungm-ukf").make_env(n_steps=6)
    d = env.reset(n_runs=7, rng=np.random.default_rng(4))
    for _ in range(5):  # a few steps in, away from the prior
        d, *_ = env.step(np.full(d.n_runs, env.default_index))
    want = d.candidates()["nis"]  # (G, M) from the filter's own unscented update
    got = ungm_ukf.ungm_nis(env.grid[:, None], d.x_pred[:, 0], d.P_pred[:, 0, 0], d.z[:, 0],
                            R=float(env.filt.model.R[0, 0]))
    np.testing.assert_allclose(got, want, rtol=1e-9)
    with pytest.raises(ValueError, match="P_pred must be positive"):
        ungm_ukf.ungm_nis(0.0, 1.0, 0.0, 1.0)


def test_greedy_updates_fully_exactly_when_the_full_update_is_not_surprised():
    # NIS falls with kappa, so with NIS(kappa_min) < 1 every kappa gives NIS < 1 and the NIS
    # cost (NIS - 1)^2 is smallest at kappa_min: greedy must choose it there, and only there.
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=60)
    traj = exp.make_model().simulate(n_runs=40, n_steps=61, rng=np.random.default_rng(5))
    g = ungm_ukf.gate_anatomy(env, GreedyPolicy(grid=env.grid), traj)
    s = g.summary()
    assert s["open_kappa"] == 0.0 and s["open_share"] == 1.0
    assert (g.kappa[g.nis0 >= 1] > 0).mean() > 0.95
    f = ungm_ukf.gate_anatomy(env, FixedPolicy(200, "kappa", grid=env.grid), traj)
    assert f.summary()["open_kappa"] == 200 and (f.kappa == 200).all()
    assert "greedy" in ungm_ukf.gate_table([g, f]) and ungm_ukf.plot_gate([g, f]).axes
    with pytest.raises(ValueError, match="UNGM UKF"):
        ungm_ukf.gate_anatomy(get_experiment("ctm-ukf").make_env(), GreedyPolicy(), traj)


# ---------------------------------------------------------------- figures


def test_greedy_and_ml_on_ungm_are_the_closed_form_argmins_of_their_losses():
    # In the states each rule visits, the NIS of every grid value in closed form (nis_at) must give
    # back its choices: greedy's argmin of (NIS - 1)^2, ML's argmax of the Gaussian likelihood
    # -(log Pzz + NIS)/2, i.e. argmin of NIS - log NIS since nu does not depend on kappa on UNGM.
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=60)
    traj = exp.make_model().simulate(n_runs=40, n_steps=61, rng=np.random.default_rng(6))
    grid = np.asarray(env.grid)
    for pol, loss in ((GreedyPolicy(grid=env.grid), lambda r: (r - 1.0) ** 2),
                      (MaxLikelihoodPolicy(grid=env.grid), lambda r: r - np.log(r))):
        a = ungm_ukf.gate_anatomy(env, pol, traj)
        nis = a.nis_at(grid)
        assert nis.shape == (grid.size,) + a.kappa.shape
        np.testing.assert_allclose(nis[0], a.nis0, rtol=1e-12)
        np.testing.assert_array_equal(grid[np.argmin(loss(nis), axis=0)], a.kappa)
    with pytest.raises(ValueError, match="no predicted moments"):
        ungm_ukf.GateAnatomy("bare", a.kappa, a.nis0, a.wrong_sign, a.sq_err).nis_at(0.0)


def test_fixed_conventions_and_cost_time_figures(ungm_res):
    fig = ungm_ukf.plot_fixed_conventions(ungm_res, refs=("greedy", "adaptive"), unit="m")
    ax = fig.axes[0]
    assert ax.get_ylabel() == "time-averaged RMSE (m)" and len(ax.containers) == 2  # two error-bar lines
    assert {t.get_text() for t in ax.get_legend().get_texts()} >= {"greedy", "adaptive (IQM over seeds)"}
    fig = ctm_ukf.plot_cost_time(ungm_res, ["greedy", "adaptive"], window=50)
    assert len(fig.axes[0].lines) == 2 and fig.axes[0].lines[0].get_xdata().size == 10
    none = copy.copy(ungm_res)
    none.policies = {n: ungm_res[n] for n in ("greedy", "ml")}
    with pytest.raises(ValueError, match="no fixed-kappa"):
        ungm_ukf.plot_fixed_conventions(none, refs=())


def test_fixed_conventions_zoom_separates_the_reference_lines(ungm_res):
    refs = ("ml", "greedy", "adaptive", "myopic")
    fig = ungm_ukf.plot_fixed_conventions(ungm_res, refs=refs, zoom=(100, 10000))
    full, zoom = fig.axes
    assert zoom.get_xlim()[0] == pytest.approx(100 / 1.3) and zoom.get_yscale() == "linear"
    lo, hi = zoom.get_ylim()
    iqm = {r: aggregate(ungm_res, claims.members(ungm_res, r), "rmse").iqm for r in refs}
    assert lo < min(iqm.values()) and max(iqm.values()) < hi < 3.5  # the bands in view, not the whole grid
    styles = {ln.get_label(): ln.get_linestyle() for ln in zoom.lines if ln.get_label().split(":")[0] in
              ("ml", "greedy", "adaptive (IQM over seeds)", "myopic (IQM over seeds)")}
    assert len(styles) == 4 and len(set(styles.values())) == 4  # coinciding lines stay visible
    assert {t.get_text() for t in zoom.texts} == {"ml", "greedy", "adaptive", "myopic"}  # direct labels
    assert any(t.get_text().startswith("greedy: 2.82 [") for t in fig.legends[0].get_texts())
    with pytest.raises(ValueError, match="no ax"):
        ungm_ukf.plot_fixed_conventions(ungm_res, refs=refs, zoom=(100, 10000), ax=full)


def test_rmse_steps_tell_the_fixed_conventions_apart_and_draw_a_floor_per_step(ungm_res):
    from adaptfilt.seed_stats import collapse_seeds

    col = collapse_seeds(ungm_res)
    floor = np.linspace(0.5, 1.0, 500)
    fig = ungm_ukf.plot_rmse_steps(col, ["fixed-kappa=200", "fixed-both-kappa=500", "greedy", "adaptive"], floor_t=floor)
    lines = {ln.get_label(): ln for ln in fig.axes[0].lines}
    assert lines["κ = 200"].get_color() != lines["both-κ = 500"].get_color()
    assert lines["greedy"].get_color() == af.plots.policy_style(ungm_res, "greedy")["color"]
    np.testing.assert_allclose(lines["Bayes floor"].get_ydata(), floor)
    np.testing.assert_allclose(lines["adaptive"].get_ydata(),
                               np.mean([ungm_res[f"adaptive-s{i}"].rmse_t for i in range(8)], axis=0))


def test_ungm_floor_steps_is_the_point_mass_filter_on_the_evaluation_runs():
    from adaptfilt.exact import PointMassFilter
    from adaptfilt.runs import TRAJ_SEED_KEY

    f = ungm_ukf.ungm_floor_steps(n_runs=3, n_steps=20, eval_runs=5, chunk=2)
    env = get_experiment("ungm-ukf").make_env(n_steps=20)
    traj = env.model.simulate(5, 20, rng=np.random.default_rng([TRAJ_SEED_KEY, 0]))
    pmf = PointMassFilter(env.model, grid=np.linspace(-45, 45, 901)).run(traj.z[:3])
    np.testing.assert_allclose(f, np.sqrt(((traj.x[:3] - pmf.mean) ** 2).sum(-1).mean(axis=0)))
