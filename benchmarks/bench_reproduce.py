"""The whole seed-level reproduction against the clock: stage table, the 15-minute target, determinism.

    python benchmarks/bench_reproduce.py [--scale medium] [--out DIR] [--compare DIR2] [--workers N]

Runs ``adaptfilt reproduce --out DIR --scale SCALE --retrain`` (default: the medium scale, into a
temporary folder), then prints

* the stage table (wall and CPU time of train, evaluate, floor + reconcile, report) and whether
  the total wall time is within the target of the multi-seed issue, 15 minutes on this machine;
* how many of its seed-level verdicts are those of the full-scale reproduction in ``data/``;
* with ``--compare DIR2`` (an earlier run of the same command): which policy and result files differ
  byte for byte (the target: none; the JSON files of the floor, the reconciliation and the
  fast-vs-faithful comparison record their own times and are compared without them).

The medium scale takes about 11 minutes on 2 idle cores, the full scale about 31. Absolute times
depend on the machine and its load: run it on an otherwise idle machine.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

TARGET_S = 15 * 60
TIMED = ("results/ungm-floor.json", "results/ctm-reconciliation.json", "results/fast-vs-faithful.json")


def _untimed(o):
    if isinstance(o, dict):
        return {k: _untimed(v) for k, v in o.items() if "time" not in k}
    return [_untimed(v) for v in o] if isinstance(o, list) else o


def differing(a: Path, b: Path) -> list[str]:
    """Policy and result files of ``b`` that are not byte-identical to ``a``'s (timed JSONs without their times)."""
    from adaptfilt.experiments.reproduce import sha256

    out = []
    for p in sorted(b.rglob("*")):
        rel = p.relative_to(b).as_posix()
        if not p.is_file() or not rel.startswith(("policies/", "results/")) or rel == "results/agreement.json":
            continue
        q = a / rel
        if not q.exists():
            out.append(rel + " (missing in the other run)")
        elif rel in TIMED:
            if _untimed(json.loads(p.read_text())) != _untimed(json.loads(q.read_text())):
                out.append(rel)
        elif sha256(p) != sha256(q):
            out.append(rel)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", choices=("quick", "medium", "full"), default="medium")
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: a temporary one)")
    ap.add_argument("--compare", type=Path, default=None, help="an earlier run of the same command")
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args()
    from adaptfilt.experiments.report import timings_md
    from adaptfilt.experiments.reproduce import reproduce

    out = args.out or Path(tempfile.mkdtemp(prefix=f"reproduce-{args.scale}-"))
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    r = reproduce(out, scale=args.scale, retrain=True, progress=True, workers=args.workers)
    wall = time.perf_counter() - t0
    print(f"\nadaptfilt reproduce --out {out} --scale {args.scale} --retrain ({os.cpu_count()} cores, "
          f"load average at the start {load:.2f})\n")
    print(timings_md(r["timings"]))
    print(f"total {wall:.0f} s wall ({wall / 60:.1f} min): {'within' if wall <= TARGET_S else 'OVER'} the "
          f"{TARGET_S // 60}-minute target")
    agr = out / "results/agreement.json"
    if agr.exists():
        a = json.loads(agr.read_text())
        print(f"verdicts: {a['n_same']} of {a['n']} seed-level comparisons as at full scale (data/)")
    if args.compare is not None:
        diff = differing(args.compare, out)
        print(f"against {args.compare}: " + ("every policy and result file identical" if not diff
                                             else f"{len(diff)} files differ: " + ", ".join(diff)))


if __name__ == "__main__":
    main()
