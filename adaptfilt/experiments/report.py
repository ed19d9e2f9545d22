r"""The reproduction's report: Markdown tables, figures, and their place in ``REPRODUCTION.md``.

Everything here is a pure function of stored results (:class:`~adaptfilt.evaluation.Results`,
the claims and Table I of :mod:`adaptfilt.experiments.claims`, the references of
:mod:`adaptfilt.experiments.references`), so that the report's numbers are
exactly the stored ones. A learned policy trained on several seeds appears as
one row: the IQM over seeds with its two-level (seeds x runs) 95 % interval and
the range of the per-seed values.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from adaptfilt.experiments.claims import members
from adaptfilt.files import atomic_savefig, atomic_write
from adaptfilt.seed_stats import aggregate, seed_groups

__all__ = ["summary_md", "table1_md", "table1_columns_md", "table1_compute_md", "claims_md", "claim_rows",
           "claims_subset_md", "recon_md", "timings_md", "report_tables", "figures", "figure_policies",
           "embed_report_tables", "replace_sections", "BEGIN_MARK", "END_MARK", "fmt", "CLAIM_KEYS"]

BEGIN_MARK, END_MARK = "<!-- BEGIN report-tables -->", "<!-- END report-tables -->"


def fmt(v, ci=None, digits: int = 4) -> str:
    s = f"{v:.{digits}g}"
    if ci is not None:
        s += f" [{ci[0]:.{digits}g}, {ci[1]:.{digits}g}]"
    return s


def _rows(res) -> list[tuple[str, list[str]]]:
    """(label, member names): baselines one by one, seed groups collapsed."""
    groups = seed_groups(res.names)
    grouped = {n for g in groups.values() for n in g}
    out, seen = [], set()
    for n in res.names:
        if n in grouped:
            g = next(k for k, v in groups.items() if n in v)
            if g not in seen:
                seen.add(g)
                out.append((f"{g} ({len(groups[g])} seeds)", groups[g]))
        else:
            out.append((n, [n]))
    return out


def _cell(res, names, metric) -> str:
    if len(names) == 1:
        p = res[names[0]]
        return fmt(getattr(p, metric), getattr(p, metric + "_ci", None))
    agg = aggregate(res, names, metric)
    return f"{fmt(agg.iqm, agg.iqm_ci)} ({agg.values.min():.3g}..{agg.values.max():.3g})"


def summary_md(res, floor: dict | None = None) -> str:
    """Every policy of one experiment: RMSE, ANEES, cost, objective (seed groups: IQM [CI] (range))."""
    has_obj = all(np.isfinite(getattr(res[n], "objective", np.nan)) for n in res.names)
    head = ["policy", "RMSE [95% CI]", "ANEES [95% CI]", "cost [95% CI]"] + (["log(1+L)"] if has_obj else []) + \
        ["median run RMSE", f"mean {res.config['param_name']}"]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, names in _rows(res):
        usage = sum(res[n].usage for n in names)
        cells = [label] + [_cell(res, names, m) for m in ("rmse", "anees", "cost")]
        if has_obj:
            cells.append(_cell(res, names, "objective") if len(names) > 1 else fmt(res[names[0]].objective))
        cells += [f"{np.median([res[n].rmse_run_median for n in names]):.4g}",
                  f"{(usage * res.grid).sum() / max(1, usage.sum()):.3g}"]
        rows.append("| " + " | ".join(cells) + " |")
    if floor is not None:
        rows.append(f"| point-mass filter (Bayes floor, {floor['n_runs']} runs) | {fmt(floor['rmse'], floor['rmse_ci'])} "
                    + "| " * (len(head) - 2) + "|")
    c = res.config
    return (f"M = {c['n_runs']} runs, T = {c['n_steps']} steps, seed {c['seed']}, cost `{c['cost']}`; a seed group is "
            f"the IQM over its training seeds [two-level 95 % CI] (range of the per-seed values).\n\n"
            + "\n".join(rows) + "\n")


def metric_label(row: dict) -> str:
    """A claim row's metric as a table shows it: the uncharged cost row says that it is not the verdict."""
    return "cost (uncharged; not the verdict)" if row.get("role") == "uncharged" else row["metric"]


