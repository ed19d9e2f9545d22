"""Learned policies anchored on greedy against greedy, seed by seed (study 5, the anchored learner).

    python benchmarks/bench_anchor.py --out results/anchor [--experiments ungm-ukf ctm-ukf]
        [--seeds 0-7] [--runs 10000] [--eval-seed 0] [--strength 3] [--kl 0.01] [--shield 1]
        [--features cand|paper] [--cost-transform log1p|none] [--episodes 1000] [--gamma 0.5]
        [--horizon T] [--workers 2] [--tag anchored]

Trains one anchored policy per seed and experiment (:mod:`adaptfilt.anchor`: a residual over greedy's
choice with strength ``c`` and the penalty ``beta KL(pi || pi_0)``, the PPO fast mode, on the
candidate-aware information state unless ``--features paper``), with the command recorded in each
file, into ``OUT/policies/EXP-TAG-sN.npz`` (a file already there with the same command is reused),
then evaluates them with greedy, ML and the default on ``--runs`` paired runs (``--eval-seed``: 1,
the selection runs, while a recipe is chosen; 0, the evaluation runs, once for the chosen one) and
prints, per experiment:

* per seed: cost, cost / RMSE / ANEES minus greedy with their run-level paired 95 % intervals,
  divergent runs, the share of steps on which the policy chose as greedy (on the first 200 runs),
  the training wall and CPU time;
* over seeds: IQM of the differences to greedy with the two-level bootstrap interval
  (:mod:`adaptfilt.seed_stats`; greedy is one policy, so only the anchored seeds are resampled),
  and the verdicts of the goal: cost lower than greedy on every seed (each seed's own interval below 0),
  RMSE and ANEES not worse (seed level, by the one rule with the margins declared for
  "anchored vs greedy" in ``adaptfilt.verdicts.DECLARED_MARGINS``), no divergent run;
* with ``--compare TAG=DIR``, another group of policies of the same seeds on the same runs, against
  greedy and against this one.

The evaluation (``OUT/results/EXP``, :meth:`~adaptfilt.evaluation.Results.save`) and the table
(``OUT/summary-EXP.md``, ``OUT/summary.json``) are written too.

Measured 2026-11-25 (2 cores shared with a data regeneration, load 3-9; c = 3, beta = 0.01, gamma 0.5,
1000 episodes, the candidate-aware state; differences to greedy, IQM over seeds [two-level 95 % CI]):

Choosing the recipe (tuning seeds 100-103, selection runs: ``--seeds 100-103 --runs 2000 --eval-seed 1``):

(the runs without ``--shield`` had no shield: the library's default then, ``--shield 0`` now)

* PPO, anchored: UNGM -0.075 [-0.081, -0.065] (4 of 4 seeds lower, 98.5 % as greedy);
  CTM +0.35 [-0.13, +1.31] (0 of 4 lower, 99.8 % as greedy);
* the same with ``--shield 1``: UNGM -0.071 [-0.083, -0.065] (4 of 4); CTM +0.47 [-0.05, +1.43] (0 of 4);
* CTM only: ``--cost-transform none`` +0 [+0, +0.26] (3 of 4 seeds act exactly as greedy, one worse);
  ``--episodes 4000`` +0.54 [-0.13, +1.53] (97-99 % as greedy); ``--strength 1`` +1.16 [+0.30, +2.22]
  (85-89 % as greedy): the further from greedy, the dearer; ``--method distill --kl 1`` (2 seeds)
  +0.46 [-0.01, +1.42] (97 % as greedy).

The rollout reference, not learned (:mod:`adaptfilt.lookahead`, H = 1, S = 4, 400 selection runs of
the CTM): cost -1.31 [-2.88, -0.12], RMSE -1.65 [-3.54, +0.05] against greedy (paired runs).

Final check, 8 seeds (0-7), M = 10^4: ``--seeds 0-7 --runs 10000 --eval-seed 0 --shield 0`` (PPO,
anchored, no shield: the library's default then; evaluation seed 0, once):

* UNGM-UKF: 7 of 8 seeds lower in cost (-0.064 to -0.084, each run-level interval below 0); seed 0 has
  a mean cost of 331 (+331 [+305, +356]) while its RMSE (-0.046) and ANEES (-3.3) are lower than
  greedy's. On 2000 selection runs (seed 1) the same policy leaves greedy on 1.3 % of its steps and
  its 976 steps that cost more than 10^3 (up to 1.9x10^6) are all steps where it chose kappa = 50 and
  greedy's kappa = 10^4 would have cost 56-132: the damage is done at the deviating step itself.
  IQM cost -0.071 [-0.076, +83.8], RMSE -0.080 [-0.091, -0.063], ANEES -3.84 [-3.99, -3.55]; no
  divergent run; 97-99 % of the steps as greedy; 26-30 CPU-s per policy.
* CTM-UKF: 1 of 8 seeds lower (none with its interval below 0); IQM cost +0.145 [-0.007, +0.329],
  RMSE +0.060 [-0.051, +0.335], ANEES +0.063 [+0.017, +0.110] (not worse within the margins); no
  divergent run; 99.5-99.8 % as greedy; 12-15 CPU-s per policy.

Final check of the chosen recipe, the shield added (``--shield 1``, chosen a priori: a deviation may
cost at most e times greedy's ``1 + L`` at its step; checked on the tuning seeds only for not losing
UNGM's gain), 8 seeds retrained, on *fresh* runs never used before (``--eval-seed 2``), beside the
unshielded policies (``--compare anchored=...``): ``--seeds 0-7 --runs 10000 --eval-seed 2 --shield 1
--tag shielded --compare anchored=DIR``

* UNGM-UKF: **8 of 8 seeds lower in cost**, each with its run-level interval below 0 (-0.068 to
  -0.083); IQM cost -0.078 [-0.082, -0.074], RMSE -0.091 [-0.100, -0.082], ANEES -4.05 [-4.18, -3.88];
  no divergent run; 97.8-98.9 % of the steps as greedy; 31-33 CPU-s per policy. The unshielded
  policies on the same runs: seed 0 again +345, the other seven -0.064 to -0.083.
* CTM-UKF: 1 of 8 seeds lower (-0.008 [-0.19, +0.20]), none with its interval below 0; IQM cost
  +0.178 [-0.027, +0.413], RMSE +0.076 [-0.080, +0.514], ANEES +0.055 [+0.006, +0.124] (not worse
  within the margins); no divergent run; 99.6-99.9 % as greedy; 13-16 CPU-s per policy. The shield
  changes nothing measurable here (shielded - unshielded: -0.022 [-0.24, +0.22]).

Why the CTM goal is not met (selection runs, seed 1, M = 2000, the shielded seed-2 policy, +1.19 against
greedy there): it leaves greedy on 0.41 % of its steps; all of its extra cost comes from the 831 runs
with a deviation, about 30 % of it at the deviating steps themselves (+87 on average, allowed by the
shield because greedy's own cost is already large there) and the rest in later steps; the largest
differences are in runs where greedy too has steps that cost 10^3-10^4. The learner trains on
log(1 + L), which barely separates 10^4 from 4x10^4, and finds no gain on it either (objective
+0.0004 [-0.0002, +0.0010]); the rollout reference shows that a gain in mean cost exists, but neither
PPO nor the distillation of rollout's Q-values into the candidate-aware state recovers it.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

CAND = {"ungm-ukf": "paper+time+cand", "ctm-ukf": "paper+circ+cand"}


#: The declared comparison (adaptfilt.verdicts.DECLARED_MARGINS) whose margins judge "not worse".
DECLARED = "anchored vs greedy"

def train_one(experiment: str, seed: int, out: str, kw: dict, command: str, method: str = "ppo") -> dict:
    """One anchored policy (module level: runs in a worker); reused when ``out`` holds this command."""
    from adaptfilt.distill import distill_rollout
    from adaptfilt.files import read_npz
    from adaptfilt.trainers import train_policy

    if Path(out).exists():
        _, meta = read_npz(out)
        if meta.get("command") == command:
            return {"reused": True, "wall_time_s": float("nan"), "cpu_time_s": float("nan")}
    t0, c0 = time.perf_counter(), time.process_time()
    if method == "ppo":
        train_policy(experiment, "fast", seed=seed, progress=False, out=out, command=command, **kw)
    else:
        distill_rollout(experiment, seed, command=command, **kw).save(out)
    return {"reused": False, "wall_time_s": time.perf_counter() - t0, "cpu_time_s": time.process_time() - c0}


def agreement(exp, pol, runs: int, seed: int, n_steps: int | None) -> float:
    """Share of (run, step) pairs, along the policy's own trajectories, on which it chose as greedy."""
    import numpy as np

    from adaptfilt.anchor import greedy_index
    from adaptfilt.policies import grid_indices

    env = exp.make_env(n_steps=n_steps)
    d, same, n = env.reset(n_runs=runs, rng=np.random.default_rng([0xA9, seed]), stream=seed), 0, 0
    while d is not None:
        a = pol.act(d)
        g = grid_indices(pol.grid, d.grid)[greedy_index(d, pol.grid)]
        same, n = same + int((a == g).sum()), n + a.size
        d, _, _, _ = env.step(a)
    return same / n


