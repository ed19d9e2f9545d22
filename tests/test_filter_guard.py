"""Guard: the evaluations of filters beside policies give the numbers they gave before the filter became a
declared interface.

At quick scale this evaluates what the studies evaluate with filters that no policy tunes, and compares
every array of every result, byte for byte, with ``tests/fixtures/filter_guard.json`` (hashes and
summaries made by main's code before ``adaptfilt.filters`` and ``adaptfilt.runs``: at 4432022, and again
at 1c71d9d, whose ``metrics.percentile_ci`` gives infinite ends where replicates are undefined):

* ``reference``: the learned-gain study's reference part (the bootstrap particle filter on the
  evaluation's runs, the point-mass floor) for both models and both regimes;
* ``gain``: its learned-gain parts: KalmanNet trained at quick scale by the study's recipe (``adaptfilt
  train-gain`` in optimiser steps), its last snapshot evaluated alone (``gain``) and its three snapshots
  together (``curve``);
* ``particles``: the particle study's reference rows (``bpf-N`` at every count of the grid, charged two
  prices) on UNGM and the CTM, and its floor;
* ``floors``: the reproduction's UNGM floor (``references.ungm_floor``) and the course's floor per step.

The ``gain`` fixture changes, legitimately, when KalmanNet's training or the study's recipe changes (what it
learns in six optimiser steps is other weights). Then regenerate it, and only it, with one command, and say why in the commit::

    python tests/test_filter_guard.py --write gain

(``--write`` alone rewrites every case: only for a change that is meant to move the numbers.)

Bit for bit is claimed on the machine, numpy and torch that made the fixture (its ``machine`` record);
elsewhere each array is compared through its summaries (sum, extremes, counts of NaN and infinities) to a
relative tolerance: a particle filter's resampling may take another branch where another CPU's ``exp``
rounds otherwise (``tests/same_numbers.py``).
"""
from __future__ import annotations

import hashlib
import json
import platform
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "filter_guard.json"
CASES = ("reference", "gain", "particles", "floors")
#: Config keys a result may gain without moving a number; every key the fixture holds must be unchanged.
_VOLATILE = ("version", "numpy", "command", "wall_time_s", "cpu_time_s")
#: Relative tolerance off the fixture's machine: deterministic filters, and particle filters (a resampling
#: branch can flip on another CPU's rounding).
RTOL, RTOL_PARTICLES = 1e-6, 5e-2


def machine() -> dict:
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"cpu": cpu, "numpy": np.__version__, "torch": torch.__version__.split("+")[0]}


# ------------------------------------------------------------------ what is evaluated
def _reference() -> dict:
    from adaptfilt.experiments.studies.gain import QUICK, evaluate_part

    return {f"{e} {r}": evaluate_part(e, r, "reference", {}, QUICK)
            for e in ("ungm-ukf", "ctm-ukf") for r in ("nominal", "q4")}


def _gain() -> dict:
    from adaptfilt.experiments.studies.gain import ARCH, QUICK, evaluate_part, knet_recipe
    from adaptfilt.experiments.jobs import GainSpec

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for e, loss, arm, seed in (("ungm-ukf", "supervised", "gain-sup", 0), ("ctm-ukf", "unsupervised", "gain-unsup", 1)):
            k, steps = knet_recipe(e, ARCH[e], QUICK), QUICK.knet_steps[(e, ARCH[e])][:3]
            files = {f"{arm}-b{b}-s{seed}": f"{tmp}/{e}-{arm}-b{b}-s{seed}.npz" for b in (1, 2, 3)}
            GainSpec(e, loss, None, seed, tuple(files.values()), arch={1: "kalmannet-arch1", 2: "kalmannet"}[ARCH[e]],
                     steps=steps[-1], snapshot_steps=steps, horizon=QUICK.n_steps, train_runs=k["n_train"],
                     val_runs=k["n_val"], batch_size=k["batch_size"], lr=k["lr"], weight_decay=k["weight_decay"],
                     clip=k["clip"], tbptt=k["tbptt"], feature_norm=k["feature_norm"], on_diverged=k["on_diverged"],
                     fresh=k["fresh"], val_every=k["val_every"], clamp=k["clamp"], restarts=k["restarts"],
                     patience=k["patience"]).run()
            last = dict(list(files.items())[-1:])
            for r in ("nominal", "q4"):
                out[f"{e} {r} gain"] = evaluate_part(e, r, "gain", last, QUICK)
                out[f"{e} {r} curve"] = evaluate_part(e, r, "gain", files, QUICK)
    return out


