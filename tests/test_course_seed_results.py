"""adaptfilt.course.seed_results: the seed-level lines, verdicts, claim tables and figures of chapters
12-13, against the library's seed statistics."""
import matplotlib

matplotlib.use("Agg")

import pytest

from adaptfilt.course import seed_results
from adaptfilt import seed_stats as sd
from adaptfilt import verdicts
from course_stand_ins import ungm_seed_groups  # tests/course_stand_ins.py


@pytest.fixture(scope="module")
def ungm_results():
    return ungm_seed_groups()


def test_seed_lines_and_verdicts(ungm_results):
    text = seed_results.seed_lines(ungm_results, ["a", "b"], ["default"], metrics=("rmse",))
    agg = sd.aggregate(ungm_results, sd.seed_groups(ungm_results.names)["a"], "rmse")
    assert f"rmse {agg.iqm:.3g} [{agg.iqm_ci[0]:.3g}, {agg.iqm_ci[1]:.3g}]" in text.splitlines()[1]
    assert text.splitlines()[1].startswith("a (4 seeds)")
    v = seed_results.seed_verdicts(ungm_results, "a", "fixed-kappa=200", "rmse")
    assert sum(v["counts"].values()) == 4
    for n, (d, lo, hi, verdict) in v["per_seed"].items():
        assert (d, lo, hi) == ungm_results.paired_difference(n, "fixed-kappa=200", "rmse")
        assert verdict == verdicts.verdict("lower", (lo, hi))
    m = verdicts.margin("adaptive vs best fixed", "rmse", ungm_results["fixed-kappa=200"].rmse)
    eq = seed_results.seed_verdicts(ungm_results, "a", "fixed-kappa=200", "rmse", "equal", m)["per_seed"]
    assert all(v[3] == verdicts.verdict("equal", v[1:3], m) for v in eq.values())
    with pytest.raises(ValueError, match="'equal' claim needs a declared margin"):
        seed_results.seed_verdicts(ungm_results, "a", "fixed-kappa=200", "rmse", "equal")


def test_claims_table_keeps_rows_with_per_seed_counts():
    claims = {"C2": [
        {"experiment": "e", "claim": "adaptive lower than ml", "metric": "rmse", "diff": 0.5, "ci": [0.1, 0.9],
         "verdict": "contradicted", "seeds_holding": 0, "n_seeds": 8},
        {"experiment": "e", "claim": "adaptive lower than myopic", "metric": "rmse", "diff": 0.1, "ci": [-0.1, 0.3],
         "verdict": "not confirmed", "seeds_holding": None, "n_seeds": 8},
        {"experiment": "other", "claim": "adaptive lower than ml", "metric": "rmse", "diff": 0.5, "ci": [0.1, 0.9],
         "verdict": "contradicted", "seeds_holding": 3, "n_seeds": 8}]}
    rows = seed_results.claims_table(claims, "e").strip().splitlines()[2:]
    assert len(rows) == 1 and "0/8" in rows[0] and "contradicted" in rows[0]
    assert len(seed_results.claims_table(claims, "e", only_held=False).strip().splitlines()) == 4


def test_claims_table_shows_the_margin_of_an_equal_claim():
    claims = {"C2": [{"experiment": "e", "claim": "adaptive equal than fixed", "metric": "rmse", "diff": -0.2,
                      "ci": [-0.24, -0.15], "verdict": "not confirmed", "seeds_holding": 2, "n_seeds": 8,
                      "margin": 0.154, "declared": "adaptive vs best fixed"}]}
    row = seed_results.claims_table(claims, "e").strip().splitlines()[2]
    assert "adaptive equal to fixed" in row and "not confirmed (margin 0.154)" in row and "2/8" in row


def test_seed_spread_and_differences_figures(ungm_results):
    fig = seed_results.plot_seed_spread(ungm_results, ["a", "b"], "rmse")
    labels = [t.get_text() for t in fig.axes[0].get_yticklabels()]
    assert labels[:4] == ["a-s0", "a-s1", "a-s2", "a-s3"] and "a: IQM of 4" in labels and "b: mean of 3" in labels
    fig = seed_results.plot_differences({"c1": {"x": (1.0, 0.5, 1.5)}, "c2": {"x": (-1.0, -2.0, 0.0), "y": (0.0, -1, 1)}})
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["c1", "c2"]


def test_timed_returns_the_result():
    out, cpu = seed_results.timed(sum, [1, 2, 3])
    assert out == 6 and cpu >= 0.0
