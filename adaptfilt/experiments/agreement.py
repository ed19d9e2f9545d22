r"""Do two reproductions reach the same verdicts? Claim by claim, side by side.

A smaller reproduction (``adaptfilt reproduce --scale medium``: half the training
episodes, M = 2000 runs) is a check of the full one only if it reaches the same
seed-level verdicts. :func:`agreement` pairs the comparisons of two
``claims.json`` (:func:`adaptfilt.experiments.claims.claims`) by claim,
experiment, the two sides and the metric, and says for each whether the verdicts
are the same; :func:`agreement_md` is the table ``reproduce`` writes beside its
claims when ``data/`` holds a full-scale reproduction.

>>> full = {"C1": [{"experiment": "e", "a": "adaptive", "b": "ml", "metric": "anees", "diff": -4.0,
...                 "ci": [-4.2, -3.8], "verdict": "confirmed"}]}
>>> agreement(full, full)["n_same"]
1
"""
from __future__ import annotations

from adaptfilt.experiments.report import md_table

__all__ = ["agreement", "agreement_md"]


def _rows(claims: dict) -> dict[tuple, dict]:
    """The verdict rows (an uncharged-cost row, ``role="uncharged"``, is a comparison, not a verdict)."""
    return {(c, r["experiment"], r["a"], r["b"], r["metric"]): r
            for c, rows in claims.items() if isinstance(rows, list)
            for r in rows if isinstance(r, dict) and "verdict" in r and r.get("role", "verdict") == "verdict"}


def agreement(claims: dict, reference: dict) -> dict:
    """Every comparison present in both, with both differences, intervals and verdicts.

    Returns ``{"rows": [...], "n": compared, "n_same": same verdict, "only_here", "only_reference"}``
    (the last two: comparisons that one side lacks, e.g. an experiment left out).
    """
    mine, ref = _rows(claims), _rows(reference)
    rows = []
    for key in (k for k in ref if k in mine):
        a, b = mine[key], ref[key]
        rows.append({"claim": key[0], "experiment": key[1], "a": key[2], "b": key[3], "metric": key[4],
                     "diff": a["diff"], "ci": list(a["ci"]), "verdict": a["verdict"],
                     "ref_diff": b["diff"], "ref_ci": list(b["ci"]), "ref_verdict": b["verdict"],
                     "same": a["verdict"] == b["verdict"]})
    return {"rows": rows, "n": len(rows), "n_same": sum(r["same"] for r in rows),
            "only_here": ["/".join(map(str, k)) for k in mine if k not in ref],
            "only_reference": ["/".join(map(str, k)) for k in ref if k not in mine]}


def agreement_md(agr: dict, here: str = "this run", reference: str = "reference") -> str:
    """The comparison as markdown: a count, then one row per comparison (differing verdicts in bold)."""
    lines = [f"{agr['n_same']} of {agr['n']} seed-level verdicts are the same in {here} and in {reference}.", "",
             *md_table(["claim", "experiment", "comparison", "metric", f"{here}: difference [95% CI]",
                        f"{reference}: difference [95% CI]", "verdicts"])]
    for r in agr["rows"]:
        v = (r["verdict"] if r["same"] else f"**{r['verdict']}** vs **{r['ref_verdict']}**")
        lines.append(f"| {r['claim']} | {r['experiment']} | {r['a']} - {r['b']} | {r['metric']} | "
                     f"{r['diff']:+.4g} [{r['ci'][0]:+.3g}, {r['ci'][1]:+.3g}] | "
                     f"{r['ref_diff']:+.4g} [{r['ref_ci'][0]:+.3g}, {r['ref_ci'][1]:+.3g}] | {v} |")
    return "\n".join(lines) + "\n"