def verdict_text(row: dict) -> str:
    """A claim row's verdict (:func:`adaptfilt.verdicts.verdict`), with its declared margin where it has one."""
    v = row["verdict"]
    if "margin" in row:
        v += f" (margin {row['margin']:.3g})"
    return v


def md_table(head: list[str], rows: list[list] = ()) -> list[str]:
    """A Markdown table's lines: the header, its rule, and ``rows`` (cells already formatted). Every table of
    the pipeline's reports starts here.

    >>> md_table(["a", "b"], [[1, 2]])
    ['| a | b |', '|---|---|', '| 1 | 2 |']
    """
    return (["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows])


def table1_md(t1: dict) -> str:
    lines = md_table(["cost", "metric", "policy", "paper", "ours [95% CI]", "per seed"])
    for e, d in t1.items():
        for m, label in (("rmse", "time-avg RMSE"), ("anees", "time-avg ANEES"),
                         ("cost_charged", "time-avg cost, compute charged (the verdict)"),
                         ("cost", "time-avg cost, chosen N_it only (the paper's)")):
            for col, o in d["ours"].items():
                if m not in o:
                    continue
                pv = d["paper"].get(col, {}).get(m)  # the paper reports the uncharged cost only
                name = col if col not in ("fixed", "best fixed (cost)") else f"{col} ({o['policy']})"
                if o["n_seeds"] > 1:
                    name += f", {o['n_seeds']} seeds"
                seeds = "" if o["n_seeds"] == 1 else ", ".join(f"{v:.3g}" for v in o[m + "_seeds"])
                lines.append(f"| {d['cost_label']} | {label} | {name} | {'' if pv is None else fmt(pv)} "
                             f"| {fmt(o[m], o[m + '_ci'])} | {seeds} |")
        for col, o in d["ours"].items():
            lines.append(f"| {d['cost_label']} | iterations per step: chosen / spent "
                         f"| {col} | | {o['mean_n_iter']:.3g} / {o.get('n_iter_spent', float('nan')):.3g} "
                         f"| divergent runs: {100 * o.get('divergent_frac', float('nan')):.2g} % (worst seed) |")
    return "\n".join(lines) + "\n"


def _t1_experiments(t1: dict, experiments) -> list[str]:
    exps = list(t1) if experiments is None else [experiments] if isinstance(experiments, str) else list(experiments)
    missing = [e for e in exps if e not in t1]
    if missing:
        raise ValueError(f"Table I has no experiment {missing[0]!r}; it has {', '.join(t1)}")
    return exps


def _t1_name(col: str, o: dict) -> str:
    name = col if col not in ("fixed", "best fixed (cost)") else f"{col} ({o['policy']})"
    return name + (f", {o['n_seeds']} seeds" if o["n_seeds"] > 1 else "")


def table1_columns_md(t1: dict, experiments=None, digits: int = 4) -> str:
    """Table I as the paper lays it out, ours beside the paper's: one row per (cost, policy),
    RMSE, ANEES and cost each as "paper | ours [95 % CI]" (seed groups: the IQM over seeds with
    the two-level interval). ``t1`` is :func:`adaptfilt.experiments.claims.table1` (or
    ``artefacts.load_table1()``), ``experiments`` a subset of its keys."""
    head = ["cost", "policy"] + [f"{m}: {w}" for m in ("RMSE", "ANEES", "cost") for w in ("paper", "ours [95 % CI]")] \
        + ["cost, compute charged: ours [95 % CI]"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for e in _t1_experiments(t1, experiments):
        d = t1[e]
        for col, o in d["ours"].items():
            cells = [d["cost_label"], _t1_name(col, o)]
            for m in ("rmse", "anees", "cost"):
                pv = d["paper"].get(col, {}).get(m)
                cells += ["" if pv is None else fmt(pv, digits=digits), fmt(o[m], o[m + "_ci"], digits=3)]
            cells.append(fmt(o["cost_charged"], o["cost_charged_ci"], digits=3) if "cost_charged_ci" in o else "")
            out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def table1_compute_md(t1: dict, experiments=None) -> str:
    """What each Table I policy computed and what it left diverged: iterations per step
    chosen (the update) and really spent (plus the innovation feature, or every greedy
    candidate), the cost charged for all of them, the fraction of divergent runs (worst
    seed) and the per-seed RMSE of a seed group."""
    head = ["cost", "policy", "N_it chosen", "N_it spent", "cost charged (IQM)", "divergent runs (worst seed)",
            "RMSE per seed"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for e in _t1_experiments(t1, experiments):
        d = t1[e]
        for col, o in d["ours"].items():
            spent = o.get("n_iter_spent")
            seeds = ", ".join(f"{v:.3g}" for v in o["rmse_seeds"]) if o["n_seeds"] > 1 else ""
            out.append(f"| {d['cost_label']} | {_t1_name(col, o)} | {o['mean_n_iter']:.3g} | "
                       f"{'n/a' if spent is None else format(spent, '.3g')} | {o['cost_charged']:.4g} | "
                       f"{100 * o['divergent_frac']:.2g} % | {seeds} |")
    return "\n".join(out) + "\n"


def claims_md(cl: dict) -> str:
    head = md_table(["claim", "experiment", "comparison", "metric", "ours a / b (IQM)",
                     "a - b, IQM [seed-level 95% CI]", "mean difference [CI]", "seeds holding alone", "verdict"])
    rows = []
    for k in ("C1", "C2", "C3a", "C3b", "C4", "C5", "C6"):
        for r in cl.get(k, []):
            held = "" if r.get("seeds_holding") is None else f"{r['seeds_holding']}/{r['n_seeds']}"
            rows.append(f"| {k} | {r['experiment']} | {r['claim']} | {metric_label(r)} | "
                        f"{r['a_value']:.4g} / {r['b_value']:.4g} | {r['diff']:+.4g} [{r['ci'][0]:+.4g}, {r['ci'][1]:+.4g}] "
                        f"| {r['mean_diff']:+.4g} [{r['mean_ci'][0]:+.4g}, {r['mean_ci'][1]:+.4g}] | {held} "
                        f"| {verdict_text(r)} |")
    return "\n".join(head + rows) + "\n"


#: The claims in the order the report lists them.
CLAIM_KEYS = ("C1", "C2", "C3a", "C3b", "C4", "C5", "C6")


def claim_rows(cl: dict, keys=CLAIM_KEYS, experiments=None, metrics=None) -> list[dict]:
    """The comparisons of the claims ``keys`` in ``cl`` (:func:`adaptfilt.experiments.claims.claims`,
    or ``artefacts.load_claims()``), kept when their experiment is in ``experiments`` and their
    metric in ``metrics`` (``None``: all); each returned row carries its claim as ``"key"``.

    >>> rows = claim_rows(artefacts.load_claims(), ["C6"], experiments=["ungm-ukf"])  # doctest: +SKIP
    """
    keys = [keys] if isinstance(keys, str) else list(keys)
    unknown = [k for k in keys if k not in CLAIM_KEYS]
    if unknown:
        raise ValueError(f"unknown claim {unknown[0]!r}; the claims are {', '.join(CLAIM_KEYS)}")
    return [{**r, "key": k} for k in keys for r in cl.get(k, [])
            if (experiments is None or r["experiment"] in experiments) and (metrics is None or r["metric"] in metrics)]


def _better(row: dict) -> str:
    """The claim of a row (:func:`adaptfilt.experiments.claims.claim_of`)."""
    from adaptfilt.experiments.claims import claim_of

    return claim_of(row)


def _phrase(row: dict) -> str:
    b = _better(row)
    return f"{row['a']} {'equal to' if b == 'equal' else b + ' than'} {row['b']}"


def claims_subset_md(cl: dict, keys=CLAIM_KEYS, experiments=None, metrics=None, results: dict | None = None,
                     digits: int = 4) -> str:
    r"""A subset of the claims as one Markdown table (rows of :func:`claim_rows`).

    Columns: the claim, the comparison "a vs b" (an experiment column only when the rows
    span several experiments), the metric, both sides' IQM over training seeds, the
    difference ``a - b`` with its two-level (seeds x runs) 95 % interval, how many seeds
    hold the claim on their own, and the verdict. With ``results``
    (``{experiment: Results}``) every row is first re-derived from the evaluation by
    :func:`adaptfilt.experiments.claims.compare`, and a row that differs raises
    ``ValueError`` naming it: the table then shows the data's numbers, not a copy.

    >>> from IPython.display import Markdown                                 # doctest: +SKIP
    >>> Markdown(claims_subset_md(artefacts.load_claims(), ["C1", "C2"], ["ungm-ukf"]))  # doctest: +SKIP
    """
    rows = claim_rows(cl, keys, experiments, metrics)
    if not rows:
        raise ValueError(f"no claim rows for claims {list(keys)}, experiments {experiments}, metrics {metrics}")
    if results is not None:
        from adaptfilt.experiments.claims import compare

        for r in rows:
            if r["experiment"] not in results:
                raise ValueError(f"{r['key']} {r['claim']} ({r['experiment']}): no results given for this experiment")
            new = compare(results[r["experiment"]], r["a"], r["b"], r["metric"], better=_better(r),
                          declared=r.get("declared"))
            got = [new["a_value"], new["b_value"], new["diff"], *new["ci"]]
            want = [r["a_value"], r["b_value"], r["diff"], *r["ci"]]
            if not np.allclose(got, want, rtol=1e-9, atol=0) or new["verdict"] != r["verdict"]:
                raise ValueError(f"{r['key']} {r['claim']} on {r['metric']} ({r['experiment']}): the stored row "
                                 f"{want} ({r['verdict']}) differs from the results {got} ({new['verdict']})")
    several = len({r["experiment"] for r in rows}) > 1
    head = ["claim"] + (["experiment"] if several else []) + \
        ["comparison", "metric", "a / b (IQM)", "a - b [95 % CI]", "seeds alone", "verdict"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    g = f".{digits}g"
    for r in rows:
        held = "" if r.get("seeds_holding") is None else f"{r['seeds_holding']}/{r['n_seeds']}"
        cells = [r["key"]] + ([r["experiment"]] if several else []) + [
            _phrase(r), metric_label(r), f"{r['a_value']:{g}} / {r['b_value']:{g}}",
            f"{r['diff']:+.3g} [{r['ci'][0]:+.3g}, {r['ci'][1]:+.3g}]", held, f"**{verdict_text(r)}**"]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def recon_md(rec: dict) -> str:
    rows = md_table(["variant", "filter", "T", "RMSE full", "per component", "position", "velocity",
                     "median run RMSE", "RMSE k>50", "ANEES"])
    for r in rec["rows"]:
        rows.append(f"| {r['description']} | {r['filter']} | {r['n_steps']} | {r['rmse']:.3g} | "
                    f"{r['rmse_per_component']:.3g} | {r['rmse_pos']:.3g} | {r['rmse_vel']:.3g} | "
                    f"{r['rmse_run_median']:.3g} | {r['rmse_after50']:.3g} | {r['anees']:.3g} |")
    n = rec["rows"][0]["n_runs"] if rec["rows"] else 0
    return f"M = {n} runs per row, seed {rec['seed']}; paper's Table I RMSE: 5.6-6.9.\n\n" + "\n".join(rows) + "\n"


def timings_md(timings: dict) -> str:
    rows = md_table(["stage", "wall time (s)", "CPU time (s)", "note"])
    for k, v in timings.items():
        rows.append(f"| {k} | {v.get('wall_time_s', float('nan')):.0f} | {v.get('cpu_time_s', float('nan')):.0f} "
                    f"| {v.get('note', '')} |")
    return "\n".join(rows) + "\n"


def report_tables(results: dict, floor: dict | None, t1: dict, claims: dict, rec: dict | None, timings: dict,
                  extra: dict[str, str] | None = None) -> str:
    """Every table REPRODUCTION.md embeds, as one Markdown document."""
    parts = ["<!-- generated by `adaptfilt reproduce`: do not edit by hand -->\n"]
    for e, res in results.items():
        parts.append(f"### {e}\n\n" + summary_md(res, floor if e == "ungm-ukf" else None))
    parts.append("### Table I\n\n" + table1_md(t1))
    parts.append("### Claims (fast trainer, seed level)\n\n" + claims_md(claims))
    if "faithful" in claims:
        parts.append("### Claims, paper-faithful training (seed level)\n\n" + claims_md(claims["faithful"]))
    for title, md in (extra or {}).items():
        parts.append(f"### {title}\n\n{md}")
    if rec is not None:
        parts.append("### CTM reconciliation\n\n" + recon_md(rec))
    parts.append("### Stage times\n\n" + timings_md(timings))
    return "\n".join(parts)


def replace_sections(tables_md: str, sections: dict[str, str]) -> str:
    """``tables_md`` (:func:`report_tables`' document) with the body of each ``### title`` section named in
    ``sections`` replaced; a title the document lacks is an error (nothing is appended)."""
    parts = tables_md.split("\n### ")
    titles = [p.split("\n", 1)[0] for p in parts]
    missing = [t for t in sections if t not in titles[1:]]
    if missing:
        raise ValueError(f"no section {missing[0]!r} in the report's tables; have: {', '.join(titles[1:])}")
    return "\n### ".join(p if i == 0 or titles[i] not in sections else f"{titles[i]}\n\n{sections[titles[i]]}"
                         for i, p in enumerate(parts))


def figure_policies(res) -> list[str]:
    """The policies Figures 1-6 show: every policy, but of those fixed in *both* steps only the
    best by RMSE (``fixed-both-*``: a second line of fixed values would double the figure)."""
    both = [n for n in res.names if n.startswith("fixed-both-")]
    keep = {res.best_fixed("rmse", both_steps=True)} if both else set()
    return [n for n in res.names if not n.startswith("fixed-both-") or n in keep]


def figures(results: dict, floor: dict | None, fig_dir: Path) -> list[Path]:
    """Figures 1-6 (per-seed points beside the aggregates) and the choices of one seed per learned group,
    drawn in matplotlib's own defaults whatever style the calling process set (``style.use()`` in a
    notebook, or an earlier test): the manifest records their bytes."""
    import matplotlib

    with matplotlib.rc_context():
        matplotlib.rcdefaults()
        return _figures(results, floor, fig_dir)


def _figures(results: dict, floor: dict | None, fig_dir: Path) -> list[Path]:
    from adaptfilt.plots import plot_anees_bars, plot_choices, plot_rmse_bars, plot_tradeoff, plt

    from adaptfilt.seed_stats import collapse_seeds

    fig_dir = Path(fig_dir)
    fig_dir.mkdir(parents=True, exist_ok=True)
    full, results = results, {e: collapse_seeds(r) for e, r in results.items()}
    specs = []
    if "ungm-ukf" in results:
        f = None if floor is None else floor["rmse"]
        r = results["ungm-ukf"]
        specs += [("fig1-ungm-ukf-rmse", plot_rmse_bars(r, figure_policies(r), floor=f)),
                  ("fig2-ungm-ukf-anees", plot_anees_bars(r, figure_policies(r))),
                  ("fig3-ungm-ukf-rmse-anees", plot_tradeoff(r, figure_policies(r), floor=f))]
    if "ctm-ukf" in results:
        r = results["ctm-ukf"]
        specs += [("fig4-ctm-ukf-rmse", plot_rmse_bars(r, figure_policies(r))),
                  ("fig5-ctm-ukf-anees", plot_anees_bars(r, figure_policies(r))),
                  ("fig6-ctm-ukf-rmse-anees", plot_tradeoff(r, figure_policies(r)))]
    for e, r in full.items():
        for k in ("adaptive", "adaptive-faithful"):
            try:
                first = members(r, k)[0]
            except KeyError:
                continue
            specs.append((f"choices-{e}-{k}", plot_choices(r, first)))
    out = []
    for stem, fig in specs:
        p = fig_dir / f"{stem}.png"
        atomic_savefig(fig, p, dpi=110)
        plt.close(fig)
        out.append(p)
    return out


def embed_report_tables(report_md: str | Path = "REPRODUCTION.md", tables_md: str | Path | None = None) -> None:
    """Replace the generated part of ``REPRODUCTION.md`` (between the BEGIN/END
    report-tables markers) by ``report-tables.md`` (default: ``data/report-tables.md``),
    so that the report's tables are exactly the stored numbers."""
    from adaptfilt.experiments.artefacts import data_dir

    report_md = Path(report_md)
    tables = Path(tables_md) if tables_md is not None else data_dir() / "report-tables.md"
    text = report_md.read_text()
    i, j = text.index(BEGIN_MARK), text.index(END_MARK)
    atomic_write(report_md, text[:i + len(BEGIN_MARK)] + "\n" + tables.read_text().rstrip() + "\n" + text[j:])
