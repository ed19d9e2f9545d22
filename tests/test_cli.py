"""The ``adaptfilt`` command (:mod:`adaptfilt.cli`): its version, the commands the manifests record (each a
command line of today's parser), ``train-gain`` and the reference stages ``floor`` and ``reconcile``, each
against the library call it stands for."""
import json
import shlex
from pathlib import Path

import numpy as np
import pytest

from adaptfilt.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]


def test_version_prints_the_package_version(capsys):
    from adaptfilt._version import __version__

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.strip() == f"adaptfilt {__version__}"


@pytest.mark.parametrize("manifest", ["data/manifest.json", "data/beyond/manifest.json"])
def test_every_recorded_command_is_a_command_line_of_the_parser(manifest, tmp_path, monkeypatch):
    """Each command a manifest records is an ``adaptfilt`` line that today's parser accepts, every value
    valid (its files written into a scratch folder instead of where it says: the recorded ``--out`` may be
    another checkout's); the relative paths it reads are the checkout's."""
    monkeypatch.chdir(ROOT)
    parser = build_parser()
    files = json.loads((ROOT / manifest).read_text())["files"]
    kinds = set()
    for entry in files:
        words = shlex.split(entry["command"])
        assert words[0] == "adaptfilt", entry
        for i, w in enumerate(words[:-1]):
            if w == "--out":
                words[i + 1] = str(tmp_path / f"o{i}" / Path(words[i + 1]).name)
        args = parser.parse_args(words[1:])
        kinds.add(args.cmd)
    want = {"train", "evaluate", "reproduce", "floor", "reconcile"} if manifest == "data/manifest.json" else \
        {"train", "train-gain", "imitate", "beyond"}
    assert kinds == want


# ------------------------------------------------------------------ imitate
def test_imitate_writes_the_policy_the_studys_shared_fit_makes(tmp_path):
    """``adaptfilt imitate`` (one feature set, its own teacher runs) writes the network the mlanchor study's job
    fits for that set on the runs it shares between three sets, weight for weight, and records its line."""
    from adaptfilt.experiments.studies.mlanchor import IMITATION, imitation_job
    from adaptfilt.learned import load_policy

    size = dict(runs=4, epochs=2, n_steps=5)
    paths = {g: str(tmp_path / f"{g}.npz") for g in IMITATION}
    imitation_job(1, size["runs"], size["epochs"], size["n_steps"], paths, {g: "study" for g in IMITATION})
    g, fs = sorted(IMITATION.items())[-1]
    out = str(tmp_path / "one.npz")
    assert main(["imitate", "ctm-ukf", "--features", fs, "--seed", "1", "--runs", "4", "--epochs", "2",
                 "--horizon", "5", "--out", out]) == 0
    one, shared = load_policy(out, experiment="ctm-ukf"), load_policy(paths[g], experiment="ctm-ukf")
    for a, b in zip(one.actor.parameters(), shared.actor.parameters()):
        np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())
    assert one.metadata["command"] == (f"adaptfilt imitate ctm-ukf --features {fs} --seed 1 --runs 4 --epochs 2 "
                                       f"--teacher ml --horizon 5 --holdout 0.2 --lr 0.001 --batch-size 1024 --out {out}")
    words = shlex.split(one.metadata["command"])
    assert build_parser().parse_args(words[1:]).features == fs


def test_imitate_rejects_bad_values_in_one_line(capsys):
    for bad, what in ((["--holdout", "1"], "--holdout must be in (0, 1)"), (["--runs", "1"], "integer >= 2"),
                      (["--features", "nonsense"], "features")):
        with pytest.raises(SystemExit) as e:
            main(["imitate", "ctm-ukf", "--features", "paper+circ", *bad, "--out", "x.npz"])
        err = capsys.readouterr().err.strip()
        assert e.value.code == 2 and err.startswith("adaptfilt: error:") and what in err and "\n" not in err, err


# ------------------------------------------------------------------ train-gain
GAIN = ["--epochs", "2", "--snapshots", "1,2", "--horizon", "8", "--train-runs", "4", "--val-runs", "2",
        "--batch-size", "2", "--clip", "10", "--feature-norm", "scale", "--no-progress"]


def _weights(knet) -> list[np.ndarray]:
    return [p.detach().numpy().copy() for p in knet.net.parameters()]


