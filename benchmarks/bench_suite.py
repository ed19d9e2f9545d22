"""The README's test command against the clock (the target: at most 15 minutes on 2 cores).

    python benchmarks/bench_suite.py [--target 900] [--top 15] [-- PYTEST ARGS]

Runs ``python3 -m pytest`` (the README's command; pytest-xdist's ``-n auto --dist loadfile`` from
pyproject.toml) with a JUnit XML report in a temporary folder, then prints

* the wall time of the whole run against the target, and the CPU time of pytest and every process
  it waited for (workers, notebook kernels, command-line runs, the browser);
* the time of each test file (a notebook is one file), largest first: with ``--dist loadfile`` a file
  runs whole on one worker, so the largest file bounds the run from below, and so does the sum of
  all files over the number of workers (both printed, with the slack of the run above them).

Arguments after ``--`` go to pytest (``-- tests/test_rules.py`` times one file; ``-- -n 0``
runs serially). Wall times depend on the machine and its load: run it on an otherwise idle machine.
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def file_times(junit: Path) -> dict[str, float]:
    """Seconds per test file (setup, call and teardown of its tests) from a JUnit XML report."""
    per = defaultdict(float)
    for case in ET.parse(junit).getroot().iter("testcase"):
        cls = case.get("classname", "")
        # tests: "tests.test_rules"; notebooks: "notebooks.09-ukf-ungm.ipynb"
        name = cls.replace(".", "/") + ".py" if not cls.endswith(".ipynb") else cls.replace(".", "/", 1)
        per[case.get("file") or name] += float(case.get("time", 0.0))
    return dict(per)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--target", type=float, default=900.0, help="seconds (default: 15 minutes)")
    p.add_argument("--top", type=int, default=15, help="files to list")
    args = p.parse_args(argv[:argv.index("--")] if "--" in argv else argv)
    workers = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        junit = Path(tmp) / "junit.xml"
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={junit}", *extra]
        print("+", " ".join(cmd), flush=True)
        t0 = time.perf_counter()
        rc = subprocess.run(cmd, cwd=ROOT).returncode
        wall = time.perf_counter() - t0
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        per = file_times(junit) if junit.exists() else {}
    total = sum(per.values())
    print(f"\nsuite: {wall:.0f} s wall (target {args.target:.0f} s: {'met' if wall <= args.target else 'NOT met'}), "
          f"{ru.ru_utime + ru.ru_stime:.0f} CPU-s, pytest exit {rc}; {os.cpu_count()} cores")
    if per:
        big = max(per.values())
        print(f"test files: {len(per)}, {total:.0f} s in all; lower bounds on the wall time: the largest file "
              f"{big:.0f} s, all files over {workers} workers {total / workers:.0f} s")
        for name, s in sorted(per.items(), key=lambda kv: -kv[1])[: args.top]:
            print(f"{s:8.1f} s  {name}")
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
