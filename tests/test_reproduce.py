"""Issue 5: the committed artefacts in data/ and the reproduction pipeline."""
from __future__ import annotations

import json
import re
import shlex

import numpy as np
import pytest

from adaptfilt import artefacts
from adaptfilt.evaluation import Results
from adaptfilt.experiments import EXPERIMENTS
from adaptfilt.reproduce import reproduce, sha256

DATA = artefacts.data_dir()


def test_data_manifest_files_exist_match_and_load():
    man = artefacts.manifest()
    files = {e["path"]: e for e in man["files"]}
    assert man["package_version"]
    for e in EXPERIMENTS:
        for kind in ("adaptive", "myopic"):
            assert f"policies/{e}-{kind}.npz" in files
        assert f"results/{e}/results.npz" in files
    for rel in ("results/ungm-floor.json", "results/table1.json", "results/table1.md",
                "results/ctm-reconciliation.json"):
        assert rel in files
    for e in man["files"]:
        assert {"path", "sha256", "command", "seed", "version", "wall_time_s"} <= set(e)
        assert sha256(DATA / e["path"]) == e["sha256"], e["path"]
    checked = artefacts.verify()  # loads every policy against its experiment and every Results
    assert len(checked) == len(man["files"])
    for e in EXPERIMENTS:
        res = artefacts.load_results(e)
        assert isinstance(res, Results) and "adaptive" in res and "myopic" in res and "greedy" in res
        assert res.config["n_runs"] == 10_000
        pol = artefacts.load_policy(e, "adaptive")
        assert pol.metadata["episodes"] == 1000
    floor = artefacts.load_floor()
    assert floor["n_steps"] == 500 and floor["rmse_ci"][0] <= floor["rmse"] <= floor["rmse_ci"][1]


def test_data_is_small():
    total = sum(p.stat().st_size for p in DATA.rglob("*") if p.is_file())
    assert total < 20e6


def test_quick_reproduce_writes_everything(tmp_path):
    reproduce(tmp_path, quick=True, retrain=True, progress=False)
    for i, stem in enumerate(["ungm-ukf-rmse", "ungm-ukf-anees", "ungm-ukf-rmse-anees", "ctm-ukf-rmse",
                              "ctm-ukf-anees", "ctm-ukf-rmse-anees"], start=1):
        assert (tmp_path / "figures" / f"fig{i}-{stem}.png").stat().st_size > 1000
    for rel in ("results/table1.json", "results/table1.md", "results/claims.json", "results/ungm-floor.json",
                "results/ctm-reconciliation.json", "report-tables.md", "manifest.json", "timings.json"):
        assert (tmp_path / rel).stat().st_size > 0, rel
    t1 = json.loads((tmp_path / "results/table1.json").read_text())
    assert set(t1) == {"ctm-sif-stateinnov", "ctm-sif-logmaxnis", "ctm-sif-nis"}
    for d in t1.values():
        for col in ("adaptive", "fixed", "myopic", "greedy"):
            o = d["ours"][col]
            assert o["rmse_ci"][0] <= o["rmse"] <= o["rmse_ci"][1]
    assert "| C5 |" in (tmp_path / "report-tables.md").read_text()
    # nothing was copied from data/: every policy was trained here at quick scale
    for e in EXPERIMENTS:
        assert artefacts.load_policy(e, "myopic", root=tmp_path).metadata["episodes"] == 20
    assert len(artefacts.verify(tmp_path)) == len(artefacts.manifest(tmp_path)["files"])


def test_retraining_with_recorded_command_is_deterministic(tmp_path):
    from adaptfilt.actor_critic import train_experiment

    entry = next(e for e in artefacts.manifest()["files"] if e["path"] == "policies/ctm-ukf-adaptive.npz")
    argv = shlex.split(entry["command"])
    assert argv[:3] == ["adaptfilt", "train", "ctm-ukf"]
    opt = {argv[i][2:]: argv[i + 1] for i in range(3, len(argv), 2)}
    assert int(opt["seed"]) == entry["seed"]
    B = int(opt["parallel"])
    paths = []
    for tag in ("a", "b"):  # reduced scale: 2 batches of the recorded B, 30 steps
        p = tmp_path / f"{tag}.npz"
        train_experiment("ctm-ukf", out=p, gamma=float(opt["gamma"]), episodes=2 * B, parallel=B,
                         seed=int(opt["seed"]), progress=False, n_steps=30, command=entry["command"])
        paths.append(p)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    from adaptfilt.learned import load_policy

    a, b = (load_policy(p, experiment="ctm-ukf") for p in paths)
    for (ka, va), (kb, vb) in zip(a.actor.state_dict().items(), b.actor.state_dict().items()):
        assert ka == kb and np.array_equal(va.numpy(), vb.numpy())
    assert re.search(r"--episodes 1000 ", entry["command"])
