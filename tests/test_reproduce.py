"""The committed artefacts in data/ and the reproduction pipeline (seed level)."""
from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from adaptfilt import artefacts
from adaptfilt.evaluation import Results
from adaptfilt.experiments import EXPERIMENTS
from adaptfilt.experiments.seeds import seed_groups
from adaptfilt.reproduce import FAITHFUL, KINDS, SEEDS, reproduce, sha256

DATA = artefacts.data_dir()


def test_data_manifest_files_exist_match_and_load():
    man = artefacts.manifest()
    files = {e["path"]: e for e in man["files"]}
    assert man["package_version"] and man["seeds"] == list(SEEDS) and len(SEEDS) >= 8
    for e in EXPERIMENTS:
        for kind in KINDS:
            for s in SEEDS:
                entry = files[f"policies/{e}-{kind}-s{s}.npz"]
                assert f"--seed {s} " in entry["command"] and entry["seed"] == s
        assert f"results/{e}/results.npz" in files
    for kind, (_, exps) in FAITHFUL.items():
        for e in exps:
            for s in artefacts.seeds(e, kind):
                entry = files[f"policies/{e}-{kind}-s{s}.npz"]
                assert "--algo faithful" in entry["command"] and f"--seed {s} " in entry["command"]
                assert entry["seed"] == s
    for rel in ("results/ungm-floor.json", "results/table1.json", "results/table1.md", "results/claims.json",
                "results/ctm-reconciliation.json"):
        assert rel in files
    for e in ("ungm-ukf", "ctm-ukf"):  # the fast-vs-faithful comparison needs 8 faithful seeds of each
        assert artefacts.seeds(e, "adaptive-faithful") == list(SEEDS), e
        assert seed_groups(artefacts.load_results(e).names)["adaptive-faithful"] == [
            f"adaptive-faithful-s{s}" for s in SEEDS]
    assert "results/fast-vs-faithful.json" in files
    for e in man["files"]:
        assert {"path", "sha256", "command", "seed", "version", "wall_time_s"} <= set(e)
        assert sha256(DATA / e["path"]) == e["sha256"], e["path"]
    checked = artefacts.verify()  # loads every policy against its experiment and every Results
    assert len(checked) == len(man["files"])
    for e in EXPERIMENTS:
        res = artefacts.load_results(e)
        assert isinstance(res, Results) and "greedy" in res and res.config["n_runs"] == 10_000
        groups = seed_groups(res.names)
        for kind in KINDS:
            assert groups[kind] == [f"{kind}-s{s}" for s in SEEDS]
        pol = artefacts.load_policy(e, "adaptive", seed=3)
        assert pol.metadata["episodes"] == 1000 and pol.metadata["seed"] == 3
    floor = artefacts.load_floor()
    assert floor["n_steps"] == 500 and floor["rmse_ci"][0] <= floor["rmse"] <= floor["rmse_ci"][1]
    claims = artefacts.load_claims()
    for row in claims["C1"] + claims["C4"]:
        assert row["n_seeds"] == len(SEEDS) and row["verdict"] in (
            "confirmed", "contradicted", "not confirmed (n.s.)")


def test_data_is_small():
    """The reproduction (about 31 MB: 96 policies, five evaluations at M = 10^4) and the studies beyond the
    paper (about 10 MB, stored without per-run arrays) stay small enough to clone."""
    total = sum(p.stat().st_size for p in DATA.rglob("*") if p.is_file())
    beyond = sum(p.stat().st_size for p in (DATA / "beyond").rglob("*") if p.is_file())
    assert total < 45e6 and beyond < 12e6


def _digest(root) -> dict:
    return {str(p.relative_to(root)): sha256(p) for p in sorted(root.rglob("*"))
            if p.is_file() and (p.suffix == ".npz" or p.name in ("results.json", "claims.json", "table1.json"))}


def test_quick_reproduce_writes_everything_and_is_identical_on_one_or_two_workers(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    reproduce(a, quick=True, retrain=True, progress=False, workers=2)
    for i, stem in enumerate(["ungm-ukf-rmse", "ungm-ukf-anees", "ungm-ukf-rmse-anees", "ctm-ukf-rmse",
                              "ctm-ukf-anees", "ctm-ukf-rmse-anees"], start=1):
        assert (a / "figures" / f"fig{i}-{stem}.png").stat().st_size > 1000
    for rel in ("results/table1.json", "results/table1.md", "results/claims.json", "results/ungm-floor.json",
                "results/ctm-reconciliation.json", "report-tables.md", "manifest.json", "timings.json"):
        assert (a / rel).stat().st_size > 0, rel
    t1 = json.loads((a / "results/table1.json").read_text())
    assert set(t1) == {"ctm-sif-stateinnov", "ctm-sif-logmaxnis", "ctm-sif-nis"}
    for d in t1.values():
        for col in ("adaptive", "fixed", "myopic", "greedy"):
            o = d["ours"][col]
            assert o["rmse_ci"][0] <= o["rmse"] <= o["rmse_ci"][1]
        assert d["ours"]["adaptive"]["n_seeds"] == 2
    assert "| C5 |" in (a / "report-tables.md").read_text()
    for e in EXPERIMENTS:  # nothing was copied from data/: every policy was trained here at quick scale
        assert artefacts.load_policy(e, "myopic", seed=1, root=a).metadata["episodes"] == 20
    assert len(artefacts.verify(a)) == len(artefacts.manifest(a)["files"])
    reproduce(b, quick=True, retrain=True, progress=False, workers=1, experiments=("ungm-ukf", "ctm-sif-nis"))
    da, db = _digest(a), _digest(b)
    shared = [k for k in db if k.startswith(("policies/ungm-ukf", "policies/ctm-sif-nis", "results/ungm-ukf/",
                                             "results/ctm-sif-nis/"))]
    assert len(shared) >= 10 and all(da[k] == db[k] for k in shared), [k for k in shared if da[k] != db[k]]


def test_retraining_with_recorded_command_is_deterministic(tmp_path):
    """The recorded command of a stored fast-mode policy, at reduced scale, twice: byte-identical files."""
    from adaptfilt.cli import main

    entry = next(e for e in artefacts.manifest()["files"] if e["path"] == "policies/ctm-ukf-adaptive-s0.npz")
    argv = shlex.split(entry["command"])
    assert argv[:3] == ["adaptfilt", "train", "ctm-ukf"] and "--algo" in argv
    i_ep, i_out = argv.index("--episodes"), argv.index("--out")
    assert argv[i_ep + 1] == "1000"
    out = tmp_path / "p.npz"
    files = []
    for _ in range(2):  # the same command twice (the file records its command, so the same --out)
        args = list(argv[1:])
        args[i_ep] = "40"  # 40 episodes of 30 steps instead of 1000 of 150
        args[i_out] = str(out)
        assert main(args + ["--horizon", "30", "--no-progress"]) == 0
        files.append(out.read_bytes())
    assert files[0] == files[1]
    from adaptfilt.learned import load_policy

    pol = load_policy(out, experiment="ctm-ukf")
    assert np.isfinite(pol.probs(np.zeros((1, pol.scaler.center.size)))).all()


@pytest.mark.parametrize("bad", ["--workers 0", "--cluster"])
def test_reproduce_cli_rejects_bad_engine_flags(bad, capsys):
    from adaptfilt.cli import main

    with pytest.raises(SystemExit) as e:
        main(["reproduce", "--out", "/tmp/never-written", *bad.split()])
    assert e.value.code == 2 and capsys.readouterr().err.startswith("adaptfilt: error:")