def _particles() -> dict:
    from adaptfilt.experiments.particles_study import PARTICLE_QUICK, evaluate_model_job, floor_job

    out = {}
    for exps in (["ungm-pf-1e-4", "ungm-pf-1e-3"], ["ctm-pf-1", "ctm-pf-0.1"]):
        for e, res in zip(exps, evaluate_model_job(exps, [[], []], PARTICLE_QUICK, parts=("reference",))):
            out[e] = res
    out["floor ungm-pf-1e-4"] = floor_job("ungm-pf-1e-4", PARTICLE_QUICK)
    out["floor ctm-pf-1"] = floor_job("ctm-pf-1", PARTICLE_QUICK)
    return out


def _floors() -> dict:
    from adaptfilt.course.ungm_ukf import ungm_floor_steps
    from adaptfilt.experiments.references import ungm_floor

    return {"ungm_floor": ungm_floor(12, 0, 8, eval_runs=30),
            "ungm_floor_steps": {"rmse_t": ungm_floor_steps(n_runs=3, n_steps=20, eval_runs=5, chunk=2)}}


def compute(case: str) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a diverged run's overflow, as in the studies
        return {"reference": _reference, "gain": _gain, "particles": _particles, "floors": _floors}[case]()


# ------------------------------------------------------------------ fingerprints
def _array(v) -> list:
    """``[dtype and shape, sha256 (64 bits), NaNs, +infs, -infs, sum of the finite values]``."""
    a = np.ascontiguousarray(np.asarray(v))
    rec = [f"{a.dtype.str}{list(a.shape)}", hashlib.sha256(a.tobytes()).hexdigest()[:16]]
    f = a.astype(float).ravel() if a.dtype.kind in "fiub" else np.zeros(0)
    fin = f[np.isfinite(f)]
    return rec + [int(np.isnan(f).sum()), int(np.isposinf(f).sum()), int(np.isneginf(f).sum()), float(fin.sum())]


def _plain(v):
    """A config value as JSON keeps it (tuples as lists, NaN as None)."""
    return json.loads(json.dumps(v, default=lambda o: np.asarray(o).tolist()).replace("NaN", "null"))


def fingerprint(value) -> dict:
    """A Results as ``{"config": ..., "policies": {name: {field: array record}}}``; a dict of numbers (a
    floor) as ``{"values": {key: array record or plain value}}``."""
    from adaptfilt.results import Results

    if isinstance(value, Results):
        pols = {}
        for name, p in value.policies.items():
            pols[name] = {k: _array(v) for k, v in vars(p).items() if k not in ("name", "wall_time_s")}
        config = {k: _plain(v) for k, v in value.config.items() if k not in _VOLATILE}
        return {"config": config, "names": list(pols), "policies": pols}
    return {"values": {k: {"array": _array(v)} if _numeric(v) else {"value": _plain(v)}
                       for k, v in value.items() if k not in _VOLATILE}}


def _numeric(v) -> bool:
    return v is not None and not isinstance(v, (bool, str, dict)) and np.asarray(v).dtype.kind in "fiu"


# ------------------------------------------------------------------ the comparison
def _same_array(got: list, want: list, exact: bool, rtol: float, where: str) -> list[str]:
    if got[:2] == want[:2]:
        return []
    if exact or got[0] != want[0]:
        return [f"{where}: not the same bytes ({want[0]} -> {got[0]})"]
    if got[2:5] != want[2:5] or not np.isclose(got[5], want[5], rtol=rtol, atol=1e-12):
        return [f"{where}: NaNs, infinities, sum {got[2:]} against {want[2:]}"]
    return []


def _plain_diff(got, want, where: str) -> list[str]:
    """A plain (JSON) value against the fixture's; a dict may have gained keys (a result records more)."""
    if isinstance(want, dict) and isinstance(got, dict):
        return [d for k, v in want.items() for d in _plain_diff(got.get(k), v, f"{where}[{k!r}]")]
    return [] if got == want else [f"{where}: {got!r} != {want!r}"]


