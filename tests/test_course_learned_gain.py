"""Chapter 18's reading of the stored learned-gain study: which stored KalmanNets are their untrained initial
network, told by their weights and checked against what their training histories recorded."""
from __future__ import annotations

import pytest

from adaptfilt.course import learned_gain as lg
from adaptfilt.kalmannet import KalmanNet, load_kalmannet, train_kalmannet


@pytest.fixture(scope="module")
def stored():
    return lg.stored_gain_policies()


def test_a_fresh_network_is_initial_a_trained_one_is_not_and_a_file_keeps_it(tmp_path):
    model = lg.linear_model()
    fresh = KalmanNet(model, seed=3, feature_norm="scale")
    assert lg.is_initial_network(fresh)
    path = fresh.save(tmp_path / "fresh.npz")
    assert lg.is_initial_network(load_kalmannet(path, model))
    trained = train_kalmannet(model, seed=3, feature_norm="scale", **{**lg.TRAIN, "epochs": 1})
    assert trained.history["best_epoch"] == 1 and not lg.is_initial_network(trained)
    other_seed = KalmanNet(model, seed=4, feature_norm="scale")
    other_seed.seed = 3  # another seed's weights under this seed's name are not its initial network
    assert not lg.is_initial_network(other_seed)


def test_the_stored_files_that_are_their_initial_network_are_those_whose_best_epoch_is_0(stored):
    """The weights (compared with a fresh network of the same seed and options) and the history (the
    validation never beat epoch 0) are two independent records: they must agree on every one of the 96."""
    assert len(stored) == 96
    by_weights = {k for k, knet in stored.items() if lg.is_initial_network(knet)}
    by_history = {k for k, knet in stored.items() if knet.history["best_epoch"] == 0}
    assert by_weights == by_history
    assert len({k for k in by_weights if k[0] == "ungm-ukf" and k[2] == 3}) == 4
    assert not {k for k in by_weights if k[0] == "ctm-ukf"}


def test_training_lines_count_per_arm_and_budget_and_read_the_ctm_curve(stored):
    text = lg.training_lines(stored)
    assert "ungm-ukf gain-unsup 1 ep. 4 of 8 (seeds 0, 4, 6, 7)" in text
    assert "one and the same network in both arms (seed 6)" in text
    assert "ctm-ukf  gain-sup   3 ep. 0 of 8" in text
    assert "the last epoch in 4 of 8" in text
