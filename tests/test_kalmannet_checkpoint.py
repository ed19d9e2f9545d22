"""A KalmanNet training stopped and resumed from its checkpoint is the training that was never stopped, bit for bit.

The reference is the same call run straight through; a stop is a KeyboardInterrupt raised right after the
k-th checkpoint is written, or some steps after it (what Ctrl-C or the end of a session does), and the resumed
call must give the same weights, the same history (CPU seconds aside) and the same snapshots, in every
configuration whose loop position a checkpoint has to capture: a window in the middle of a minibatch
(truncated back-propagation), a minibatch in the middle of an epoch, fresh data per minibatch or per epoch, a
fixed training set in a seeded order, validation once per epoch, the Bayesian variant's dropout draws, attempts
abandoned by the restart rule, returns to the best weights at half the learning rate, and the unsupervised loss
on a truth that differs from the model.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

import adaptfilt as af
from adaptfilt import kalmannet
from adaptfilt.kalmannet import train_kalmannet

torch.set_num_threads(1)


def linear_model(q: float = 1.0) -> af.StateSpaceModel:
    return af.models.linear_gaussian(F=[[0.9]], H=[[1.0]], Q=[[q]], R=[[1.0]], m0=[0.0], P0=[[1.0]], name="lin1")


# n_steps 12 in windows of 5: steps 0-4, 5-9, 10-11, so a validation every 2 optimiser steps falls inside a
# minibatch as often as at its end; 8 trajectories in minibatches of 4: two minibatches per epoch
STEPS = dict(n_train=8, n_val=4, n_steps=12, batch_size=4, tbptt=5, lr=3e-3, progress=False, seed=2, epochs=None,
             val_every=2, max_steps=24, snapshot_steps=(6, 12, 24))
CONFIGS = {
    "fresh minibatches, restart rule": (linear_model, dict(STEPS, arch=1, fresh="batch", on_diverged="restart",
                                                           restarts=1, patience=6)),
    "fresh epochs, architecture 2": (linear_model, dict(STEPS, arch=2, fresh="epoch")),
    # numpy numbers where Python's are expected: the checkpoint's record must still be plain JSON
    "fixed training set, numpy arguments": (linear_model, dict(STEPS, arch=1, lr=np.float64(3e-3),
                                                               val_every=np.int64(2))),
    "validation once per epoch": (linear_model, dict(STEPS, arch=1, fresh="batch", val_every=None, max_steps=None,
                                                     epochs=4, snapshot_steps=(), snapshots=(2, 4))),
    "Bayesian variant": (linear_model, dict(STEPS, arch=1, fresh="batch", dropout=0.2, n_samples=3)),
    "abandoned attempts": (linear_model, dict(STEPS, arch=1, fresh="batch", lr=1e-300, on_diverged="restart",
                                              restarts=2, patience=4)),
    # a learning rate far too large on UNGM: non-finite losses, each a return to the best weights at half the rate
    "returns to the best weights": (af.models.ungm, dict(STEPS, arch=2, n_steps=40, tbptt=15, fresh="batch",
                                                         lr=0.3, on_diverged="restore", max_restores=50)),
    "unsupervised loss on another truth": (linear_model, dict(STEPS, arch=1, fresh="batch", loss="unsupervised",
                                                              truth=linear_model(q=4.0))),
}


class Stop(KeyboardInterrupt):
    pass


def stopped_after(monkeypatch, k: int, later: int = 0):
    """Stop the training ``later`` optimiser steps after the k-th checkpoint written (k = 0: never); the count of
    checkpoints written, as a dict."""
    write, after = kalmannet._Training.write_checkpoint, kalmannet._Training.after_step
    n = {"written": 0, "stop_at": None}

    def write_then_stop(self, *args):
        before = self.ckpt_time
        write(self, *args)
        if self.ckpt_time != before:  # written (not skipped as not yet due)
            n["written"] += 1
            if n["written"] == k:
                n["stop_at"] = self.step + later
                if not later:
                    raise Stop

    def step_then_stop(self, epoch):
        end = after(self, epoch)
        if n["stop_at"] is not None and self.step >= n["stop_at"]:
            raise Stop
        return end

    monkeypatch.setattr(kalmannet._Training, "write_checkpoint", write_then_stop)
    monkeypatch.setattr(kalmannet._Training, "after_step", step_then_stop)
    return n


def same_training(a, b) -> None:
    for (name, x), y in zip(a.net.state_dict().items(), b.net.state_dict().values()):
        assert torch.equal(x, y), name
    # as JSON: a non-finite loss (NaN) in both histories compares equal
    plain = lambda h: json.dumps({k: v for k, v in h.items() if k != "cpu_s"}, sort_keys=True)  # noqa: E731
    assert plain(a.history) == plain(b.history)
    assert a.seed == b.seed


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # restarts, restores and failed trainings warn: not the point
@pytest.mark.parametrize("config", CONFIGS)
def test_a_stopped_training_resumes_bit_for_bit(config, tmp_path, monkeypatch, capsys):
    make, kw = CONFIGS[config]
    model = make()
    ref = train_kalmannet(model, **kw)
    if config == "returns to the best weights":
        assert len(ref.history["restores"]) >= 2
    ckpt = tmp_path / "t.ckpt.npz"
    with monkeypatch.context() as m:
        n = stopped_after(m, 0)  # count the checkpoints of an unstopped call: the same training
        same_training(ref, train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw))
    assert n["written"] >= 3 and ckpt.is_file()  # the file stays: the caller deletes it once its results are safe
    stops = [(k, 0) for k in sorted({1, 2, n["written"] // 2, n["written"]})] + [(n["written"] // 2, 1)]
    for k, later in stops:
        ckpt.unlink()
        with monkeypatch.context() as m:
            stopped_after(m, k, later)
            with pytest.raises(Stop):
                train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
        got = train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
        assert len(got.resumed_at) == 1 and 0 < got.resumed_at[0] < ref.history["optimiser_steps"]
        assert "KalmanNet training resumed at optimiser step" in capsys.readouterr().err
        same_training(ref, got)
        for kind, at in ref._snapshots:
            snap = (lambda f: f.snapshot(at)) if kind == "epoch" else (lambda f: f.snapshot(step=at))
            same_training(snap(ref), snap(got))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_a_training_stopped_twice_writes_the_same_file_byte_for_byte(tmp_path, monkeypatch):
    model = af.models.ungm()
    kw = dict(arch=2, n_train=6, n_val=4, n_steps=40, batch_size=3, tbptt=15, lr=1e-3, clip=10.0, seed=1,
              progress=False, epochs=None, max_steps=12, fresh="batch", val_every=2, feature_norm="scale",
              clamp="auto", on_diverged="restart", restarts=1, patience=4, collapse_after=2)
    ref = train_kalmannet(model, **kw).save(tmp_path / "ref.npz")
    ckpt = tmp_path / "t.ckpt.npz"
    for k in (2, 1):  # the second sitting stops one checkpoint after its resume
        with monkeypatch.context() as m:
            stopped_after(m, k)
            with pytest.raises(Stop):
                train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
    got = train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
    assert len(got.resumed_at) == 2 and got.resumed_at[0] < got.resumed_at[1]
    assert got.save(tmp_path / "got.npz").read_bytes() == ref.read_bytes()


def test_a_checkpoint_of_another_training_is_an_error_naming_what_differs(tmp_path, monkeypatch):
    model = linear_model()
    kw = CONFIGS["fresh epochs, architecture 2"][1]
    ckpt = tmp_path / "t.ckpt.npz"
    with monkeypatch.context() as m:
        stopped_after(m, 2)
        with pytest.raises(Stop):
            train_kalmannet(model, checkpoint=ckpt, checkpoint_every=0, **kw)
    with pytest.raises(ValueError, match=r"written by a different training \(lr 0.003 there, 0.001 here\); delete it"):
        train_kalmannet(model, checkpoint=ckpt, **dict(kw, lr=1e-3))
    with pytest.raises(ValueError, match=r"\(model \['lin1', .*\.\.\. there, \['lin1', .*\.\.\. here\)"):
        train_kalmannet(linear_model(q=2.0), checkpoint=ckpt, **kw)
    ckpt.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not an adaptfilt KalmanNet checkpoint"):
        train_kalmannet(model, checkpoint=ckpt, **kw)


def test_the_checkpoint_interval_is_wall_time_and_checkpoint_errors_name_the_option(tmp_path, monkeypatch):
    model = linear_model()
    kw = CONFIGS["fresh epochs, architecture 2"][1]
    written = []
    write = kalmannet._Training.write_checkpoint

    def counting(self, *args):
        before = self.ckpt_time
        write(self, *args)
        written.append(self.ckpt_time != before)

    monkeypatch.setattr(kalmannet._Training, "write_checkpoint", counting)
    train_kalmannet(model, checkpoint=tmp_path / "a.ckpt.npz", checkpoint_every=3600, **kw)
    assert len(written) == kw["max_steps"] // kw["val_every"] - 1 and not any(written)  # none due in an hour
    assert not (tmp_path / "a.ckpt.npz").exists()
    written.clear()
    train_kalmannet(model, checkpoint=tmp_path / "b.ckpt.npz", checkpoint_every=0, **kw)
    assert written and all(written)
    traj = model.simulate(4, 12, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="a checkpoint resumes a training that simulates its own data"):
        train_kalmannet(model, train=traj, val=traj, checkpoint=tmp_path / "c.ckpt.npz", epochs=1, progress=False)
    with pytest.raises(ValueError, match="checkpoint_every must be a number of seconds >= 0"):
        train_kalmannet(model, checkpoint=tmp_path / "c.ckpt.npz", checkpoint_every=-1, **kw)


def gain_spec(folder: Path):
    from adaptfilt.experiments.jobs import GainSpec

    outs = tuple(str(folder / f"g-b{i}.npz") for i in (1, 2))
    return GainSpec("ungm-ukf", "supervised", None, 3, outs, horizon=20, train_runs=4, val_runs=4, batch_size=2,
                    fresh="batch", val_every=2, tbptt=15, lr=3e-3, clip=10.0, clamp="auto", steps=12,
                    snapshot_steps=(6, 12), on_diverged="restart", restarts=1, patience=4)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_a_train_gain_job_keeps_its_checkpoint_beside_its_last_file_and_resumes_from_it(tmp_path, monkeypatch):
    """The pipeline's learned-gain job (``adaptfilt train-gain``): stopped, then run again, it writes the files
    of the job that was never stopped, byte for byte, and deletes its checkpoint once they are written."""
    ref = gain_spec(tmp_path / "ref")
    ref.run()
    monkeypatch.setattr(kalmannet, "CHECKPOINT_EVERY_S", 0.0)
    job = gain_spec(tmp_path / "job")
    assert job.checkpoint == tmp_path / "job" / "g-b2.ckpt.npz"  # as adaptfilt train names its checkpoints
    with monkeypatch.context() as m:
        stopped_after(m, 3)
        with pytest.raises(Stop):
            job.run()
    assert job.checkpoint.is_file() and not any(Path(p).exists() for p in job.outputs)
    job.run()
    assert not job.checkpoint.exists()
    for a, b in zip(ref.outputs, job.outputs):
        assert Path(a).read_bytes() == Path(b).read_bytes()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_train_gain_stopped_says_in_one_line_that_its_checkpoint_is_kept(tmp_path, monkeypatch, capsys):
    from adaptfilt.cli import main

    spec = gain_spec(tmp_path)
    args = spec.command.split()[1:] + ["--no-progress"]
    monkeypatch.setattr(kalmannet, "CHECKPOINT_EVERY_S", 0.0)
    stopped_after(monkeypatch, 2)
    with pytest.raises(SystemExit) as e:
        main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 130 and err[-1] == (f"adaptfilt: interrupted: the checkpoint {spec.checkpoint} is kept; "
                                               "run the same command again to continue from it")
    assert spec.checkpoint.is_file()
