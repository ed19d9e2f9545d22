"""A KalmanNet training stopped at a checkpoint and resumed is the training that was never stopped, bit for bit.

The reference is the same call run straight through; a stop is a KeyboardInterrupt raised right after the
k-th checkpoint is written (what Ctrl-C or the end of a session does between two checkpoints), and the resumed
call must give the same weights, the same history (CPU seconds aside) and the same snapshots, in every
configuration whose loop position a checkpoint has to capture: a window in the middle of a minibatch
(truncated back-propagation), a minibatch in the middle of an epoch, fresh data per minibatch or per epoch, a
fixed training set in a seeded order, validation once per epoch, the Bayesian variant's dropout draws, and
attempts abandoned by the restart rule.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

import adaptfilt as af
from adaptfilt import kalmannet
from adaptfilt.kalmannet import train_kalmannet

torch.set_num_threads(1)


def linear_model() -> af.StateSpaceModel:
    return af.models.linear_gaussian(F=[[0.9]], H=[[1.0]], Q=[[1.0]], R=[[1.0]], m0=[0.0], P0=[[1.0]], name="lin1")


# n_steps 12 in windows of 5: steps 0-4, 5-9, 10-11, so a validation every 2 optimiser steps falls inside a
# minibatch as often as at its end; 8 trajectories in minibatches of 4: two minibatches per epoch
STEPS = dict(n_train=8, n_val=4, n_steps=12, batch_size=4, tbptt=5, lr=3e-3, progress=False, seed=2, epochs=None,
             val_every=2, max_steps=24, snapshot_steps=(6, 12, 24))
CONFIGS = {
    "fresh minibatches, restart rule": dict(STEPS, arch=1, fresh="batch", on_diverged="restart", restarts=1,
                                            patience=6),
    "fresh epochs, architecture 2": dict(STEPS, arch=2, fresh="epoch"),
    "fixed training set": dict(STEPS, arch=1),
    "validation once per epoch": dict(STEPS, arch=1, fresh="batch", val_every=None, max_steps=None, epochs=4,
                                      snapshot_steps=(), snapshots=(2, 4)),
    "Bayesian variant": dict(STEPS, arch=1, fresh="batch", dropout=0.2, n_samples=3),
    "abandoned attempts": dict(STEPS, arch=1, fresh="batch", lr=1e-300, on_diverged="restart", restarts=2,
                               patience=4),
}


class Stop(KeyboardInterrupt):
    pass


def stopped_after(monkeypatch, k: int):
    """Make the k-th checkpoint written the last one: a KeyboardInterrupt right after it (k = 0: never); the
    count of checkpoints written."""
    write = kalmannet._Training.write_checkpoint
    n = {"written": 0}

    def write_then_stop(self, *args):
        before = self.ckpt_time
        write(self, *args)
        if self.ckpt_time != before:  # written (not skipped as not yet due)
            n["written"] += 1
            if n["written"] == k:
                raise Stop

    monkeypatch.setattr(kalmannet._Training, "write_checkpoint", write_then_stop)
    return n


def same_training(a, b) -> None:
    for (name, x), y in zip(a.net.state_dict().items(), b.net.state_dict().values()):
        assert torch.equal(x, y), name
    strip = lambda h: {k: v for k, v in h.items() if k != "cpu_s"}  # noqa: E731 -- CPU seconds vary
    assert strip(a.history) == strip(b.history)
    assert a.seed == b.seed


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # restarts and failed trainings warn: not the point here
@pytest.mark.parametrize("config", CONFIGS)
def test_a_stopped_training_resumes_bit_for_bit(config, tmp_path, monkeypatch, capsys):
    model = linear_model()
    kw = CONFIGS[config]
    ref = train_kalmannet(model, **kw)
    ckpt = tmp_path / "t.resume.pt"
    with monkeypatch.context() as m:
        n = stopped_after(m, 0)  # count the checkpoints of an unstopped call: the same training
        same_training(ref, train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw))
    assert n["written"] >= 3
    for k in sorted({1, 2, n["written"] // 2, n["written"]}):
        with monkeypatch.context() as m:
            stopped_after(m, k)
            with pytest.raises(Stop):
                train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
        assert ckpt.is_file()
        got = train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
        assert len(got.resumed_at) == 1 and 0 < got.resumed_at[0] < ref.history["optimiser_steps"]
        assert "KalmanNet training resumed at optimiser step" in capsys.readouterr().err
        assert not ckpt.exists()  # a finished training removes its checkpoint
        same_training(ref, got)
        for key in ref._snapshots:
            kind, at = key
            snap = (lambda f: f.snapshot(at)) if kind == "epoch" else (lambda f: f.snapshot(step=at))
            same_training(snap(ref), snap(got))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_a_training_stopped_twice_writes_the_same_file_byte_for_byte(tmp_path, monkeypatch):
    model = af.models.ungm()
    kw = dict(arch=2, n_train=6, n_val=4, n_steps=40, batch_size=3, tbptt=15, lr=1e-3, clip=10.0, seed=1,
              progress=False, epochs=None, max_steps=12, fresh="batch", val_every=2, feature_norm="scale",
              clamp="auto", on_diverged="restart", restarts=1, patience=4, collapse_after=2)
    ref = train_kalmannet(model, **kw).save(tmp_path / "ref.npz")
    ckpt = tmp_path / "t.resume.pt"
    for k in (2, 1):  # the second sitting stops one checkpoint after its resume
        with monkeypatch.context() as m:
            stopped_after(m, k)
            with pytest.raises(Stop):
                train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
    got = train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
    assert len(got.resumed_at) == 2 and got.resumed_at[0] < got.resumed_at[1]
    assert got.save(tmp_path / "got.npz").read_bytes() == ref.read_bytes()


def test_a_checkpoint_of_another_call_is_ignored_with_a_warning(tmp_path, monkeypatch):
    model = linear_model()
    kw = CONFIGS["fixed training set"]
    ckpt = tmp_path / "t.resume.pt"
    with monkeypatch.context() as m:
        stopped_after(m, 2)
        with pytest.raises(Stop):
            train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
    other = dict(kw, lr=1e-3)
    with pytest.warns(RuntimeWarning, match="checkpoint .* ignored, made by a training with other arguments"):
        got = train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **other)
    assert got.resumed_at == []
    same_training(train_kalmannet(model, **other), got)
    with monkeypatch.context() as m:
        stopped_after(m, 2)
        with pytest.raises(Stop):
            train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
    monkeypatch.setattr(kalmannet, "_code_sha256", lambda: "edited training code")
    with pytest.warns(RuntimeWarning, match="other arguments or other training code"):
        assert train_kalmannet(model, checkpoint=ckpt, **kw).resumed_at == []
    ckpt.write_bytes(b"not a checkpoint")
    with pytest.warns(RuntimeWarning, match="checkpoint .* ignored, unreadable"):
        assert train_kalmannet(model, checkpoint=ckpt, **kw).resumed_at == []


def test_the_checkpoint_interval_is_wall_time_and_checkpoint_errors_name_the_option(tmp_path, monkeypatch):
    model = linear_model()
    kw = CONFIGS["fixed training set"]
    written = []
    write = kalmannet._Training.write_checkpoint

    def counting(self, *args):
        before = self.ckpt_time
        write(self, *args)
        written.append(self.ckpt_time != before)

    monkeypatch.setattr(kalmannet._Training, "write_checkpoint", counting)
    train_kalmannet(model, checkpoint=tmp_path / "a.pt", checkpoint_every=3600, **kw)
    assert len(written) == kw["max_steps"] // kw["val_every"] - 1 and not any(written)  # none due in an hour
    written.clear()
    train_kalmannet(model, checkpoint=tmp_path / "b.pt", checkpoint_every=0, **kw)
    assert written and all(written)
    traj = model.simulate(4, 12, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="a checkpoint resumes a training that simulates its own data"):
        train_kalmannet(model, train=traj, val=traj, checkpoint=tmp_path / "c.pt", epochs=1, progress=False)
    with pytest.raises(ValueError, match="checkpoint_every must be a number of seconds >= 0"):
        train_kalmannet(model, checkpoint=tmp_path / "c.pt", checkpoint_every=-1, **kw)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_a_train_gain_job_keeps_its_checkpoint_beside_its_last_file_and_resumes_from_it(tmp_path, monkeypatch):
    """The pipeline's learned-gain job (``adaptfilt train-gain``): stopped, then run again, it writes the files
    of the job that was never stopped, byte for byte, and leaves no checkpoint behind."""
    from adaptfilt.experiments.jobs import GainSpec

    def spec(folder: str) -> GainSpec:
        outs = tuple(str(tmp_path / folder / f"g-b{i}.npz") for i in (1, 2))
        return GainSpec("ungm-ukf", "supervised", None, 3, outs, horizon=20, train_runs=4, val_runs=4, batch_size=2,
                        fresh="batch", val_every=2, tbptt=15, lr=3e-3, clip=10.0, clamp="auto", steps=12,
                        snapshot_steps=(6, 12), on_diverged="restart", restarts=1, patience=4)

    ref = spec("ref")
    ref.run()
    monkeypatch.setattr(kalmannet, "CHECKPOINT_EVERY_S", 0.0)
    job = spec("job")
    assert job.checkpoint == tmp_path / "job" / "g-b2.npz.resume.pt"
    with monkeypatch.context() as m:
        stopped_after(m, 3)
        with pytest.raises(Stop):
            job.run()
    assert job.checkpoint.is_file() and not any(map(lambda p: Path(p).exists(), job.outputs))
    job.run()
    assert not job.checkpoint.exists()
    for a, b in zip(ref.outputs, job.outputs):
        assert Path(a).read_bytes() == Path(b).read_bytes()
