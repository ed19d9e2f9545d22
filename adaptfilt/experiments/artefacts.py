"""The committed artefacts in ``data/`` (trained policies, evaluation results), for the notebooks.

``data/`` is written by ``adaptfilt reproduce --out data`` (:mod:`adaptfilt.experiments.reproduce`);
every file is listed in ``data/manifest.json`` with its sha256, the one
command that regenerates it, the seed, the package version and its wall time.

>>> from adaptfilt.experiments import artefacts         # doctest: +SKIP
>>> res = artefacts.load_results("ungm-ukf")             # doctest: +SKIP
>>> res.paired_difference("adaptive", "greedy", "rmse")  # doctest: +SKIP
>>> pol = artefacts.stored_policy("ungm-ukf", "adaptive", seed=3)  # doctest: +SKIP
>>> artefacts.load_floor()["rmse"]                        # doctest: +SKIP
>>> artefacts.verify()                                    # doctest: +SKIP
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from adaptfilt.files import sha256

__all__ = ["data_dir", "find_data", "DataNotFound", "manifest", "load_results", "stored_policy", "stored_policies", "seeds", "load_floor",
           "load_table1", "load_claims", "load_reconciliation", "verify", "load_beyond", "load_beyond_results",
           "verify_beyond", "load_archive", "CHECK_FILES", "store_check"]


def data_dir() -> Path:
    """``$ADAPTFILT_DATA`` if set, else the ``data/`` folder of the repository."""
    env = os.environ.get("ADAPTFILT_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "data"


class DataNotFound(FileNotFoundError):
    """No stored artefacts where :func:`find_data` looked (the message says where)."""


def find_data(data: str | Path | None = None, required: str | None = None) -> Path | None:
    """The stored artefacts a command reuses: ``data`` (``--data DIR``), else ``$ADAPTFILT_DATA``, else
    the ``data/`` of the checkout this package runs from. A folder counts when it holds ``manifest.json``.

    A folder given by ``data`` or ``$ADAPTFILT_DATA`` that holds none is an error: it was asked for.
    With none given and no checkout (a package installed from a wheel), the result is None, or, when
    ``required`` says what to do instead, a :class:`DataNotFound` naming where it looked and that."""
    for given, what in ((data, "--data"), (os.environ.get("ADAPTFILT_DATA"), "$ADAPTFILT_DATA")):
        if given:
            d = Path(given).expanduser()
            if not (d / "manifest.json").is_file():
                raise DataNotFound(f"{what} {d}: no manifest.json there; give a copy of the repository's data/ folder")
            return d
    package = Path(__file__).resolve().parents[1]  # adaptfilt/ (this module is adaptfilt/experiments/artefacts.py)
    checkout = package.parent
    if (checkout / "pyproject.toml").is_file() and (checkout / "data" / "manifest.json").is_file():
        return checkout / "data"
    if required is None:
        return None
    raise DataNotFound(f"no stored artefacts: no --data DIR given, $ADAPTFILT_DATA not set, and {package} is not "
                       f"in a checkout with data/manifest.json (give --data with a copy of the repository's data/); "
                       f"{required}")


def _d(root) -> Path:
    return data_dir() if root is None else Path(root)


def manifest(root: str | Path | None = None) -> dict:
    """``data/manifest.json`` as a dict (``{"package_version", "files": [...]}``)."""
    p = _d(root) / "manifest.json"
    if not p.exists():
        raise FileNotFoundError(f"no {p}: run `adaptfilt reproduce --out {_d(root)}` first")
    return json.loads(p.read_text())


def load_results(experiment: str, root: str | Path | None = None):
    """The M = 10^4 evaluation of ``experiment`` (every baseline + ``adaptive`` and ``myopic``)."""
    from adaptfilt.results import Results

    return Results.load(_d(root) / "results" / experiment)


POLICY_KINDS = ("adaptive", "myopic", "adaptive-faithful")


def seeds(experiment: str, kind: str = "adaptive", root: str | Path | None = None) -> list[int]:
    """The training seeds of ``data/policies/{experiment}-{kind}-s{seed}.npz``, sorted."""
    d = _d(root) / "policies"
    pre = f"{experiment}-{kind}-s"
    return sorted(int(p.stem[len(pre):]) for p in d.glob(pre + "*.npz") if p.stem[len(pre):].isdigit())


def stored_policy(experiment: str, kind: str = "adaptive", seed: int = 0, root: str | Path | None = None):
    """The learned policy ``kind`` of ``experiment`` trained with ``seed``: "adaptive"
    (gamma 0.5) or "myopic" (gamma 0), trained by the fast mode, or "adaptive-faithful"
    (Algorithm 2's loop with the library's recipe). Its ``name`` is ``{kind}-s{seed}``, as in the stored results. (A policy
    file by its path: :func:`adaptfilt.learned.load_policy`.)"""
    if kind not in POLICY_KINDS:
        raise ValueError(f"kind must be one of {', '.join(POLICY_KINDS)}; got {kind!r}")
    from adaptfilt.learned import load_policy as _load

    return _load(_d(root) / "policies" / f"{experiment}-{kind}-s{seed}.npz", experiment=experiment,
                 name=f"{kind}-s{seed}")


def stored_policies(experiment: str, kind: str = "adaptive", root: str | Path | None = None) -> list:
    """Every seed of ``kind`` (see :func:`stored_policy`), in seed order."""
    return [stored_policy(experiment, kind, s, root) for s in seeds(experiment, kind, root)]


def _json(rel: str, root) -> dict:
    return json.loads((_d(root) / rel).read_text())


def load_floor(root: str | Path | None = None) -> dict:
    """The point-mass (Bayes) RMSE floor on UNGM: ``{"rmse", "rmse_ci", "n_runs", "n_steps", ...}``."""
    return _json("results/ungm-floor.json", root)


def load_table1(root: str | Path | None = None) -> dict:
    """Table I (ours with CIs beside the paper's)."""
    return _json("results/table1.json", root)


def load_claims(root: str | Path | None = None) -> dict:
    """The claims C1-C6 as paired comparisons with verdicts."""
    return _json("results/claims.json", root)


def load_reconciliation(root: str | Path | None = None) -> dict:
    """The CTM RMSE reconciliation table (:func:`adaptfilt.experiments.references.ctm_reconciliation`)."""
    return _json("results/ctm-reconciliation.json", root)


def load_beyond(root: str | Path | None = None) -> dict:
    """``data/beyond/summary.json``: the studies beyond the paper (``adaptfilt beyond --out data``)."""
    p = _d(root) / "beyond" / "summary.json"
    if not p.exists():
        raise FileNotFoundError(f"no {p}: run `adaptfilt beyond --out {_d(root)}` first")
    return json.loads(p.read_text())


def load_beyond_results(name: str, root: str | Path | None = None):
    """One evaluation of the beyond studies, e.g. ``"cand-ungm-ukf"``, ``"sif-ctm-sif-nis"``,
    ``"ood-q4-r0.25"`` (the out-of-distribution ones hold summaries only: ``Results.save(arrays=False)``)."""
    from adaptfilt.results import Results

    p = _d(root) / "beyond" / "results" / name
    if not (p / "results.json").exists():
        have = sorted(q.name for q in p.parent.iterdir()) if p.parent.is_dir() else []
        raise FileNotFoundError(f"no beyond results {name!r} in {p.parent}; there are: {have}")
    return Results.load(p)


def verify_beyond(root: str | Path | None = None) -> list[str]:
    """Check ``beyond/manifest.json`` like :func:`verify`: every file exists, matches its sha256 and
    loads (policies against their experiment, KalmanNet files against its model, results with
    ``Results.load``). Returns the checked paths."""
    from adaptfilt.results import Results
    from adaptfilt.learned import load_policy as _load

    d = _d(root) / "beyond"

    def load(rel: str, p: Path) -> None:
        if p.suffix == ".npz" and rel.startswith("policies/"):
            name = p.name.removeprefix("gain-")  # the gain study's files: gain-<experiment>-<arm>-b<i>-s<j>
            exp = next(x for x in sorted(_experiments(), key=len, reverse=True) if name.startswith(x + "-"))
            if name == p.name:
                _load(p, experiment=exp)
                return
            from adaptfilt.experiment_registry import get_experiment
            from adaptfilt.files import read_npz
            from adaptfilt.kalmannet import load_kalmannet

            if "-gain-" in name:  # a KalmanNet, against its experiment's model
                load_kalmannet(p, get_experiment(exp).make_model())
                return
            # a kappa policy, trained on the experiment or a twin of it (-sqerr, -sqerr-nll0.1): the file says which
            trained = read_npz(p)[1].get("experiment", "")
            if trained != exp and not trained.startswith(exp + "-"):
                raise ValueError(f"trained on {trained!r}, not on {exp!r} or a variant of it")
            _load(p, experiment=trained)
        elif p.name == "results.json":
            Results.load(p.parent)
        elif p.suffix == ".json":
            json.loads(p.read_text())

    return _check_files(d, json.loads((d / "manifest.json").read_text())["files"], load, "data/beyond")


def load_archive(name: str, what: str, root: str | Path | None = None) -> dict:
    """An archived summary, ``data/archive/{name}/{what}.json`` (e.g. ``load_archive("onepass", "table1")``:
    the verdicts before the SIF form, the compute charge and the margins changed, kept as comparison
    rows), after checking it against its manifest."""
    d = _d(root) / "archive" / name
    man = json.loads((d / "manifest.json").read_text())
    rel = f"{what}.json"
    entry = [e for e in man["files"] if e["path"] == rel]
    if not entry:
        raise KeyError(f"no {rel} in {d}; have: {', '.join(e['path'] for e in man['files'])}")
    _check_files(d, entry, None, f"data/archive/{name}")
    return json.loads((d / rel).read_text())


def _experiments() -> list[str]:
    from adaptfilt.experiment_registry import EXPERIMENTS, PARTICLE_EXPERIMENTS, VARIANTS

    return [*EXPERIMENTS, *VARIANTS, *PARTICLE_EXPERIMENTS]


def verify(root: str | Path | None = None, load: bool = True) -> list[str]:
    """Check every manifest entry: the file exists, matches its sha256 and
    (``load``) loads: policies against their experiment, results with
    ``Results.load``, JSON files with ``json``. Returns the checked paths;
    raises ``ValueError`` listing every problem."""
    d = _d(root)

    def loader(rel: str, p: Path) -> None:
        parts = Path(rel).parts
        if parts[0] == "policies":
            stem, _, seed = Path(rel).stem.rpartition("-s")
            kind = next(k for k in sorted(POLICY_KINDS, key=len, reverse=True) if stem.endswith("-" + k))
            stored_policy(stem[: -len(kind) - 1], kind, int(seed), root=d)
        elif parts[0] == "results" and len(parts) == 3 and parts[2] == "results.npz":
            load_results(parts[1], root=d)
        elif p.suffix == ".json":
            json.loads(p.read_text())

    return _check_files(d, manifest(d)["files"], loader if load else None, "data/")


def _check_files(d: Path, files: list[dict], load, label: str) -> list[str]:
    """Each entry's file exists, matches its sha256 and (``load(rel, path)``) loads; returns the checked
    paths, or raises ``ValueError`` listing every problem."""
    problems, checked = [], []
    for e in files:
        p = d / e["path"]
        if not p.exists():
            problems.append(f"{e['path']}: missing")
            continue
        h = sha256(p)
        if h != e["sha256"]:
            problems.append(f"{e['path']}: sha256 {h} != manifest {e['sha256']}")
            continue
        if load is not None:
            try:
                load(e["path"], p)
            except Exception as ex:  # noqa: BLE001 - report every problem
                problems.append(f"{e['path']}: does not load ({type(ex).__name__}: {ex})")
                continue
        checked.append(e["path"])
    if problems:
        raise ValueError(f"{label} does not match its manifest:\n  " + "\n  ".join(problems))
    return checked


#: The summary files of a reproduction that a check keeps (``data/medium``, ``data/retrain``).
CHECK_FILES = ("results/claims.json", "results/agreement.json", "results/fast-vs-faithful.json", "results/table1.json",
               "results/table1.md", "timings.json", "report-tables.md")


def store_check(run: str | Path, dest: str | Path, note: str = "", commit: str | None = None) -> list[str]:
    """Keep the summary of a reproduction made in another folder as a check of ``data/``: the files of
    :data:`CHECK_FILES` that ``run`` holds (its claims, their agreement with data/'s, Table I, the
    fast-vs-faithful comparison, the report's tables, every stage's and job's time) copied to ``dest``
    (``data/medium`` for ``--scale medium --retrain``, ``data/retrain`` for ``--retrain``) with a
    manifest of data/'s form: sha256, the command with ``--out DIR``, seed and version, plus ``note``
    and the ``commit`` of the code that ran. The run's policies and per-policy results are not kept
    (the command remakes them). Returns the paths kept; a run without claims is refused."""
    import shutil

    from adaptfilt.files import atomic_write

    run, dest = Path(run), Path(dest)
    man = json.loads((run / "manifest.json").read_text())
    if not (run / "results/claims.json").is_file():
        raise ValueError(f"{run}: no results/claims.json; not a finished reproduction")
    cmd = man["generated_by"].replace("--out data ", "--out DIR ")
    kept = [rel for rel in CHECK_FILES if (run / rel).is_file()]
    files = []
    for rel in kept:
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run / rel, dest / rel)
        files.append({"path": rel, "sha256": sha256(dest / rel), "command": cmd, "seed": 0,
                      "version": man["package_version"], "wall_time_s": None, "cpu_time_s": None})
    out = {"package_version": man["package_version"], "scale": man["scale"], "seeds": man["seeds"], "generated_by": cmd,
           "note": note or f"the summary files of `{cmd}` (DIR's policies and per-policy results are not stored)"}
    if commit:
        out["commit"] = commit
    out["files"] = files
    atomic_write(dest / "manifest.json", json.dumps(out, indent=1) + "\n")
    return kept
