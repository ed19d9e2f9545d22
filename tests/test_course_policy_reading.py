"""adaptfilt.course.policy_reading: how chapter 8 reads a policy (its state, usage, switch-off curves),
against direct computations."""
import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest

from adaptfilt.course import policy_reading
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.features import observe
from course_stand_ins import ungm_seed_groups  # tests/course_stand_ins.py


@pytest.fixture(scope="module")
def ungm_results():
    return ungm_seed_groups()


class SigmoidPolicy:
    """pi(large kappa | s) = sigmoid(|innovation| - c): a policy with a known switch."""

    def __init__(self, c: float, name: str, grid=(1.0, 1000.0)):
        self.c, self.name, self.grid = c, name, np.asarray(grid)

    def probs(self, s):
        p = 1.0 / (1.0 + np.exp(-(np.abs(s[:, 4]) - self.c)))
        return np.stack([1.0 - p, p], axis=1)


def test_ungm_state_is_the_environments_information_state():
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=30)
    d = env.reset(n_runs=4, rng=np.random.default_rng(3))
    for _ in range(17):
        d, *_ = env.step(np.full(4, d.default_index))
    f = observe(d, exp.features)
    for i in range(4):
        mine = policy_reading.ungm_state(P_pred=f[i, 1], innov=f[i, 4], x_pred=f[i, 0], k=d.t + 1)
        assert np.allclose(mine, f[i], rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="P_pred"):
        policy_reading.ungm_state(0.0, 1.0)


def test_usage_lines_and_share_over_time(ungm_results):
    lines = policy_reading.usage_lines(ungm_results, ["fixed-kappa=200", "a-s0"], split=50).splitlines()
    assert "50 or less:   0%" in lines[0] and "200: 100%" in lines[0]
    assert "50 or less: 100%" in lines[1] and "1: 100%" in lines[1]
    fig = policy_reading.plot_share_over_time(ungm_results, ["a", "fixed-kappa=200"], 100)
    y_group, y_fixed = (line.get_ydata() for line in fig.axes[0].get_lines()[:2])
    assert np.allclose(y_group, 0.25) and np.allclose(y_fixed, 1.0)   # one of four seeds at 1000


def test_switch_off_curves_follow_the_policy():
    rng = np.random.default_rng(0)
    states = rng.normal(size=(4000, 7)) * np.array([1, 1, 1, 1, 3, 1, 1])
    pols = [SigmoidPolicy(1.0, "early"), SigmoidPolicy(3.0, "late")]
    fig = policy_reading.plot_switch_off(pols, states, {"innovation": 4}, at_least=100, n_bins=8)
    early, late = (line.get_ydata() for line in fig.axes[0].get_lines())
    assert np.all(np.diff(early) > 0) and np.all(early > late)
    x = np.abs(states[:, 4])
    top = x >= np.quantile(x, 7 / 8)
    assert np.isclose(early[-1], pols[0].probs(states)[top, 1].mean(), atol=1e-3)


def test_policy_probs_heat_map():
    pols = [SigmoidPolicy(1.0, "a"), SigmoidPolicy(8.0, "b")]
    s = policy_reading.ungm_state(1.0, 4.0)
    fig = policy_reading.plot_policy_probs(pols, s)
    ax = fig.axes[0]
    img = ax.get_images()[0].get_array()
    assert np.allclose(img, np.concatenate([p.probs(s) for p in pols]))
    assert list(ax.get_lines()[0].get_xdata()) == [1, 0]      # argmax: large kappa for "a", small for "b"
