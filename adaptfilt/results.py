r"""The results of an evaluation and their files: :class:`PolicyResult` (one policy's summaries,
bootstrap replicates and per-run values), :class:`Results` (all policies of one paired evaluation:
paired differences, the text table, ``summary.json``) and the on-disk format ``results.json`` +
``results.npz`` (:data:`RESULTS_FORMAT`; :meth:`Results.save`, :meth:`Results.load`).

:func:`adaptfilt.evaluation.evaluate` makes them; what is reported is listed there. This module
needs neither the filters nor the engine, so whatever only reads results (the seed statistics, the
pipeline's reader of ``data/``) imports it alone.
"""
from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Sequence

import numpy as np

from adaptfilt import metrics
from adaptfilt.files import atomic_path, atomic_write

__all__ = ["PolicyResult", "Results", "RESULTS_FORMAT", "PAIRED_METRICS"]

RESULTS_FORMAT = "adaptfilt-results/1"

_SCALARS = ("rmse", "anees", "nis", "cost", "cost_median", "cost_q99", "cost_q999", "cost_max",
            "rmse_run_median", "n_repairs", "wall_time_s")
_CIS = ("rmse_ci", "anees_ci", "cost_ci")
_ARRAYS = ("rmse_t", "rmse_t_band", "anees_t", "anees_t_band", "nis_t", "choices", "usage",
           "boot_rmse", "boot_anees", "boot_cost", "run_rmse", "run_anees", "run_cost")
# Added later: results written before them load with NaN / empty values.
_SCALARS_NEW = ("objective", "cost_charged", "anees_run_median", "divergent_frac", "extra_spent", "spent")
_CIS_NEW = ("objective_ci", "cost_charged_ci")
_ARRAYS_NEW = ("boot_objective", "cost_t", "boot_cost_charged")
#: Metrics with run-level bootstrap replicates (``boot_<metric>``): paired differences and seed statistics.
PAIRED_METRICS = ("rmse", "anees", "cost", "objective", "cost_charged")



@dataclass
class PolicyResult:
    """The evaluation of one policy; see the module docstring for what each number means.

    ``*_band (2, T)`` are pointwise 95 % bands of ``RMSE_k`` (bootstrap) and
    ``ANEES_k`` (mean +- 1.96 standard errors);
    ``boot_* (n_boot,)`` the bootstrap replicates of the time averages (shared
    resamples across policies); ``run_* (M,)`` per-run time averages (RMS
    error, mean NEES, mean cost).
    """

    name: str
    rmse: float
    rmse_ci: tuple[float, float]
    anees: float
    anees_ci: tuple[float, float]
    nis: float
    cost: float
    cost_ci: tuple[float, float]
    cost_median: float
    cost_q99: float
    cost_q999: float
    cost_max: float
    rmse_run_median: float
    n_repairs: int
    wall_time_s: float
    rmse_t: np.ndarray
    rmse_t_band: np.ndarray
    anees_t: np.ndarray
    anees_t_band: np.ndarray
    nis_t: np.ndarray
    choices: np.ndarray
    usage: np.ndarray
    boot_rmse: np.ndarray
    boot_anees: np.ndarray
    boot_cost: np.ndarray
    run_rmse: np.ndarray
    run_anees: np.ndarray
    run_cost: np.ndarray
    objective: float = float("nan")
    objective_ci: tuple[float, float] = (float("nan"), float("nan"))
    cost_charged: float = float("nan")
    anees_run_median: float = float("nan")
    divergent_frac: float = float("nan")
    extra_spent: float = float("nan")
    spent: float = float("nan")
    cost_charged_ci: tuple[float, float] = (float("nan"), float("nan"))
    boot_objective: np.ndarray = field(default_factory=lambda: np.empty(0))
    cost_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    boot_cost_charged: np.ndarray = field(default_factory=lambda: np.empty(0))

    def scalars(self) -> dict:
        """The JSON-able scalar summaries (CIs as ``[lo, hi]``, usage as counts)."""
        d = {k: getattr(self, k) for k in _SCALARS + _SCALARS_NEW}
        d.update({k: list(getattr(self, k)) for k in _CIS + _CIS_NEW})
        d["usage"] = self.usage.tolist()
        return d