def differences(got: dict, want: dict, exact: bool) -> list[str]:
    """What differs between two fingerprints of one case (every result of the fixture must be there)."""
    out = []
    for key, w in want.items():
        if key not in got:
            out.append(f"{key}: missing")
            continue
        g = got[key]
        if "values" in w:
            for k, v in w["values"].items():
                gv = g["values"].get(k, {})
                if "array" in v:
                    out += (_same_array(gv["array"], v["array"], exact, RTOL, f"{key} {k}") if "array" in gv
                            else [f"{key} {k}: {gv} is not an array"])
                else:
                    out += _plain_diff(gv.get("value"), v["value"], f"{key} {k}")
            continue
        for k, v in w["config"].items():
            out += _plain_diff(g["config"].get(k), v, f"{key} config[{k!r}]")
        if g["names"] != w["names"]:
            out.append(f"{key}: policies {g['names']} != {w['names']}")
        for name, fields in w["policies"].items():
            rtol = RTOL_PARTICLES if name.startswith("bpf-") else RTOL
            for f, rec in fields.items():
                gf = g["policies"].get(name, {}).get(f)
                out += _same_array(gf, rec, exact, rtol, f"{key} {name}.{f}") if gf else [f"{key} {name}.{f}: missing"]
    return out


def _stored() -> dict:
    return json.loads(FIXTURE.read_text())


@pytest.mark.parametrize("case", CASES)
def test_filter_evaluations_give_the_numbers_they_gave(case):
    """Every array of the case's results as the fixture holds it: the same bytes on the fixture's machine, the same
    summaries to a tolerance elsewhere. Regenerate ``gain`` with ``python tests/test_filter_guard.py --write gain``
    when KalmanNet's training is changed on purpose (module docstring)."""
    stored = _stored()
    want = stored["cases"][case]
    exact = stored["machine"] == machine()
    got = {k: fingerprint(v) for k, v in compute(case).items()}
    bad = differences(got, want, exact)
    assert not bad, f"{len(bad)} differences from tests/fixtures/filter_guard.json ({case}):\n" + "\n".join(bad[:40])


def test_the_guard_sees_a_changed_number():
    """The comparison fails on one changed bit, and off the fixture's machine on a change above the tolerance only."""
    from adaptfilt.results import Results

    a = np.linspace(0.0, 1.0, 50)
    b = a.copy()
    b[7] = np.nextafter(b[7], 2.0)
    fa, fb = _array(a), _array(b)
    assert _same_array(fb, fa, exact=True, rtol=RTOL, where="x") and not _same_array(fb, fa, exact=False, rtol=RTOL, where="x")
    c = a.copy()
    c[7] += 1e-3
    assert _same_array(_array(c), fa, exact=False, rtol=RTOL, where="x")
    res = Results(config={"seed": 0, "version": "x"})
    assert fingerprint(res)["config"] == {"seed": 0}
    assert differences({"r": fingerprint(Results(config={"seed": 1}))}, {"r": fingerprint(res)}, True) == [
        "r config['seed']: 1 != 0"]
    # a result may record more (a new key, in a nested dict too), never other values
    more = Results(config={"seed": 0, "floor": {"rmse": 1.0, "grid": "np.linspace(-45, 45, 1801)"}, "filters": {}})
    less = Results(config={"seed": 0, "floor": {"rmse": 1.0}})
    assert differences({"r": fingerprint(more)}, {"r": fingerprint(less)}, True) == []
    assert differences({"r": fingerprint(less)}, {"r": fingerprint(more)}, True) == [
        "r config['floor']['grid']: None != 'np.linspace(-45, 45, 1801)'", "r config['filters']: None != {}"]


def write(cases: tuple[str, ...]) -> None:
    stored = _stored() if FIXTURE.exists() else {"cases": {}}
    if set(cases) != set(CASES) and stored.get("machine") not in (None, machine()):
        raise SystemExit(f"the fixture was made on {stored['machine']}, this is {machine()}: regenerate every case "
                         "(--write) on one machine")
    for case in cases:
        stored["cases"][case] = {k: fingerprint(v) for k, v in compute(case).items()}
        print(f"{case}: {len(stored['cases'][case])} results")
    stored["machine"] = machine()
    stored["made_by"] = "python tests/test_filter_guard.py --write " + " ".join(cases)
    # one line per result: a diff shows which result moved
    lines = [f"{json.dumps(case)}: {{\n" + ",\n".join(f"  {json.dumps(k)}: {json.dumps(v, sort_keys=True)}"
                                                     for k, v in results.items()) + "\n}"
             for case, results in sorted(stored["cases"].items())]
    FIXTURE.write_text("{\n" + f'"machine": {json.dumps(stored["machine"])},\n"made_by": {json.dumps(stored["made_by"])},\n'
                       + '"cases": {\n' + ",\n".join(lines) + "\n}\n}\n")


if __name__ == "__main__":
    args = sys.argv[1:]
    if not args or args[0] != "--write" or any(a not in CASES for a in args[1:]):
        raise SystemExit(f"usage: python tests/test_filter_guard.py --write [{' | '.join(CASES)} ...]")
    write(tuple(args[1:]) or CASES)
