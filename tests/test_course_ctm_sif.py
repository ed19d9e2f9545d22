"""adaptfilt.course.ctm_sif: chapter 11's analyses (the innovation a policy responds to, the SIF's
integration noise), against direct computations."""
from course_stand_ins import close_figures  # noqa: F401 (fixtures: tests/course_stand_ins.py)

import numpy as np
import pytest
from scipy import stats

import adaptfilt as af
from adaptfilt.course import ctm_sif
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.policies import FixedPolicy

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


class _Loud:
    """A SIF policy that chooses 5 iterations where the one-iteration innovation exceeds ``t`` rad, else 1."""
    feature_set = "paper+circ+innov@1"

    def __init__(self, t, name="loud"):
        self.t, self.name = t, name

    def act(self, d):
        one, five = (int(np.flatnonzero(d.grid == v)[0]) for v in (1, 5))  # a policy acts with grid indices
        return np.where(np.abs(d.observe(self.feature_set)[:, -1]) > self.t, five, one)


def test_innovation_response_follows_the_innovation_a_policy_sees():
    env = lambda: get_experiment("ctm-sif-nis").make_env(0, n_steps=14)
    fixed = ctm_sif.innovation_response(env(), FixedPolicy(3, "n_iter", grid=env().grid), n_runs=20, early=4)
    assert fixed["early"] == fixed["late"] == 3 and np.all(fixed["quartiles"] == 3)
    r = ctm_sif.innovation_response(env(), _Loud(0.1), n_runs=20, early=4)
    q, e = r["quartiles"], r["edges"]
    assert np.all(np.diff(q) >= 0) and q[0] < q[3] and np.all(np.diff(e) > 0)  # a step in |innov| rises by quartile
    assert 1 <= r["late"] <= 5 and r["early_steps"] == 4
    # the loop: every seed of every group on the same runs; the table summarises them over the seeds
    load = lambda e, g, seed: _Loud(0.05 * (seed + 1), name=f"{g}-s{seed}")
    rs = ctm_sif.innovation_responses(["ctm-sif-nis"], ("adaptive",), seeds=[0, 1, 2], n_runs=20, load=load, n_steps=14)
    assert list(rs) == [("ctm-sif-nis", "adaptive")] and len(rs["ctm-sif-nis", "adaptive"]) == 3
    assert rs["ctm-sif-nis", "adaptive"][1]["quartiles"] == pytest.approx(r["quartiles"])  # seed 1 is _Loud(0.1)
    md = ctm_sif.innovation_response_md(rs)
    q4 = np.array([x["quartiles"][3] for x in rs["ctm-sif-nis", "adaptive"]])
    iqm3 = stats.trim_mean(q4, 0.25)  # of three seeds: the middle one
    assert "N_it, steps 1-10" in md and f"| {iqm3:.1f} ({q4.min():.1f}-{q4.max():.1f}) |" in md
    d = q4 - np.array([x["quartiles"][0] for x in rs["ctm-sif-nis", "adaptive"]])
    assert md.count("\n") == 3 and f"{stats.trim_mean(d, 0.25):+.2f} ({d.min():+.2f} to {d.max():+.2f}); {np.sum(d > 0)} / 3 > 0 |" in md


# ---------------------------------------------------------------- SIF integration noise


def test_sif_spread_vanishes_for_a_deterministic_rule_and_shrinks_with_iterations():
    model = af.models.coordinated_turn(n_steps=4)
    traj = model.simulate(n_runs=1, rng=np.random.default_rng(1))
    ukf = ctm_sif.sif_spread(lambda n: af.UKF(model), [1, 5], traj, n_filters=50)
    assert np.all(ukf["spread"] < 1e-9) and np.all(ukf["claimed"] > 0)
    sif = ctm_sif.sif_spread(lambda n: af.SIF(model, n_iter=n, seed=0, on_indefinite="clip"), [2, 32], traj,
                              n_filters=400)
    ratio = sif["spread"][0] / sif["spread"][1]  # 1/sqrt(N): about 4 for 16 times the iterations
    assert 2.5 < ratio < 6.5
