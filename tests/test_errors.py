"""Bad input as a new user gives it: one clear error naming the problem.

CLI: exit status 2 and a single stderr line ``adaptfilt: error: ...`` (no
traceback); API: ``ValueError`` / ``FileNotFoundError`` naming what is wrong.
"""
import json
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt import metrics
from adaptfilt.cli import main
from adaptfilt.evaluation import evaluate
from adaptfilt.experiments.evaluate import evaluate_experiment
from adaptfilt.files import read_npz, write_npz
from adaptfilt.learned import learned_name, learned_names, load_policy

ROOT = Path(__file__).resolve().parents[1]
POLICIES = ROOT / "data" / "policies"
UNGM_ADAPTIVE = POLICIES / "ungm-ukf-adaptive-s0.npz"


def cli_error(capsys, args: list[str]) -> str:
    """Run ``adaptfilt ARGS``; assert exit 2 and one ``adaptfilt: error:`` line; return it."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as ei:
        main(args)
    assert ei.value.code == 2
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("adaptfilt: error: ") and "Traceback" not in err
    return lines[0]


# ------------------------------------------------------------- bad files
def bad_files(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name -> (file, what the error must say)."""
    rng = np.random.default_rng(0)
    good = UNGM_ADAPTIVE.read_bytes()
    out = {}

    def put(name: str, data: bytes, why: str) -> None:
        p = tmp_path / name
        p.write_bytes(data)
        out[name] = (p, why)

    put("random.npz", rng.bytes(300), "not a zip/npz archive")
    put("empty.npz", b"", "the file is empty")
    put("truncated.npz", good[: len(good) // 2], "damaged or truncated archive")
    corrupt = bytearray(good)
    info = zipfile.ZipFile(UNGM_ADAPTIVE).getinfo("actor/net.0.weight.npy")
    for i in range(info.header_offset + 100, info.header_offset + 200):  # inside the compressed weights
        corrupt[i] ^= 0x5A
    put("corrupt.npz", bytes(corrupt), "damaged or truncated archive")
    np.savez(tmp_path / "plain.npz", center=np.zeros(3), scale=np.ones(3))
    out["plain.npz"] = (tmp_path / "plain.npz", "no __metadata__ entry")
    with zipfile.ZipFile(tmp_path / "nometa.npz", "w") as z:
        z.writestr("notes.txt", "hello")
    out["nometa.npz"] = (tmp_path / "nometa.npz", "no __metadata__ entry")
    np.savez(tmp_path / "pickled.npz", a=np.array([{"x": 1}], dtype=object))
    out["pickled.npz"] = (tmp_path / "pickled.npz", "pickled Python objects")
    write_npz(tmp_path / "mixed.npz", {"a": np.zeros(2)}, {"format": "adaptfilt-policy/1"})
    with zipfile.ZipFile(tmp_path / "mixed.npz", "a") as z:
        z.writestr("notes.txt", "not an array")
    out["mixed.npz"] = (tmp_path / "mixed.npz", "entry 'notes.txt' is not a .npy array")
    np.save(tmp_path / "single.npy", np.arange(3.0))
    out["single.npy"] = (tmp_path / "single.npy", "a single .npy array")
    return out


def test_read_npz_and_load_policy_name_the_file_and_the_reason(tmp_path):
    for name, (path, why) in bad_files(tmp_path).items():
        pattern = re.escape(f"{path}: not an adaptfilt policy file (") + ".*" + re.escape(why)
        with pytest.raises(ValueError, match=pattern):
            load_policy(path)
        with pytest.raises(ValueError, match=pattern):
            read_npz(path)
    missing = tmp_path / "nope.npz"
    with pytest.raises(FileNotFoundError, match=re.escape(str(missing))):
        load_policy(missing)
    with pytest.raises(ValueError, match="it is a directory"):
        load_policy(tmp_path)


def test_load_policy_rejects_adaptfilt_files_that_are_not_policies(tmp_path):
    arrays, meta = read_npz(UNGM_ADAPTIVE)
    # a training checkpoint (what train writes next to OUT.npz)
    write_npz(tmp_path / "x.ckpt.npz", {"torch_rng": np.zeros(3, np.uint8)}, {"config": {}, "episode": 10})
    with pytest.raises(ValueError, match=r"x\.ckpt\.npz: not an adaptfilt policy file \(it is a training checkpoint"):
        load_policy(tmp_path / "x.ckpt.npz")
    # another format version
    write_npz(tmp_path / "v2.npz", arrays, {**meta, "format": "adaptfilt-policy/2"})
    with pytest.raises(ValueError, match=r"format 'adaptfilt-policy/2', expected 'adaptfilt-policy/1'"):
        load_policy(tmp_path / "v2.npz")
    # the metadata says 3 inputs, the weights and scaler were made for another number
    write_npz(tmp_path / "dims.npz", arrays, {**meta, "actor": {**meta["actor"], "in_dim": 3}})
    with pytest.raises(ValueError, match=r"scaler/center has shape \(\d+,\), the actor expects \(3,\)"):
        load_policy(tmp_path / "dims.npz")
    # weights missing
    no_w = {k: v for k, v in arrays.items() if k != "actor/net.2.weight"}
    write_npz(tmp_path / "now.npz", no_w, meta)
    with pytest.raises(ValueError, match=r"now\.npz: not an adaptfilt policy file \(its actor weights do not fit"):
        load_policy(tmp_path / "now.npz")
    # fields missing, a grid of the wrong size, metadata that is not a JSON object
    write_npz(tmp_path / "nogrid.npz", arrays, {k: v for k, v in meta.items() if k != "grid"})
    with pytest.raises(ValueError, match=r"\(missing grid\)"):
        load_policy(tmp_path / "nogrid.npz")
    write_npz(tmp_path / "grid.npz", arrays, {**meta, "grid": [0.0, 1.0]})
    with pytest.raises(ValueError, match=r"does not give the actor's 13 finite values"):
        load_policy(tmp_path / "grid.npz")
    write_npz(tmp_path / "list.npz", arrays, [1, 2])
    with pytest.raises(ValueError, match=r"__metadata__ is a JSON list, not an object"):
        load_policy(tmp_path / "list.npz")
    # the untouched file still loads, and a file written without metadata reads back as {}
    assert load_policy(UNGM_ADAPTIVE, "ungm-ukf").grid.size == 13
    write_npz(tmp_path / "bare.npz", {"a": np.arange(2)})
    a, m = read_npz(tmp_path / "bare.npz")
    assert m == {} and a["a"].tolist() == [0, 1]


# ------------------------------------------------------------------ gamma
@pytest.mark.parametrize("gamma", [1.5, 1.0, -0.1, float("nan"), "0.5"])
def test_train_rejects_a_gamma_outside_0_1(gamma):
    with pytest.raises(ValueError, match=r"gamma must be a discount in \[0, 1\), got"):
        af.actor_critic.train("ungm-ukf", gamma=gamma, episodes=1, progress=False)


# ------------------------------------------------------------------- NEES
def _nees_case(nx: int, rng):
    M, T = 3, 4
    x = rng.standard_normal((M, T, nx))
    mean = np.zeros_like(x)
    G = rng.standard_normal((M, T, nx, nx))
    cov = G @ G.transpose(0, 1, 3, 2) + np.eye(nx)
    return x, mean, cov


@pytest.mark.parametrize("nx", [1, 2, 4])
def test_nees_rejects_a_covariance_that_is_not_positive_definite(nx):
    x, mean, cov = _nees_case(nx, np.random.default_rng(nx))
    bad = cov.copy()
    bad[2, 1] *= -1.0  # negative definite
    bad[1, 3] *= -1.0  # the first bad one in (run, step) order
    with pytest.raises(ValueError, match=r"covariance P is not positive definite at run 1, step 3 \(and 1 more"):
        metrics.nees(x, mean, bad)
    with pytest.raises(ValueError, match=r"not positive definite at run 1, step 3"):
        metrics.anees(x, mean, bad)
    # explicit opt-ins; references by np.linalg.inv, independent of the Cholesky path
    ref = np.einsum("mti,mtij,mtj->mt", x - mean, np.linalg.inv(bad), x - mean)
    nan = metrics.nees(x, mean, bad, on_indefinite="nan")
    assert np.isnan(nan).sum() == 2 and np.isnan(nan[1, 3]) and np.isnan(nan[2, 1])
    ok = ~np.isnan(nan)
    np.testing.assert_allclose(nan[ok], ref[ok], rtol=1e-10)
    np.testing.assert_allclose(metrics.nees(x, mean, bad, on_indefinite="solve"), ref, rtol=1e-10)
    assert metrics.nees(x, mean, bad, on_indefinite="solve")[2, 1] < 0  # e^T P^-1 e of a negative P
    # singular and non-finite covariances
    sing = bad.copy()
    sing[0, 2] = 0.0
    with pytest.raises(ValueError, match=r"covariance P is singular at run 0, step 2"):
        metrics.nees(x, mean, sing, on_indefinite="solve")
    nonfinite = cov.copy()
    nonfinite[2, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match=r"covariance P is not finite at run 2, step 0"):
        metrics.nees(x, mean, nonfinite)
    with pytest.raises(ValueError, match="on_indefinite must be 'raise', 'nan', 'solve' or 'inf', got 'clip'"):
        metrics.nees(x, mean, cov, on_indefinite="clip")


def test_filters_return_positive_definite_covariances_or_name_the_step():
    """A SIF with one iteration makes some P_filt indefinite on the CTM: with on_indefinite="clip" the
    filter repairs (and counts) them before returning, so every stored covariance has a NEES; with
    "raise" it is a FilterError naming P_filt and the step. A hand-made indefinite covariance is refused."""
    exp = af.experiment_registry.get_experiment("ctm-sif-nis")
    model = exp.make_model()
    traj = model.simulate(300, n_steps=60, rng=np.random.default_rng(0))
    run = af.SIF(model, n_iter=1, seed=0, on_indefinite="clip").run(traj.z)
    assert run.n_repairs > 0
    assert np.isfinite(metrics.nees(traj.x, run.mean, run.cov)).all()
    assert np.all(np.linalg.eigvalsh(run.cov) > 0)
    with pytest.raises(af.FilterError, match=r"not positive definite at step t=\d+"):
        af.SIF(model, n_iter=1, seed=0).run(traj.z)
    bad = run.cov.copy()
    bad[3, 7] = -np.eye(4)
    with pytest.raises(ValueError, match=r"not positive definite at run 3, step 7"):
        metrics.nees(traj.x, run.mean, bad)
    env = exp.make_env(n_steps=60)
    res = evaluate(env, [af.policies.FixedPolicy(1.0, "n_iter", grid=exp.grid)], traj=traj, progress=False)
    p = res["fixed-n_iter=1"]
    assert p.n_repairs > 0 and np.isfinite(p.anees) and np.isfinite(p.anees_t).all()


# ------------------------------------------------------------------ names
def test_learned_names_keep_data_names_and_tell_same_stems_apart(tmp_path):
    kinds = ["adaptive-s0", "myopic-s0", "adaptive-s1", "myopic-s7"]
    files = [POLICIES / f"ungm-ukf-{k}.npz" for k in kinds]
    assert learned_names(files, "ungm-ukf") == kinds
    assert [learned_name(f, "ungm-ukf") for f in files] == kinds
    assert learned_name("runs/try3.npz", "ungm-ukf") == "try3"
    assert learned_name("runs/ctm-ukf-adaptive.npz", "ungm-ukf") == "ctm-ukf-adaptive"
    assert learned_name("ungm-ukf.npz", "ungm-ukf") == "ungm-ukf"
    a, b = tmp_path / "a" / "ungm-ukf-adaptive.npz", tmp_path / "b" / "adaptive.npz"
    assert learned_names([a, b, files[1]], "ungm-ukf") == ["a/adaptive", "b/adaptive", "myopic-s0"]
    deep = [tmp_path / "r1" / "x" / "p.npz", tmp_path / "r2" / "x" / "p.npz"]
    assert learned_names(deep, "ungm-ukf") == ["r1/x/p", "r2/x/p"]
    same_dir = [tmp_path / "ungm-ukf-p.npz", tmp_path / "p.npz"]
    assert learned_names(same_dir, "ungm-ukf") == [str(same_dir[0]), str(same_dir[1])]
    with pytest.raises(ValueError, match="is given twice"):
        learned_names([a, tmp_path / "a" / ".." / "a" / "ungm-ukf-adaptive.npz"], "ungm-ukf")


def test_evaluate_two_files_of_the_same_kind(tmp_path):
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        shutil.copy(UNGM_ADAPTIVE, tmp_path / d / UNGM_ADAPTIVE.name)
    mine = tmp_path / "mine.npz"
    shutil.copy(POLICIES / "ungm-ukf-myopic-s0.npz", mine)
    files = [tmp_path / "a" / UNGM_ADAPTIVE.name, tmp_path / "b" / UNGM_ADAPTIVE.name, mine]
    res = evaluate_experiment("ungm-ukf", n_runs=2, out_dir=tmp_path / "out", policy_files=files,
                              progress=False, figures=False, quiet=True)
    assert res.names[-3:] == ["a/adaptive-s0", "b/adaptive-s0", "mine"]
    assert res["a/adaptive-s0"].rmse == res["b/adaptive-s0"].rmse  # the same policy on the same trajectories
    assert json.loads((tmp_path / "out" / "results.json").read_text())["order"][-1] == "mine"
    shutil.copy(UNGM_ADAPTIVE, tmp_path / "greedy.npz")
    with pytest.raises(ValueError, match=r"greedy\.npz would be named 'greedy', which is reserved for a baseline"):
        evaluate_experiment("ungm-ukf", n_runs=2, out_dir=tmp_path / "o2", policy_files=[tmp_path / "greedy.npz"],
                            progress=False, figures=False, quiet=True)


# -------------------------------------------------------------------- CLI
OUT = "--out"


@pytest.mark.parametrize("args, expect", [
    ([], "the following arguments are required: cmd"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
    (["evaluate", "nope", OUT, "{tmp}/o"], "argument name: unknown experiment 'nope'; known: ungm-ukf, ctm-ukf"),
    (["train", "nope", OUT, "{tmp}/p.npz"], "unknown experiment 'nope'"),
    (["evaluate", "ungm-ukf", "--runs", "0", OUT, "{tmp}/o"], "argument --runs: must be an integer >= 2"),
    (["evaluate", "ungm-ukf", "--runs", "-5", OUT, "{tmp}/o"], "argument --runs: must be an integer >= 2"),
    (["evaluate", "ungm-ukf", "--runs", "1", OUT, "{tmp}/o"], "the bootstrap needs two runs"),
    (["evaluate", "ungm-ukf", "--runs", "ten", OUT, "{tmp}/o"], "argument --runs: expected an integer, got 'ten'"),
    (["evaluate", "ungm-ukf", "--seed", "-1", OUT, "{tmp}/o"], "argument --seed: must be an integer >= 0"),
    (["evaluate", "ungm-ukf", OUT, "{tmp}/afile/o"], "{tmp}/afile is not a folder"),
    (["evaluate", "ungm-ukf", OUT, "{tmp}/afile"], "{tmp}/afile: exists and is not a folder"),
    (["evaluate", "ungm-ukf", OUT, "{tmp}/o", "--policy", "{tmp}/missing.npz"],
     "argument --policy: {tmp}/missing.npz: no such file"),
    (["evaluate", "ungm-ukf", OUT, "{tmp}/o", "--policy", "{tmp}"], "argument --policy: {tmp}: not a file"),
    (["evaluate", "ungm-ukf"], "the following arguments are required: --out"),
    (["train", "ungm-ukf", "--episodes", "0", OUT, "{tmp}/p.npz"], "argument --episodes: must be an integer >= 1"),
    (["train", "ungm-ukf", "--episodes", "-1", OUT, "{tmp}/p.npz"], "argument --episodes: must be an integer >= 1"),
    (["train", "ungm-ukf", "--parallel", "0", OUT, "{tmp}/p.npz"], "argument --parallel: must be an integer >= 1"),
    (["train", "ungm-ukf", "--gamma", "1.5", OUT, "{tmp}/p.npz"], r"argument --gamma: the discount gamma must be in [0, 1)"),
    (["train", "ungm-ukf", "--gamma", "1", OUT, "{tmp}/p.npz"], "must be in [0, 1), got 1"),
    (["train", "ungm-ukf", "--gamma", "-0.5", OUT, "{tmp}/p.npz"], "must be in [0, 1), got -0.5"),
    (["train", "ungm-ukf", "--gamma", "nan", OUT, "{tmp}/p.npz"], "must be in [0, 1), got nan"),
    (["train", "ungm-ukf", OUT, "{tmp}"], "argument --out: {tmp}: is a folder, expected a file name"),
    (["train", "ungm-ukf", OUT, "{tmp}/afile/p.npz"], "{tmp}/afile is not a folder"),
    (["train", "ungm-ukf", "--actions", "1,x", OUT, "{tmp}/p.npz"], "argument --actions: expected comma-separated numbers"),
    (["train", "ungm-ukf", "--actions", "1,inf", OUT, "{tmp}/p.npz"], "argument --actions: expected finite numbers"),
    (["train", "ungm-ukf", "--cost-transform", "sqrt", OUT, "{tmp}/p.npz"], "argument --cost-transform: invalid choice"),
    (["reproduce", OUT, "{tmp}", "--scale", "huge"], "argument --scale: invalid choice"),
    (["beyond", OUT, "{tmp}", "--studies", "cand,tail"], "subset of cand,sif,ood,raw,anchor,look"),
    (["reproduce", OUT, "{tmp}/afile"], "exists and is not a folder"),
    (["book", OUT, "{tmp}/afile/book"], "{tmp}/afile is not a folder"),
])
def test_cli_usage_errors_are_one_line(capsys, tmp_path, args, expect):
    (tmp_path / "afile").write_text("x")
    line = cli_error(capsys, [a.replace("{tmp}", str(tmp_path)) for a in args])
    assert expect.replace("{tmp}", str(tmp_path)) in line, line


def test_cli_library_errors_are_one_line(capsys, tmp_path):
    for name, (path, why) in bad_files(tmp_path).items():
        line = cli_error(capsys, ["evaluate", "ungm-ukf", "--runs", "2", OUT, str(tmp_path / "o"), "--no-progress",
                                  "--policy", str(path)])
        assert f"{path}: not an adaptfilt policy file (" in line and why in line, line
    # a policy of another experiment
    line = cli_error(capsys, ["evaluate", "ungm-ukf", "--runs", "2", OUT, str(tmp_path / "o"), "--no-progress",
                              "--policy", str(POLICIES / "ctm-ukf-adaptive-s0.npz")])
    assert "mismatch in experiment: the file was trained for experiment = 'ctm-ukf'" in line
    line = cli_error(capsys, ["evaluate", "ungm-ukf", "--runs", "2", OUT, str(tmp_path / "o"), "--no-progress",
                              "--policy", str(UNGM_ADAPTIVE), "--policy", str(UNGM_ADAPTIVE)])
    assert "is given twice" in line
    # a resume checkpoint that another training wrote
    out = tmp_path / "p.npz"
    write_npz(tmp_path / "p.ckpt.npz", {"a": np.zeros(1)}, {"config": {"gamma": 0.0}, "episode": 1})
    line = cli_error(capsys, ["train", "ungm-ukf", "--episodes", "1", OUT, str(out), "--resume", "--no-progress"])
    assert "was written by a different training" in line
    # a restricted grid with a value off the experiment's grid, and with the faithful trainer
    line = cli_error(capsys, ["train", "ctm-sif-nis", "--algo", "fast", "--actions", "4,10", OUT, str(out), "--no-progress"])
    assert "actions must be values of the ctm-sif-nis grid" in line and "not on it: [4.0]" in line
    line = cli_error(capsys, ["train", "ctm-sif-nis", "--actions", "5,10", OUT, str(out), "--no-progress"])
    assert "needs an SB3 trainer" in line
    assert not (tmp_path / "o").exists() and not out.exists()  # nothing was written before the error


def _wrong_contexts(tmp_path: Path) -> dict[str, tuple[list[str], str]]:
    """Each sub-command where it cannot work: args, and what its one line must say."""
    full = tmp_path / "not-a-book"
    full.mkdir()
    (full / "notes.txt").write_text("mine")
    for s in (0, 1):  # resume checkpoints another training wrote: the jobs fail in their workers
        write_npz(tmp_path / f"p-s{s}.ckpt.npz", {"a": np.zeros(1)}, {"config": {"gamma": 0.0}, "episode": 1})
    out, p = str(tmp_path / "o"), str(tmp_path / "p.npz")
    return {
        "experiments": (["experiments", "ungm-ukf"], "unrecognized arguments: ungm-ukf"),
        "evaluate": (["evaluate", "ungm-ukf", "--runs", "10", OUT, out, "--no-progress", "--policy",
                      str(POLICIES / "ctm-ukf-adaptive-s0.npz")], "ctm-ukf-adaptive-s0.npz"),
        "train --cluster": (["train", "ungm-ukf", "--algo", "fast", "--episodes", "1", "--seeds", "0-1", "--cluster",
                             "tcp://127.0.0.1:1", "--no-progress", OUT, p], "Timed out trying to connect to tcp://127.0.0.1:1"),
        "train, failing in the pool": (["train", "ungm-ukf", "--episodes", "1", "--seeds", "0-1", "--workers", "2",
                                        "--resume", "--no-progress", OUT, p], "was written by a different training"),
        "reproduce --data": (["reproduce", OUT, out, "--data", str(tmp_path)],
                             f"--data {tmp_path}: no manifest.json there"),
        "reproduce --cluster": (["reproduce", OUT, out, "--quick", "--retrain", "--no-progress", "--cluster", "nonsense"],
                                "missing port number in address 'nonsense'"),
        "beyond --cluster": (["beyond", OUT, out, "--quick", "--studies", "cand", "--no-progress", "--cluster",
                              "tcp://127.0.0.1:1"],  # distributed's timeout, or its IO loop failing to start
                             ("Timed out trying to connect", "could not connect to the Dask scheduler at tcp://127.0.0.1:1")),
        "book": (["book", OUT, str(full)], "is a non-empty directory that is not a built book"),
    }


def test_every_subcommand_in_a_wrong_context_is_one_line(capsys, tmp_path):
    """Errors raised deep inside -- a pool job, a Dask client, the book builder -- are one line too."""
    pytest.importorskip("distributed")  # first: it adds its defaults to dask's config, which set() then keeps
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        for name, (args, expect) in _wrong_contexts(tmp_path).items():
            line = cli_error(capsys, args)
            assert any(e in line for e in (expect if isinstance(expect, tuple) else (expect,))), (name, line)
    assert (tmp_path / "not-a-book" / "notes.txt").read_text() == "mine"


def test_a_bug_in_a_job_keeps_its_traceback(monkeypatch, tmp_path):
    import adaptfilt.cli as cli
    from adaptfilt.experiments.sweep import JobFailed

    def broken(args, seed, out):
        raise ZeroDivisionError("a genuine bug")

    monkeypatch.setattr(cli, "train_job", broken)
    with pytest.raises(JobFailed, match="a genuine bug") as e:
        main(["train", "ungm-ukf", "--seeds", "0-1", "--workers", "1", OUT, str(tmp_path / "p.npz")])
    assert isinstance(e.value.__cause__, ZeroDivisionError)


def test_cli_bug_keeps_its_traceback(monkeypatch):
    def broken():
        raise ZeroDivisionError("a genuine bug")

    monkeypatch.setattr(af.experiment_registry, "describe_experiments", broken)
    with pytest.raises(ZeroDivisionError, match="a genuine bug"):
        main(["experiments"])


def test_python_m_adaptfilt_prints_one_line_and_exits_2(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"not a policy at all")
    for args, expect in [
        (["train", "ungm-ukf", "--gamma", "1.5", OUT, str(tmp_path / "p.npz")], "--gamma"),
        (["evaluate", "ungm-ukf", "--runs", "2", OUT, str(tmp_path / "o"), "--no-progress",
          "--policy", str(tmp_path / "junk.npz")], "junk.npz: not an adaptfilt policy file (not a zip/npz archive)"),
    ]:
        p = subprocess.run([sys.executable, "-m", "adaptfilt", *args], capture_output=True, text=True, cwd=ROOT,
                           timeout=120)
        assert p.returncode == 2, p.stderr
        assert p.stderr.count("\n") == 1 and p.stderr.startswith("adaptfilt: error: ") and expect in p.stderr
        assert "Traceback" not in p.stderr and p.stdout == ""