def test_train_gain_writes_one_file_per_snapshot_with_its_command(tmp_path, capsys):
    """The files are the snapshots of ``train_kalmannet`` called with the same recipe, weights bit for bit,
    and each records in its manifest entry the command that wrote them all."""
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.jobs import GainSpec
    from adaptfilt.kalmannet import load_kalmannet, train_kalmannet

    outs = [str(tmp_path / "b1.npz"), str(tmp_path / "b2.npz")]
    assert main(["train-gain", "ungm-ukf", "--seed", "3", *GAIN, "--out", outs[0], "--out", outs[1]]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {outs[0]}, {outs[1]}"
    model = get_experiment("ungm-ukf").make_model()
    ref = train_kalmannet(model, loss="supervised", n_steps=8, epochs=2, seed=3, progress=False, snapshots=(1, 2),
                          n_train=4, n_val=2, batch_size=2, lr=1e-3, weight_decay=1e-4, clip=10.0, tbptt=None,
                          feature_norm="scale", on_diverged="raise")
    for e, f in zip((1, 2), outs):
        got = load_kalmannet(f, model)
        for a, b in zip(_weights(got), _weights(ref.snapshot(e))):
            np.testing.assert_array_equal(a, b)
        assert got.history["epochs"] == e
    spec = GainSpec("ungm-ukf", "supervised", 2, 3, tuple(outs), snapshots=(1, 2), horizon=8, train_runs=4,
                    val_runs=2, batch_size=2, clip=10.0)
    assert spec.command == ("adaptfilt train-gain ungm-ukf --arch kalmannet --loss supervised --epochs 2 "
                            "--snapshots 1,2 --seed 3 --horizon 8 --train-runs 4 --val-runs 2 --batch-size 2 "
                            "--lr 0.001 --weight-decay 0.0001 --clip 10 --feature-norm scale --on-diverged raise "
                            f"--model-grad jacobian --out {outs[0]} --out {outs[1]}")


def test_train_gain_on_a_truth_trains_on_its_trajectories(tmp_path):
    """``--truth q=4``: the same training on trajectories of the model with Q x 4 (drawn from the generators the
    training draws its own from), the filter keeping the nominal model; not the nominal training."""
    from adaptfilt.experiment_registry import get_experiment, scaled_truth
    from adaptfilt.kalmannet import load_kalmannet, train_kalmannet

    out, nominal = tmp_path / "q4.npz", tmp_path / "nominal.npz"
    small = [w for w in GAIN if w not in ("--snapshots", "1,2")]
    main(["train-gain", "ungm-ukf", "--truth", "q=4", *small, "--out", str(out)])
    main(["train-gain", "ungm-ukf", *small, "--out", str(nominal)])
    model = get_experiment("ungm-ukf").make_model()
    truth = scaled_truth(model, q=4.0)
    ref = train_kalmannet(model, loss="supervised", n_steps=8, epochs=2, seed=0, progress=False, n_train=4, n_val=2,
                          batch_size=2, clip=10.0, feature_norm="scale",
                          train=truth.simulate(4, 8, rng=np.random.default_rng([0, 0])),
                          val=truth.simulate(2, 8, rng=np.random.default_rng([0, 1])))
    got, other = load_kalmannet(out, model), load_kalmannet(nominal, model)
    for a, b in zip(_weights(got), _weights(ref)):
        np.testing.assert_array_equal(a, b)
    assert any((a != b).any() for a, b in zip(_weights(got), _weights(other)))


@pytest.mark.parametrize("args, expect", [
    (["--snapshots", "1,3", "--epochs", "2", "--out", "a.npz", "--out", "b.npz"], "epochs up to --epochs 2"),
    (["--snapshots", "1,2", "--out", "a.npz"], "2 files to write (one per snapshot), got 1 --out"),
    (["--snapshots", "2,1", "--out", "a.npz"], "increasing epochs"),
    (["--truth", "q=-1", "--out", "a.npz"], "a truth is written q=FACTOR,r=FACTOR"),
    (["--truth", "f=2", "--out", "a.npz"], "got 'f=2'"),
    (["--arch", "gru", "--out", "a.npz"], "argument --arch: invalid choice"),
    (["--lr", "0", "--out", "a.npz"], "argument --lr: must be a finite number > 0, got 0"),
    (["--steps", "4", "--snapshot-steps", "2,4", "--out", "a.npz", "--out", "b.npz"], "multiples of --val-every"),
    (["--steps", "4", "--epochs", "2", "--out", "a.npz"], "not allowed with argument"),
    (["--steps", "4", "--val-every", "2", "--snapshot-steps", "2,6", "--out", "a.npz", "--out", "b.npz"],
     "optimiser steps up to --steps 4"),
    (["--restarts", "2", "--out", "a.npz"], "give --on-diverged restart"),
    (["--arch", "kalmannet-arch1", "--hidden-mult", "2", "--out", "a.npz"], "hidden_mult widens architecture 2"),
    (["--truth", "forcing=inf", "--out", "a.npz"], "forcing=AMPLITUDE"),
])
def test_train_gain_usage_errors_are_one_line(capsys, tmp_path, monkeypatch, args, expect):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        main(["train-gain", "ungm-ukf", *args])
    err = capsys.readouterr().err.splitlines()
    assert e.value.code == 2 and len(err) == 1 and err[0].startswith("adaptfilt: error: ") and expect in err[0], err
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ the reference stages
@pytest.mark.parametrize("stage", ["floor", "reconcile"])
def test_reference_stages_write_what_the_reproduction_writes(stage, tmp_path):
    """``adaptfilt floor`` / ``reconcile`` write the JSON of the reproduction's stage of that name: the library
    call's value (its times aside), recording the line that makes it."""
    from adaptfilt.experiments.references import ctm_reconciliation, floor_command, reconcile_command, ungm_floor

    out = tmp_path / "ref.json"
    if stage == "floor":
        main(["floor", "--runs", "6", "--horizon", "4", "--eval-runs", "9", "--out", str(out)])
        want = ungm_floor(6, 0, 4, eval_runs=9)
        assert want["command"] == floor_command(6, 0, 4, 9) == \
            "adaptfilt floor --runs 6 --seed 0 --horizon 4 --eval-runs 9 --out data/results/ungm-floor.json"
    else:
        main(["reconcile", "--runs", "5", "--seed", "2", "--horizon", "3", "--out", str(out)])
        want = ctm_reconciliation(5, 2, 3)
        assert want["command"] == reconcile_command(5, 2, 3)
    got = json.loads(out.read_text())
    timed = ("wall_time_s", "cpu_time_s")
    assert {k: v for k, v in got.items() if k not in timed} == \
        json.loads(json.dumps({k: v for k, v in want.items() if k not in timed}))


def test_a_recorded_train_gain_line_reads_back_the_same_numbers():
    """The command writes each number so that the parser reads back the same float (0.001, but all the digits
    of 1.2345678e-3), and every option of the spec survives the round trip."""
    from adaptfilt.experiments.jobs import GainSpec

    spec = GainSpec("ctm-ukf", "unsupervised", 7, 2, ("a.npz", "b.npz"), snapshots=(3, 7), truth="q=4,r=1",
                    horizon=40, train_runs=9, val_runs=5, batch_size=3, lr=1.2345678e-3, weight_decay=0.0,
                    clip=0.5, tbptt=10, feature_norm="l2", on_diverged="restore")
    args = build_parser().parse_args(shlex.split(spec.command)[1:])
    back = GainSpec(args.name, args.loss, args.epochs, args.seed, tuple(args.out), snapshots=args.snapshots,
                    arch=args.arch, truth=args.truth, horizon=args.horizon, train_runs=args.train_runs,
                    val_runs=args.val_runs, batch_size=args.batch_size, lr=args.lr, weight_decay=args.weight_decay,
                    clip=args.clip, tbptt=args.tbptt, feature_norm=args.feature_norm, on_diverged=args.on_diverged)
    assert back == spec and "--lr 0.0012345678" in spec.command and "--clip 0.5" in spec.command


def test_a_train_gain_line_with_every_option_of_the_gain_study_reads_back_the_same_spec():
    """The options the gain study's trainings use (architecture 1, a width, budgets and snapshots in optimiser
    steps, fresh trajectories, validation every k steps, the clamp, the restart rule, a truth with other dynamics)
    are written out and read back, and the options left out are those whose value is the feature's absence."""
    from adaptfilt.cli import gain_spec
    from adaptfilt.experiments.jobs import GainSpec

    for spec in (GainSpec("ungm-ukf", "supervised", None, 5, ("a.npz", "b.npz"), arch="kalmannet-arch1", steps=50,
                          snapshot_steps=(25, 50), truth="q=1,r=1,forcing=10", horizon=30, train_runs=100,
                          val_runs=100, batch_size=100, fresh="batch", val_every=25, lr=3e-3, clip=10.0, tbptt=20,
                          clamp="auto", on_diverged="restart", restarts=2, patience=200, collapse_after=4),
                 GainSpec("ctm-ukf", "unsupervised", 4, 1, ("c.npz",), hidden_mult=8, fresh="epoch",
                          on_diverged="restart", restarts=1)):
        back = gain_spec(build_parser().parse_args(shlex.split(spec.command)[1:]))
        assert back == spec, (back, spec)
    words = spec.command.split()
    assert "--hidden-mult" in words and "--patience" not in words and "--clamp" not in words
    old = GainSpec("ungm-ukf", "supervised", 3, 0, ("x.npz",))
    assert old.command == ("adaptfilt train-gain ungm-ukf --arch kalmannet --loss supervised --epochs 3 --seed 0 "
                           "--train-runs 100 --val-runs 50 --batch-size 20 --lr 0.001 --weight-decay 0.0001 "
                           "--feature-norm scale --on-diverged raise --model-grad jacobian --out x.npz")


def test_train_gain_in_optimiser_steps_writes_the_step_snapshots_of_train_kalmannet(tmp_path):
    """``--steps --snapshot-steps`` with fresh trajectories, architecture 1 and a truth whose forcing differs: the
    files hold the step snapshots of ``train_kalmannet`` called with that recipe and that truth (weights bit for
    bit), the filter keeping the nominal model."""
    from adaptfilt.experiment_registry import get_experiment, truth_model
    from adaptfilt.kalmannet import load_kalmannet, train_kalmannet

    outs = [str(tmp_path / "s2.npz"), str(tmp_path / "s4.npz")]
    args = ["--arch", "kalmannet-arch1", "--steps", "4", "--snapshot-steps", "2,4", "--horizon", "8", "--train-runs",
            "4", "--val-runs", "2", "--batch-size", "4", "--fresh", "batch", "--val-every", "2", "--tbptt", "4",
            "--clamp", "auto", "--on-diverged", "restart", "--restarts", "1", "--truth", "forcing=10", "--no-progress"]
    main(["train-gain", "ungm-ukf", "--seed", "2", *args, "--out", outs[0], "--out", outs[1]])
    model = get_experiment("ungm-ukf").make_model()
    ref = train_kalmannet(model, loss="supervised", n_steps=8, epochs=None, max_steps=4, snapshot_steps=(2, 4),
                          seed=2, progress=False, n_train=4, n_val=2, batch_size=4, fresh="batch", val_every=2,
                          tbptt=4, clamp="auto", on_diverged="restart", restarts=1, arch=1, feature_norm="scale",
                          truth=truth_model(model, "forcing=10"))
    for s, f in zip((2, 4), outs):
        got = load_kalmannet(f, model)
        for a, b in zip(_weights(got), _weights(ref.snapshot(step=s))):
            np.testing.assert_array_equal(a, b)
        assert got.history["optimiser_steps"] == s and got.options["arch"] == 1
        assert got.history["truth"] == "ungm, forcing 10 cos(0.05k), Q x1, R x1"
        assert got.model.description == model.description


def test_a_forcing_truth_on_a_model_without_one_is_one_line(capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        main(["train-gain", "ctm-ukf", "--truth", "forcing=3", "--epochs", "1", "--out", str(tmp_path / "a.npz")])
    err = capsys.readouterr().err.splitlines()
    assert e.value.code == 2 and len(err) == 1 and "model 'ctm' has none" in err[0], err


def test_train_with_snapshots_writes_each_shorter_training_and_reads_back(tmp_path):
    """``adaptfilt train --snapshots E1,E2 --out A --out B`` with the PPO recipe's overrides and a truth: each file
    holds the weights of a training of that many episodes (the same command without snapshots), its metadata the
    command that wrote it and the truth; the command line reads back the same spec."""
    from adaptfilt.cli import _train_spec
    from adaptfilt.learned import load_policy

    outs = [str(tmp_path / "e40.npz"), str(tmp_path / "e200.npz")]
    common = ["ungm-ukf", "--algo", "fast", "--parallel", "8", "--horizon", "10", "--lr", "0.001", "--n-epochs",
              "2", "--truth", "q=4", "--no-progress"]
    main(["train", *common, "--episodes", "200", "--snapshots", "40,200", "--out", outs[0], "--out", outs[1]])
    short = str(tmp_path / "short.npz")
    main(["train", *common, "--episodes", "40", "--out", short])
    a, b = load_policy(outs[0], experiment="ungm-ukf"), load_policy(short, experiment="ungm-ukf")
    assert a.metadata["episodes"] == 40 and a.metadata["truth"] == "q=4,r=1"
    assert a.metadata["trainer"]["kwargs"]["learning_rate"] == 0.001 and a.metadata["trainer"]["kwargs"]["n_epochs"] == 2
    assert "--snapshots 40,200" in a.metadata["command"] and "--snapshots" not in b.metadata["command"]
    (xa, _), (xb, _) = a.to_arrays(), b.to_arrays()
    assert sorted(xa) == sorted(xb)
    for k in xa:
        np.testing.assert_array_equal(xa[k], xb[k])
    spec = _train_spec(build_parser().parse_args(shlex.split(a.metadata["command"])[1:]), 0, tuple(outs))
    assert spec.command == a.metadata["command"]