@dataclass
class Results:
    """The outcome of :func:`evaluate`: the configuration and one :class:`PolicyResult` per policy.

    >>> res["greedy"].rmse, res["greedy"].rmse_ci        # doctest: +SKIP
    >>> res.paired_difference("greedy", "default", "rmse")  # (diff, lo, hi)  # doctest: +SKIP
    """

    config: dict
    policies: dict[str, PolicyResult] = field(default_factory=dict)

    # ------------------------------------------------------------ access
    def __getitem__(self, name: str) -> PolicyResult:
        try:
            return self.policies[name]
        except KeyError:
            raise KeyError(f"no policy {name!r} in these results; have: {', '.join(self.policies)}") from None

    def __contains__(self, name: str) -> bool:
        return name in self.policies

    @property
    def names(self) -> list[str]:
        return list(self.policies)

    @property
    def grid(self) -> np.ndarray:
        return np.asarray(self.config["grid"], dtype=float)

    def paired_difference(self, a: str, b: str, metric: Literal["rmse", "anees", "cost"] = "rmse",
                          level: float = 0.95) -> tuple[float, float, float]:
        """``metric(a) - metric(b)`` and its paired bootstrap interval ``(diff, lo, hi)``.

        Both policies ran on the same trajectories and are resampled with the
        same counts, so the interval is that of the difference itself: it
        excludes 0 when the difference is significant at ``level``.
        """
        if metric not in PAIRED_METRICS:
            raise ValueError(f"metric must be one of {', '.join(map(repr, PAIRED_METRICS))}, got {metric!r}")
        pa, pb = self[a], self[b]
        diff = float(getattr(pa, metric) - getattr(pb, metric))
        lo, hi = metrics.percentile_ci(getattr(pa, "boot_" + metric) - getattr(pb, "boot_" + metric), level)
        return diff, lo, hi

    def fixed_names(self, both_steps: bool = False) -> list[str]:
        """The fixed-value policies (:class:`~adaptfilt.policies.FixedPolicy`, by the names it gives), fixed in
        the update only (default) or, ``both_steps``, in both steps; in their order here."""
        return [n for n in self.policies if n.startswith("fixed-") and n.startswith("fixed-both-") == both_steps]

    def best_fixed(self, metric: Literal["rmse", "anees", "cost"] = "rmse", both_steps: bool = False) -> str:
        """Name of the fixed-value policy with the lowest ``metric`` (ANEES: closest to ``nx``),
        among those fixed in the update only (default) or, ``both_steps``, in both steps."""
        fixed = self.fixed_names(both_steps)
        if not fixed:
            raise ValueError("these results have no fixed-value policies")
        if metric == "anees":
            return min(fixed, key=lambda n: abs(np.log(self[n].anees / self.config["nx"])))
        return min(fixed, key=lambda n: getattr(self[n], metric))

    @classmethod
    def merge(cls, parts: Sequence["Results"], ignore: Sequence[str] = ()) -> "Results":
        """One evaluation from its parts, jobs that simulated the same runs (same seed, runs, horizon:
        an evaluation's trajectories, filter draws and bootstrap resamples depend on its seed only, so the
        merge is exact), policies in the order of the parts. Their configurations must agree but for
        ``"policies"``, what ran (``"filters"``, ``"failed_filters"``: joined) and the keys in ``ignore``
        (RuntimeError otherwise). The first part is the one returned, extended in place: the parts are a
        job's values, not kept.

        >>> a = Results({"n_runs": 2, "policies": ["x"]}, {"x": None}); b = Results({"n_runs": 2}, {"y": None})
        >>> Results.merge([a, b]).config["policies"]
        ['x', 'y']
        """
        joined = ("filters", "failed_filters")
        skip = {"policies", *joined, *ignore}
        first = parts[0]
        mine = {k: v for k, v in first.config.items() if k not in skip}
        for other in parts[1:]:
            theirs = {k: v for k, v in other.config.items() if k not in skip}
            if theirs != mine:
                diff = sorted(k for k in mine.keys() | theirs.keys() if mine.get(k) != theirs.get(k))
                raise RuntimeError(f"parts of the {mine.get('experiment', '')} evaluation disagree on {', '.join(diff)}")
            first.policies.update(other.policies)
            for k in joined:
                if k in other.config:
                    first.config[k] = {**first.config.get(k, {}), **other.config[k]}
        first.config["policies"] = list(first.policies)
        return first

    # ----------------------------------------------------------- tables
    def summary(self) -> dict:
        """``{name: {"rmse", "anees", "cost", "rmse_ci", "anees_ci", ...}}`` (what ``summary.json`` holds)."""
        out = {}
        for n, p in self.policies.items():
            out[n] = {"rmse": p.rmse, "anees": p.anees, "cost": p.cost,
                      "rmse_ci": list(p.rmse_ci), "anees_ci": list(p.anees_ci),
                      "cost_ci": list(p.cost_ci), "cost_median": p.cost_median,
                      "rmse_run_median": p.rmse_run_median, "nis": p.nis}
        return out

    def table(self) -> str:
        """A Markdown table of the time-averaged summaries with 95 % CIs."""
        c = self.config
        head = (f"**{c.get('experiment') or c.get('model')}**: M = {c['n_runs']} runs, T = {c['n_steps']} steps, "
                f"seed {c['seed']}, cost `{c['cost']}`; 95 % bootstrap CIs over runs "
                f"(ideal ANEES = nx = {c['nx']}, ideal NIS = nz = {c['nz']}).\n\n")
        rows = ["| policy | RMSE [95% CI] | ANEES [95% CI] | NIS | cost mean [95% CI] | cost median | "
                "cost q99.9 | median run RMSE | repairs | time (s) |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        for n, p in self.policies.items():
            rows.append(
                f"| {n} | {p.rmse:.4g} [{p.rmse_ci[0]:.4g}, {p.rmse_ci[1]:.4g}] "
                f"| {p.anees:.4g} [{p.anees_ci[0]:.4g}, {p.anees_ci[1]:.4g}] | {p.nis:.4g} "
                f"| {p.cost:.4g} [{p.cost_ci[0]:.4g}, {p.cost_ci[1]:.4g}] | {p.cost_median:.4g} "
                f"| {p.cost_q999:.4g} | {p.rmse_run_median:.4g} | {p.n_repairs} | {p.wall_time_s:.1f} |")
        return head + "\n".join(rows) + "\n"

    # ------------------------------------------------------------- files
    def save(self, out_dir: str | Path, arrays: bool = True, drop: Sequence[str] = ()) -> Path:
        """Write ``results.json`` (config and scalar summaries) and ``results.npz``
        (arrays) into ``out_dir``; :meth:`load` reads them back bit-identically.
        ``arrays=False`` writes the summaries only (no per-run or per-step arrays,
        so no paired differences or figures from the file: for studies whose
        paired statistics are computed before saving and stored on their own).
        ``drop`` leaves out the named arrays (e.g. the per-run ``run_rmse``,
        ``run_anees``, ``run_cost`` and ``choices``, which are most of the file;
        the bootstrap replicates that paired differences and seed-level
        aggregates use stay); they load back empty and the config lists them."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        bad = sorted(set(drop) - set(_ARRAYS + _ARRAYS_NEW))
        if bad:
            raise ValueError(f"drop names no array of a result: {bad}; arrays are {list(_ARRAYS + _ARRAYS_NEW)}")
        config = self.config if arrays else {**self.config, "arrays": False}
        if arrays and drop:
            config = {**config, "dropped": [k for k in _ARRAYS + _ARRAYS_NEW if k in drop]}
        doc = {"format": RESULTS_FORMAT, "config": config,
               "policies": {n: p.scalars() for n, p in self.policies.items()},
               "order": list(self.policies)}
        # json writes floats with repr(): they read back exactly.
        # arrays first, then the JSON that names them: each file whole or absent (adaptfilt.files)
        if arrays:
            arrays = {f"p{i}_{k}": getattr(p, k) for i, p in enumerate(self.policies.values())
                      for k in _ARRAYS + _ARRAYS_NEW if k not in drop}
            with atomic_path(out / "results.npz") as tmp, open(tmp, "wb") as f:
                np.savez_compressed(f, **arrays)
        atomic_write(out / "results.json", json.dumps(doc, indent=1) + "\n")
        return out

    @classmethod
    def load(cls, out_dir: str | Path) -> "Results":
        """Read what :meth:`save` wrote."""
        out = Path(out_dir)
        doc = json.loads((out / "results.json").read_text())
        if doc.get("format") != RESULTS_FORMAT:
            raise ValueError(f"{out / 'results.json'} is not an adaptfilt results file (format {doc.get('format')!r})")
        pols = {}
        with contextlib.ExitStack() as stack:
            z = (None if doc["config"].get("arrays") is False  # saved without arrays: empty ones
                 else stack.enter_context(np.load(out / "results.npz", allow_pickle=False)))
            for i, n in enumerate(doc["order"]):
                s = doc["policies"][n]
                kw = {k: s[k] for k in _SCALARS}
                kw.update({k: s[k] for k in _SCALARS_NEW if k in s})
                kw.update({k: (s[k][0], s[k][1]) for k in _CIS + _CIS_NEW if k in s})
                if z is None:
                    kw.update({k: np.empty(0) for k in _ARRAYS})
                    kw["usage"] = np.asarray(s["usage"], dtype=np.int64)  # the scalars keep the counts
                else:
                    kw.update({k: np.empty(0) for k in doc["config"].get("dropped", ())})
                    kw.update({k: z[f"p{i}_{k}"] for k in _ARRAYS + _ARRAYS_NEW if f"p{i}_{k}" in z.files})
                pols[n] = PolicyResult(name=n, **kw)
        return cls(config=doc["config"], policies=pols)


# ------------------------------------------------------------------ evaluate
