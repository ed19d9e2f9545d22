"""Stand-ins the course's tests share: evaluations small enough to make on the spot."""


def ungm_seed_groups():
    """A tiny UNGM evaluation with two seed groups of fixed policies (``a-s0..3``, ``b-s0..2``) standing in for
    learned ones, beside the default, a fixed kappa of 200 and greedy."""
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.policies import FixedPolicy, GreedyPolicy, default_policy

    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=20)
    g = exp.grid
    pols = [default_policy(2.0, grid=g), FixedPolicy(200, "kappa", grid=g), GreedyPolicy(grid=g)]
    pols += [FixedPolicy(v, "kappa", grid=g, name=f"a-s{i}") for i, v in enumerate((1.0, 5.0, 20.0, 1000.0))]
    pols += [FixedPolicy(v, "kappa", grid=g, name=f"b-s{i}") for i, v in enumerate((2.0, 10.0, 500.0))]
    return evaluate(env, pols, n_runs=60, seed=1, progress=False, n_boot=200)


# ---------------------------------------------------------------- fixtures the course's test files import
import matplotlib  # noqa: E402

matplotlib.use("Agg")

import pytest  # noqa: E402


@pytest.fixture(autouse=True)
def close_figures():
    """Every figure a test drew is closed after it (import this fixture into a test file to use it)."""
    import matplotlib.pyplot as plt

    yield
    plt.close("all")


@pytest.fixture(scope="module")
def ungm_res():
    """The stored UNGM evaluation (``data/results/ungm-ukf``)."""
    from adaptfilt.experiments import artefacts

    return artefacts.load_results("ungm-ukf")


@pytest.fixture(scope="module")
def sif_results():
    """The stored evaluations of the three SIF experiments."""
    from adaptfilt.experiment_registry import SIF_EXPERIMENTS
    from adaptfilt.experiments import artefacts

    return {e: artefacts.load_results(e) for e in SIF_EXPERIMENTS}
