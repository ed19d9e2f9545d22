"""Beyond the paper: the studies' pipeline at toy scale, out-of-distribution truths and retuning."""
import json

import numpy as np
import pytest

from adaptfilt.experiments.ood import CONDITIONS, Condition, evaluate_condition, gain_table, retune, truth_model


def test_truth_model_scales_the_noise_only():
    c = Condition(4.0, 0.25)
    nominal = truth_model("ctm-ukf", Condition(1.0, 1.0))
    m = truth_model("ctm-ukf", c)
    np.testing.assert_allclose(m.Q, 4.0 * nominal.Q)
    np.testing.assert_allclose(m.R, 0.25 * nominal.R)
    np.testing.assert_array_equal(m.P0, nominal.P0)
    assert m.circular_z == (0,) and len(CONDITIONS) == 9
    # simulated noise has the scaled variance
    t1 = truth_model("ungm-ukf", Condition(1.0, 4.0)).simulate(4000, 3, rng=np.random.default_rng(0))
    x, z = t1.x[:, 0, 0], t1.z[:, 0, 0]
    assert abs(np.var(z - x**2 / 20) / 0.4 - 1) < 0.1


def test_retune_moves_the_policy_and_is_reproducible():
    from adaptfilt.trainers import train_policy

    pol = train_policy("ungm-ukf", "a2c", 0.5, episodes=20, seed=0, progress=False, n_steps=20)
    pol.name = "adaptive-s0"
    c = Condition(4.0, 0.25)
    a = retune(pol, "ungm-ukf", c, episodes=3, seed=1, n_steps=20)
    b = retune(pol, "ungm-ukf", c, episodes=3, seed=1, n_steps=20)
    wa, wb, w0 = (p.actor.net[0].weight.detach().numpy() for p in (a, b, pol))
    np.testing.assert_array_equal(wa, wb)
    assert not np.array_equal(wa, w0)
    np.testing.assert_array_equal(a.scaler.center, pol.scaler.center)  # keeps the features' scaling
    res = evaluate_condition("ungm-ukf", c, [pol, a], n_runs=40, n_steps=20)
    assert {"default", "greedy", "adaptive-s0", "adaptive-s0-retuned"} <= set(res.names)
    table = gain_table({c.key: res}, {"learned": ["adaptive-s0"]}, "objective")
    row = table[c.key]
    assert row["learned"]["gain"] == pytest.approx(res["default"].objective - res["adaptive-s0"].objective)


def test_quick_candidate_study_writes_its_manifest(tmp_path):
    from adaptfilt.experiments.beyond import run, summary_md
    from adaptfilt.reproduce import sha256

    summary = run(tmp_path, quick=True, workers=1, studies=("cand",), progress=False)
    man = json.loads((tmp_path / "beyond" / "manifest.json").read_text())
    for e in man["files"]:
        assert sha256(tmp_path / "beyond" / e["path"]) == e["sha256"] and e["command"]
    assert set(summary["cand"]) == {"ungm-ukf", "ctm-ukf"}
    rows = summary["cand"]["ungm-ukf"]
    assert rows["adaptive-cand"]["cost"]["n_seeds"] == 2 and "greedy" in rows
    assert "| ungm-ukf | adaptive-cand |" in summary_md(summary)
