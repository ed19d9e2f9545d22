"""The evaluation's paired runs (adaptfilt.runs): the trajectories and counts of an evaluation's seed, derived once."""
import numpy as np
import pytest

import adaptfilt as af
from adaptfilt import metrics
from adaptfilt.runs import TRAJ_SEED_KEY, EvalRuns, bootstrap_counts, trajectory_rng


def test_the_runs_are_the_seeds_draws_and_drawn_once():
    model = af.models.ungm()
    runs = EvalRuns(model, 40, 5, 9, n_boot=25)
    want = model.simulate(40, 9, rng=np.random.default_rng([TRAJ_SEED_KEY, 5]))
    assert runs.traj.x.tobytes() == want.x.tobytes() and runs.traj is runs.traj
    counts = metrics.bootstrap_counts(40, 25, rng=np.random.default_rng([TRAJ_SEED_KEY, 5, 1]))
    assert runs.counts.tobytes() == counts.tobytes()
    assert runs.first(7).z.tobytes() == want.z[:7].tobytes()
    assert trajectory_rng(5).standard_normal() == np.random.default_rng([TRAJ_SEED_KEY, 5]).standard_normal()
    # a reference's own resamples: another stream, not the evaluation's
    other = bootstrap_counts(40, 25, 5, stream=2)
    assert other.tobytes() == metrics.bootstrap_counts(40, 25, rng=np.random.default_rng([TRAJ_SEED_KEY, 5, 2])).tobytes()
    assert repr(runs) == "EvalRuns('ungm', n_runs=40, seed=5, n_steps=9)" and runs.trajectories == "default_rng([59297, seed])"


def test_given_and_streamed_runs(tmp_path):
    model = af.models.coordinated_turn()
    traj = model.simulate(6, 5, rng=1)
    given = EvalRuns(model, traj=traj, n_steps=5, n_boot=4)
    assert given.n_runs == 6 and given.traj is traj and given.trajectories == "given"
    streamed = EvalRuns(model, 30, 2, 5, n_boot=4, chunk_size=8, folder=tmp_path)
    assert streamed.streamed and streamed.store.chunks()[-1] == (24, 30)
    assert streamed.first(3).x.tobytes() == EvalRuns(model, 30, 2, 5).traj.x[:3].tobytes()
    with pytest.raises(ValueError, match="streamed from disk"):
        streamed.traj
    with pytest.raises(ValueError, match="give a folder"):
        EvalRuns(model, 30, 2, 5, chunk_size=8)
    with pytest.raises(ValueError, match="n_runs must be at least 2"):
        EvalRuns(model, 1, 0, 5)
    with pytest.raises(ValueError, match=r"first\(n\) takes 1 to 6 runs"):
        given.first(7)
    lin = af.models.linear_gaussian(F=[[1.0]], H=[[1.0]], Q=[[1.0]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
    with pytest.raises(ValueError, match="give n_steps"):
        EvalRuns(lin, 5, 0)
    assert EvalRuns(model, 5, 0).n_steps == 150
