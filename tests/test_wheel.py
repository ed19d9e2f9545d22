"""The package as a user installs it from a wheel, outside the checkout.

The wheel is built from a copy of the sources with setuptools' PEP 517 backend (what ``pip wheel`` and
``python -m build`` call), installed without dependencies into a fresh virtual environment that sees
the packages of the interpreter running the tests (numpy, torch, ... : nothing is downloaded; a
system interpreter or a virtual environment alike), and run from a folder of its own
with no PYTHONPATH, so that neither the checkout nor an editable install of it can be imported. There:
the README's library example runs, every module imports, and the commands that need the checkout or
its stored artefacts say so in one line (``reproduce`` and ``beyond`` without ``--data``, ``book``),
while ``reproduce --data`` with the checkout's ``data/`` works.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from adaptfilt.course.quoted_times import check_phrase

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.wheel


@pytest.fixture(scope="module")
def venv(tmp_path_factory) -> dict:
    """A virtual environment with the built wheel installed; ``{"python", "adaptfilt", "env", "cwd"}``."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    shutil.copytree(ROOT / "adaptfilt", src / "adaptfilt", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "ADAPTFILT_DATA", "VIRTUAL_ENV")}
    build = subprocess.run([sys.executable, "-c", "import sys; from setuptools import build_meta as b; "
                            "print(b.build_wheel(sys.argv[1]))", str(tmp / "dist")],
                           cwd=src, env=env, capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stderr[-3000:]
    wheel = tmp / "dist" / build.stdout.split()[-1]
    assert wheel.name.startswith("adaptfilt-") and wheel.suffix == ".whl"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(tmp / "venv")], check=True, env=env, timeout=120)
    python = tmp / "venv" / "bin" / "python"
    # The new environment sees the packages of the interpreter that runs pytest, as plain path entries.
    # Not `venv --system-site-packages`: inside a virtual environment that gives the *base* interpreter's
    # site-packages, which lack what the running environment installed (torch, ...). Plain entries also
    # keep the running environment's .pth files unread, so an editable install of the checkout stays out.
    site_dirs = json.loads(subprocess.run(
        [sys.executable, "-c", "import json, site; print(json.dumps(site.getsitepackages()"
                               " + ([site.getusersitepackages()] if site.ENABLE_USER_SITE else [])))"],
        cwd=tmp, env=env, capture_output=True, text=True, check=True, timeout=60).stdout)
    own = json.loads(subprocess.run([str(python), "-c", "import json, site; print(json.dumps(site.getsitepackages()))"],
                                    cwd=tmp, env=env, capture_output=True, text=True, check=True, timeout=60).stdout)[0]
    outer = [d for d in site_dirs if Path(d).is_dir() and ROOT not in Path(d).resolve().parents]
    (Path(own) / "outer-site.pth").write_text("".join(f"{d}\n" for d in outer))
    install = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps",
                              "--no-build-isolation", "--no-index", str(wheel)],
                             env=env, capture_output=True, text=True, timeout=300)
    assert install.returncode == 0, install.stderr[-3000:]
    cwd = tmp / "elsewhere"
    cwd.mkdir()
    return {"python": str(python), "adaptfilt": str(python.parent / "adaptfilt"), "env": env, "cwd": cwd}


def _run(venv: dict, args: list[str], timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=venv["cwd"], env=venv["env"], capture_output=True, text=True, timeout=timeout)


def test_the_installed_package_is_the_wheel_not_the_checkout(venv):
    p = _run(venv, [venv["python"], "-c", "import adaptfilt; print(adaptfilt.__file__)"])
    where = Path(p.stdout.strip())
    assert p.returncode == 0 and "site-packages" in where.parts, p.stderr
    assert Path(venv["python"]).parents[1] in where.parents and ROOT not in where.parents


def test_readme_library_example_and_every_module_run_from_the_wheel(venv):
    block = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)[0]
    check = block + (
        "\nimport importlib, pkgutil, adaptfilt\n"
        "names = [m.name for m in pkgutil.walk_packages(adaptfilt.__path__, 'adaptfilt.') if m.name != 'adaptfilt.__main__']\n"
        "for n in names:\n    importlib.import_module(n)\n"
        "print(len(names), float(af.metrics.rmse(traj.x, run.mean).mean()), float(traj.x.std()))\n")
    p = _run(venv, [venv["python"], "-c", check])
    assert p.returncode == 0, p.stderr[-3000:]
    n, rmse, spread = p.stdout.split()[-3:]
    assert int(n) > 30 and float(rmse) < float(spread)  # every module; the UKF beats ignoring the data


def _one_line_error(p: subprocess.CompletedProcess) -> str:
    assert p.returncode == 2 and p.stdout == "", (p.returncode, p.stdout, p.stderr)
    assert p.stderr.count("\n") == 1 and p.stderr.startswith("adaptfilt: error: "), p.stderr
    return p.stderr


def test_commands_that_need_the_checkout_say_so_in_one_line(venv):
    out = venv["cwd"] / "out"
    err = _one_line_error(_run(venv, [venv["adaptfilt"], "reproduce", "--out", str(out)]))
    assert "no --data DIR given, $ADAPTFILT_DATA not set" in err and "site-packages" in err
    assert "--retrain" in err
    # what --retrain costs, as data/retrain/timings.json (which the installed package cannot read) records it
    cost = re.search(r"\((about \d+ minutes on 2 cores)\)", err)
    assert cost, err
    why = check_phrase(cost.group(1), "wall of data/retrain/timings.json:total", ROOT)
    assert why is None, why
    err = _one_line_error(_run(venv, [venv["adaptfilt"], "beyond", "--out", str(out)]))
    assert "no stored artefacts" in err and "--data" in err
    err = _one_line_error(_run(venv, [venv["adaptfilt"], "reproduce", "--out", str(out), "--data", str(out)]))
    assert f"--data {out}: no manifest.json there" in err
    err = _one_line_error(_run(venv, [venv["adaptfilt"], "book", "--out", str(venv["cwd"] / "book")]))
    assert "book.toml" in err and "checkout" in err
    assert not out.exists() and not (venv["cwd"] / "book").exists()  # nothing written before the errors


def test_reproduce_with_data_reuses_the_stored_artefacts(venv):
    out = venv["cwd"] / "reproduced"
    p = _run(venv, [venv["adaptfilt"], "reproduce", "--out", str(out), "--data", str(ROOT / "data")])
    assert p.returncode == 0, p.stderr[-3000:]
    assert "[train] 0 policies to train" in p.stdout and f"stored artefacts: {ROOT / 'data'}" in p.stdout
    stored = {e["path"]: e["sha256"] for e in json.loads((ROOT / "data" / "manifest.json").read_text())["files"]}
    made = {e["path"]: e["sha256"] for e in json.loads((out / "manifest.json").read_text())["files"]}
    policies = [k for k in stored if k.startswith("policies/")]
    assert len(policies) >= 80 and all(made[k] == stored[k] for k in policies)
    assert len(list((out / "figures").glob("*.png"))) >= 6
