"""The README's examples run as written, and its commands match CI."""
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README, flags=re.S)


def test_readme_has_both_fresh_machine_commands():
    bash = re.findall(r"```bash\n(.*?)```", README, flags=re.S)
    assert len(bash) >= 2
    assert any("adaptfilt book" in b and "torch==2.13.0" in b for b in bash), "main job command missing"
    test_cmd = [b.strip() for b in bash if "pytest" in b]
    assert test_cmd, "test command missing"
    ci = (ROOT / ".ci" / "run").read_text()
    # CI runs exactly the README's test command (after its own install steps)
    pytest_part = test_cmd[0].split("&&")[-1].strip()
    assert pytest_part in ci


def test_readme_first_example_runs_as_written():
    ns: dict = {}
    exec(compile(_python_blocks()[0], "README-example-1", "exec"), ns)
    run, traj = ns["run"], ns["traj"]
    assert run.mean.shape == (1000, 100, 1) and run.cov.shape == (1000, 100, 1, 1)
    assert np.isfinite(run.mean).all()
    # the UKF must do better than ignoring the measurements (prior-only prediction)
    assert ns["af"].metrics.rmse(traj.x, run.mean).mean() < traj.x.std()


def test_readme_adaptation_example_runs_as_written():
    """The own-model example trains with the fast mode and gives the comparison the README reads from it:
    the learned policies far below the default on their cost, and above it on RMSE."""
    pytest.importorskip("stable_baselines3")
    ns: dict = {}
    src = _python_blocks()[0] + "\n" + _python_blocks()[1]
    exec(compile(src, "README-example-2", "exec"), ns)
    adaptive, res = ns["adaptive"], ns["res"]
    assert adaptive.mean.shape == (1000, 100, 1)
    assert set(np.unique(adaptive.params)) <= {0.0, 1.0, 2.0, 5.0, 10.0, 50.0}
    assert {"default", "greedy", "ml", "fast-s0", "fast-s1"} <= set(res.names) and res.config["n_runs"] == 2000
    for name in ("fast-s0", "fast-s1", "greedy"):
        assert res[name].cost < res["default"].cost / 5 and res[name].rmse > res["default"].rmse, name


def test_readme_sb3_example_trains_and_evaluates_ppo():
    pytest.importorskip("stable_baselines3")
    block = next(b for b in _python_blocks() if "stable_baselines3" in b)
    ns: dict = {}
    exec(compile(block, "README-example-sb3", "exec"), ns)
    res = ns["res"]
    assert "ppo" in res and "greedy" in res and res.config["n_runs"] == 1000
    assert np.isfinite(res["ppo"].rmse) and res["ppo"].rmse < res["default"].rmse


def test_readme_links_only_to_files_of_the_repository():
    """The architecture and decisions live in the repository, not in a development workspace."""
    targets = re.findall(r"\]\(([^)#\s]+)", README)
    local = [t for t in targets if "://" not in t]
    assert "docs/ARCHITECTURE.md" in local and "../shared" not in README
    assert all((ROOT / t).exists() for t in local), [t for t in local if not (ROOT / t).exists()]


def test_particle_count_example_runs_and_kld_uses_fewer_particles_than_the_default():
    block = next(b for b in _python_blocks() if "ungm-pf-1e-4" in b)
    ns: dict = {}
    exec(compile(block.replace("print(", "(lambda *a: None)("), "README-example-particles", "exec"), ns)
    res = ns["res"]
    assert res["default"].spent == 1000
    assert res["kld-x1"].spent < res["default"].spent  # what the example is there to show: KLD adapts the count


def test_the_command_line_block_lists_every_command_and_every_study():
    """The README's command-line block shows each sub-command of ``adaptfilt`` and the ``beyond`` line every
    study (``adaptfilt beyond --help`` lists them from the same table)."""
    from adaptfilt.cli import build_parser
    from adaptfilt.experiments.beyond import STUDIES

    block = README.split("## The command line", 1)[1].split("```", 2)[1]
    sub = next(a for a in build_parser()._actions if a.dest == "cmd")
    for name in sub.choices:
        assert f"adaptfilt {name} " in block, name
    assert "adaptfilt --version" in block
    line = next(ln for ln in block.splitlines() if ln.startswith("adaptfilt beyond"))
    assert f"--studies {','.join(STUDIES)}]" in line


def test_filters_example_runs_and_pairs_the_particle_filter_with_the_policies():
    block = next(b for b in _python_blocks() if "filters=" in b)
    ns: dict = {}
    exec(compile(block.replace("print(", "(lambda *a: None)("), "README-example-filters", "exec"), ns)
    res = ns["res"]
    assert res.names == ["default", "greedy", "bpf-500"] and res.config["filters"]["bpf-500"].startswith("Bootstrap")
    d, lo, hi = res.paired_difference("bpf-500", "default", "rmse")
    assert hi < 0 and np.isnan(res["bpf-500"].cost) and np.isfinite(res["bpf-500"].anees)
