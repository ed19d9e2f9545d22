"""Peer check of our actor-critic: Stable-Baselines3 PPO and A2C on the same MDP, at the seed level.

Learners (all see the same MDP: the experiment's feature set, the scaler fitted on a mix of grid values,
reward -log(1 + L), the horizon as a time limit; gamma 0.5; networks 2 x 64 ReLU):

  faithful     our Algorithm 2 as printed (the policies in data/: adaptive-faithful-s*)
  fast         our fast mode, SB3 A2C with 5-step returns over 64 runs (data/: adaptive-s*)
  a2c-default  SB3 A2C, its defaults (16 runs per batch, no entropy bonus)
  ppo-default  SB3 PPO, its defaults (16 runs per batch)
  ppo-walltime SB3 PPO (defaults) stopped at the fast mode's mean wall time per policy
(the tuned setting is the fast mode itself: A2C with 5-step returns over 64 runs and the paper's
entropy bonus, chosen by the measurement in REPRODUCTION.md)

each at the paper's budget (1000 episodes: 5x10^5 transitions on UNGM, 1.5x10^5 on CTM) unless stopped by
wall time, on --seeds seeds, evaluated with every baseline on the same M paired runs; prints per learner the
IQM over seeds [two-level 95 % CI] of cost, objective (mean log(1+L)), RMSE and ANEES, the difference to the
faithful trainer, and the mean training wall/CPU time measured in this run (faithful: from data/'s manifest).

    python benchmarks/bench_peers.py [--experiments ungm-ukf ctm-ukf] [--seeds 8] [--seeds-ppo 4] [--runs 10000] [--out bench-out/peers]

Trained policies are cached in --out (delete it to retrain); this takes about an hour of CPU.
--train-only trains (and caches) without evaluating, e.g. before data/ holds the faithful policies.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

LEARNERS = ("a2c-default", "ppo-default", "ppo-walltime")


def train_one(experiment: str, learner: str, seed: int, out: str, wall_budget: float | None) -> dict:
    import torch

    from adaptfilt.trainers import PPO_DEFAULTS, SB3Config, train_sb3

    torch.set_num_threads(1)
    cfg = {"a2c-default": SB3Config("a2c", 16, {}), "ppo-default": PPO_DEFAULTS, "ppo-walltime": PPO_DEFAULTS}[learner]
    t, c = time.perf_counter(), time.process_time()
    pol = train_sb3(experiment, 0.5, 1000, seed, cfg, progress=False, name=f"{learner}-s{seed}",
                    max_seconds=wall_budget if learner == "ppo-walltime" else None)
    times = {"wall_time_s": time.perf_counter() - t, "cpu_time_s": time.process_time() - c,
             "transitions": pol.metadata["transitions"]}
    pol.save(out)
    Path(out + ".json").write_text(json.dumps(times))
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiments", nargs="+", default=["ungm-ukf", "ctm-ukf"])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--seeds-ppo", type=int, default=None,
                    help="seeds for ppo-default only (its 5x10^5 UNGM transitions cost about 750 CPU-s each); default --seeds")
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default="bench-out/peers")
    ap.add_argument("--train-only", action="store_true")
    args = ap.parse_args()
    from adaptfilt.experiments import artefacts
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.seed_stats import aggregate, difference
    from adaptfilt.experiments.sweep import run_jobs
    from adaptfilt.learned import load_policy

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    man = {e["path"]: e for e in artefacts.manifest()["files"]}
    for exp_name in args.experiments:
        fast_walls = [man[f"policies/{exp_name}-adaptive-s{s}.npz"]["wall_time_s"] for s in range(args.seeds)
                      if man.get(f"policies/{exp_name}-adaptive-s{s}.npz", {}).get("wall_time_s")]
        budget = sum(fast_walls) / len(fast_walls) if fast_walls else 15.0
        n_seeds = {lr: args.seeds_ppo if lr == "ppo-default" and args.seeds_ppo else args.seeds for lr in LEARNERS}
        jobs = [(exp_name, lr, s, str(out / f"{exp_name}-{lr}-s{s}.npz"), budget)
                for lr in LEARNERS for s in range(n_seeds[lr]) if not (out / f"{exp_name}-{lr}-s{s}.npz").exists()]
        run_jobs(train_one, jobs, workers=args.workers, desc=f"train peers on {exp_name}")
        if args.train_only:
            continue
        exp = get_experiment(exp_name)
        pols = [p for p in exp.baselines() if not p.name.startswith("fixed")]
        groups = {"faithful": [], "fast": []}
        for kind, g in (("adaptive-faithful", "faithful"), ("adaptive", "fast")):
            for s in artefacts.seeds(exp_name, kind)[:args.seeds]:
                pols.append(artefacts.stored_policy(exp_name, kind, s))
                groups[g].append(pols[-1].name)
        times = {}
        for lr in LEARNERS:
            groups[lr] = []
            for s in range(n_seeds[lr]):
                f = out / f"{exp_name}-{lr}-s{s}.npz"
                pols.append(load_policy(f, experiment=exp_name, name=f"{lr}-s{s}"))
                groups[lr].append(pols[-1].name)
                times.setdefault(lr, []).append(json.loads(Path(str(f) + ".json").read_text()))
        for g, kind in (("faithful", "adaptive-faithful"), ("fast", "adaptive")):
            t = [man[f"policies/{exp_name}-{kind}-s{s}.npz"] for s in range(args.seeds)
                 if man.get(f"policies/{exp_name}-{kind}-s{s}.npz", {}).get("cpu_time_s")]
            times[g] = [{"wall_time_s": e["wall_time_s"], "cpu_time_s": e["cpu_time_s"]} for e in t]
        res = evaluate(exp, pols, n_runs=args.runs, seed=0, progress=True)
        print(f"\n### {exp_name}: M = {args.runs} paired runs, seeds per learner {n_seeds} (faithful, fast: {args.seeds}); "
              f"PPO wall budget {budget:.1f} s\n")
        print("| learner | cost | objective log(1+L) | RMSE | ANEES | minus faithful: objective [95% CI] | "
              "train wall / CPU s | transitions |")
        print("|---|---|---|---|---|---|---|---|")
        for name in ("greedy", "default", "ml"):
            if name in res:
                p = res[name]
                print(f"| {name} | {p.cost:.4g} | {p.objective:.4f} | {p.rmse:.4g} | {p.anees:.4g} | | | |")
        for g, names in groups.items():
            if not names:
                continue
            cells = []
            for m in ("cost", "objective", "rmse", "anees"):
                a = aggregate(res, names, m)
                cells.append(f"{a.iqm:.4g} [{a.iqm_ci[0]:.4g}, {a.iqm_ci[1]:.4g}]")
            d = difference(res, names, groups["faithful"], "objective")["iqm"] if groups["faithful"] and g != "faithful" else None
            ts = times.get(g) or []
            tw = f"{sum(t['wall_time_s'] for t in ts) / len(ts):.0f} / {sum(t['cpu_time_s'] for t in ts) / len(ts):.0f}" if ts else ""
            tr = ts[0].get("transitions", "") if ts else ""
            print(f"| {g} | " + " | ".join(cells) + f" | {'' if d is None else f'{d[0]:+.4f} [{d[1]:+.4f}, {d[2]:+.4f}]'} "
                  f"| {tw} | {tr} |")


if __name__ == "__main__":
    main()