def _seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--experiments", nargs="+", default=["ungm-ukf", "ctm-ukf"], choices=sorted(CAND))
    ap.add_argument("--seeds", type=_seeds, default=list(range(8)))
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--eval-seed", type=int, default=0)
    ap.add_argument("--strength", type=float, default=None, help="anchor strength c (default: the library's)")
    ap.add_argument("--kl", type=float, default=None, help="KL coefficient beta (default: the library's)")
    ap.add_argument("--shield", type=float, default=None, help="anchor shield (default: the library's; 0: none)")
    ap.add_argument("--features", choices=("cand", "paper"), default="cand")
    ap.add_argument("--cost-transform", choices=("log1p", "none"), default="log1p")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--gamma", type=float, default=0.5)
    ap.add_argument("--horizon", type=int, default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--agree-runs", type=int, default=200)
    ap.add_argument("--tag", default="anchored")
    ap.add_argument("--method", choices=("ppo", "distill"), default="ppo",
                    help="ppo: train_policy(..., anchor='greedy'); distill: adaptfilt.distill.distill_rollout")
    ap.add_argument("--distill-runs", type=int, default=500)
    ap.add_argument("--teacher", default="1:4", help="distill: rollout H:S")
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--compare", action="append", default=[], metavar="TAG=DIR",
                    help="also evaluate DIR/policies/EXP-TAG-sN.npz (same seeds) on the same runs (repeatable)")
    args = ap.parse_args(argv)

    import numpy as np

    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.seed_stats import difference
    from adaptfilt.verdicts import DECLARED_MARGINS, judge, margin, verdict
    from adaptfilt.experiments.sweep import run_jobs
    from adaptfilt.learned import load_policy

    out = Path(args.out)
    (out / "policies").mkdir(parents=True, exist_ok=True)
    summary: dict = {"args": vars(args), "experiments": {}}
    for e in args.experiments:
        exp = get_experiment(e)
        feats = CAND[e] if args.features == "cand" else exp.features
        kw = {"gamma": args.gamma, "episodes": args.episodes, "features": feats, "n_steps": args.horizon,
              "anchor": "greedy", "anchor_strength": args.strength, "anchor_kl": args.kl, "anchor_shield": args.shield,
              "cost_transform": args.cost_transform}
        jobs = []
        if args.method == "distill":
            H, S = (int(x) for x in args.teacher.split(":"))
            kw = {"runs": args.distill_runs, "features": feats, "n_steps": args.horizon, "horizon": H, "samples": S,
                  "gamma": args.gamma, "epochs": args.epochs}
            kw.update({k: v for k, v in (("strength", args.strength), ("kl", args.kl)) if v is not None})
        for s in args.seeds:
            f = out / "policies" / f"{e}-{args.tag}-s{s}.npz"
            if args.method == "distill":
                call = ", ".join(f"{k}={v!r}" for k, v in kw.items())
                jobs.append((e, s, str(f), kw, f"adaptfilt.distill.distill_rollout({e!r}, {s}, {call}).save({str(f)!r})",
                             "distill"))
                continue
            cmd = (f"adaptfilt train {e} --algo fast --gamma {args.gamma:g} --episodes {args.episodes} --seed {s} "
                   f"--features {feats}" + (f" --horizon {args.horizon}" if args.horizon else "")
                   + (f" --cost-transform {args.cost_transform}" if args.cost_transform != "log1p" else "")
                   + " --anchor greedy" + (f" --anchor-strength {args.strength:g}" if args.strength is not None else "")
                   + (f" --anchor-kl {args.kl:g}" if args.kl is not None else "")
                   + (f" --anchor-shield {args.shield:g}" if args.shield is not None else "") + f" --out {f}")
            jobs.append((e, s, str(f), kw, cmd))
        t0 = time.perf_counter()
        times = run_jobs(train_one, jobs, workers=args.workers, desc=f"train {e}")
        train_wall = time.perf_counter() - t0
        names = [f"{args.tag}-s{s}" for s in args.seeds]
        pols = [p for p in exp.baselines() if p.name in ("greedy", "ml", "default")]
        pols += [load_policy(j[2], experiment=exp, name=n) for j, n in zip(jobs, names)]
        n_own = len(pols)
        compare = {}
        for spec in args.compare:
            tag, root = spec.split("=", 1)
            compare[tag] = [f"{tag}-s{s}" for s in args.seeds]
            pols += [load_policy(Path(root) / "policies" / f"{e}-{tag}-s{s}.npz", experiment=exp, name=f"{tag}-s{s}")
                     for s in args.seeds]
        t0 = time.perf_counter()
        res = evaluate(exp, pols, n_runs=args.runs, seed=args.eval_seed, progress=False, n_steps=args.horizon)
        eval_wall = time.perf_counter() - t0
        res.save(out / "results" / e, arrays=False)
        agree = [agreement(exp, p, min(args.agree_runs, args.runs), args.eval_seed, args.horizon) for p in pols[3:n_own]]

        g = res["greedy"]
        how = (f"{args.cost_transform}, gamma {args.gamma:g}, {args.episodes} episodes" if args.method == "ppo" else
               f"distilled from rollout H:S = {args.teacher}, {args.distill_runs} runs, {args.epochs} epochs")
        mine = pols[n_own - 1].anchor  # this group's (the --compare groups come after it)
        shield = mine.shield
        lines = [f"## {e}: {args.tag} ({feats}, c = {mine.strength:g}, beta = {mine.kl:g}, "
                 + (f"shield {shield:g}, " if shield is not None else "") +
                 f"{how}) against greedy, "
                 f"M = {args.runs}, evaluation seed {args.eval_seed}", "",
                 "| policy | cost | cost - greedy | RMSE - greedy | ANEES - greedy | divergent | as greedy | train s (wall / CPU) |",
                 "|---|---|---|---|---|---|---|---|"]
        for b in ("greedy", "ml", "default"):
            p = res[b]
            lines.append(f"| {b} | {p.cost:.4g} | | {p.rmse - g.rmse:+.3g} | {p.anees - g.anees:+.3g} | "
                         f"{p.divergent_frac:.2%} | | |")
        per_seed = []
        for n, a, t in zip(names, agree, times):
            d = {m: res.paired_difference(n, "greedy", m) for m in ("cost", "rmse", "anees")}
            per_seed.append({"name": n, "cost": res[n].cost, "diff": d, "divergent_frac": res[n].divergent_frac,
                             "as_greedy": a, **t})
            cell = lambda x: f"{x[0]:+.3g} [{x[1]:+.3g}, {x[2]:+.3g}]"
            lines.append(f"| {n} | {res[n].cost:.4g} | {cell(d['cost'])} | {cell(d['rmse'])} | {cell(d['anees'])} | "
                         f"{res[n].divergent_frac:.2%} | {a:.1%} | {t['wall_time_s']:.0f} / {t['cpu_time_s']:.0f} |")
        agg = {m: difference(res, names, ["greedy"], m) for m in ("cost", "rmse", "anees", "objective")}
        cell = lambda x: f"{x[0]:+.4g} [{x[1]:+.4g}, {x[2]:+.4g}]"
        lines += ["", "| over seeds, IQM (mean) [two-level 95 % CI] | cost - greedy | RMSE - greedy | ANEES - greedy | log(1+L) - greedy |",
                  "|---|---|---|---|---|",
                  f"| {args.tag}, {len(names)} seeds | " + " | ".join(f"{cell(agg[m]['iqm'])} (mean {agg[m]['mean'][0]:+.4g})"
                                                               for m in ("cost", "rmse", "anees", "objective")) + " |"]
        lower = sum(s["diff"]["cost"][0] < 0 for s in per_seed)
        lower_ci = sum(verdict("lower", s["diff"]["cost"]) == "confirmed" for s in per_seed)
        m_rmse, m_anees = margin(DECLARED, "rmse", g.rmse), margin(DECLARED, "anees", g.anees)
        alone = lambda m, mg: sum(verdict("not worse", s["diff"][m], mg) == "confirmed" for s in per_seed)  # noqa: E731
        verdicts = {
            "cost lower than greedy on every seed": f"{lower} of {len(names)} seeds lower, {lower_ci} with their run-level interval below 0",
            "cost lower, seed level (IQM)": judge("lower", agg["cost"]["iqm"])[0],
            "RMSE not worse (margin 5 %)": judge("not worse", agg["rmse"]["iqm"], DECLARED, "rmse", g.rmse)[0],
            "ANEES not worse (margin 10 %)": judge("not worse", agg["anees"]["iqm"], DECLARED, "anees", g.anees)[0],
            "RMSE not worse on every seed": f"{alone('rmse', m_rmse)} of {len(names)}",
            "ANEES not worse on every seed": f"{alone('anees', m_anees)} of {len(names)}",
            "no divergent run": f"{sum(s['divergent_frac'] > 0 for s in per_seed)} seeds with a divergent run",
        }
        for tag, other in compare.items():
            lines += ["", f"Compared on the same runs: {tag} (per seed, cost - greedy: "
                      + ", ".join(f"{res.paired_difference(n, 'greedy', 'cost')[0]:+.3g}" for n in other) + ")", "",
                      f"| IQM [two-level 95 % CI] | cost | RMSE | ANEES |", "|---|---|---|---|"]
            for label, a, b in ((f"{tag} - greedy", other, ["greedy"]), (f"{args.tag} - {tag}", names, other)):
                lines.append(f"| {label} | " + " | ".join(cell(difference(res, a, b, m)["iqm"])
                                                          for m in ("cost", "rmse", "anees")) + " |")
        lines += [""] + [f"* {k}: **{v}**" for k, v in verdicts.items()]
        lines += [f"* train {train_wall:.0f} s wall for {len(jobs)} policies ({args.workers} workers), "
                  f"evaluate {eval_wall:.0f} s; margins {DECLARED_MARGINS[DECLARED].fractions['rmse']:.0%} RMSE, "
                  f"{DECLARED_MARGINS[DECLARED].fractions['anees']:.0%} ANEES (declared for {DECLARED!r})"]
        text = "\n".join(lines)
        print(text + "\n", flush=True)
        (out / f"summary-{e}.md").write_text(text + "\n")
        summary["experiments"][e] = {"per_seed": per_seed, "aggregate": agg, "verdicts": verdicts,
                                     "greedy": {"cost": g.cost, "rmse": g.rmse, "anees": g.anees},
                                     "train_wall_s": train_wall, "eval_wall_s": eval_wall}
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    return summary


if __name__ == "__main__":
    main()
