"""Which SB3 setting makes a fast trainer as good as Algorithm 2, at the seed level.

Algorithm 2 as printed takes one Adam step per transition (5x10^5 steps of lr 1e-4 / 5e-4 for a UNGM
policy); the first fast mode (:data:`adaptfilt.trainers.A2C_FAST`: 64 runs x 5-step returns per update)
takes about 1600 RMSprop steps of lr 7e-4 for the same transitions and learns less; PPO with its
defaults learns more but takes about 700 s. This trains variants of both (how many updates, how large,
how much exploration; ``ppo-fast`` is today's fast mode, :data:`adaptfilt.trainers.FAST`), --seeds
seeds each, on one experiment; evaluates them with
the stored paper-faithful policies (``data/policies/<exp>-adaptive-faithful-s*.npz``) and the baselines
on the same M paired runs; and prints the IQM over seeds [two-level 95 % CI] of the objective (mean
log(1 + L)), cost, RMSE and ANEES, each variant minus faithful, and the mean training wall time per
policy measured in this run (one torch thread per worker; compare times of one run only):

    python benchmarks/bench_fast_tuning.py --exp ungm-ukf [--seeds 8] [--runs 2000] [--variants a2c,ppo-fast]

A choice must not be judged on the runs it was made on: the variants train on *selection* seeds
(``--first-seed``, default 100: never one of the reproduction's training seeds 0-7) and are compared on
*selection* runs (``--eval-seed``, default 1: not the reproduction's evaluation seed 0). The faithful
reference is the stored ``adaptive-faithful-s0..`` group (it is not being chosen).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

VARIANTS = {
    "a2c": ("a2c", 64, {"n_steps": 5, "ent_coef": 1e-3}),             # the first fast mode (A2C_FAST)
    "envs16": ("a2c", 16, {"n_steps": 5, "ent_coef": 1e-3}),          # 4x the updates, 1/4 the batch
    "envs16-lr2e-3": ("a2c", 16, {"n_steps": 5, "ent_coef": 1e-3, "learning_rate": 2e-3}),
    "lr3e-3": ("a2c", 64, {"n_steps": 5, "ent_coef": 1e-3, "learning_rate": 3e-3}),
    "envs8": ("a2c", 8, {"n_steps": 5, "ent_coef": 1e-3}),
    "ent1e-2": ("a2c", 64, {"n_steps": 5, "ent_coef": 1e-2}),
    "envs16-ent1e-2": ("a2c", 16, {"n_steps": 5, "ent_coef": 1e-2}),
    # PPO: its defaults (16 runs x 2048 steps, 10 epochs of minibatches of 64, lr 3e-4) learn best but
    # take about 700 s; these trade epochs and minibatch size for time (the chosen one is "ppo-fast").
    "ppo-fast": ("ppo", 256, {"n_steps": 64, "batch_size": 2048, "n_epochs": 5, "learning_rate": 2e-3}),
    "ppo-e10": ("ppo", 256, {"n_steps": 64, "batch_size": 2048, "n_epochs": 10, "learning_rate": 1e-3}),
    "ppo-b4096": ("ppo", 256, {"n_steps": 64, "batch_size": 4096, "n_epochs": 5, "learning_rate": 1e-3}),
    "ppo-roll32": ("ppo", 256, {"n_steps": 32, "batch_size": 2048, "n_epochs": 5, "learning_rate": 1e-3}),
    "ppo-envs128": ("ppo", 128, {"n_steps": 64, "batch_size": 1024, "n_epochs": 5, "learning_rate": 2e-3}),
    "ppo-envs64-e3": ("ppo", 64, {"n_steps": 64, "batch_size": 1024, "n_epochs": 3, "learning_rate": 1e-3}),
}


#: Selection seeds (module docstring): disjoint from the reproduction's training seeds and evaluation seed.
FIRST_SEED, EVAL_SEED = 100, 1


def train_variant(exp: str, variant: str, seed: int, out: str) -> tuple[str, float]:
    import torch

    from adaptfilt.trainers import SB3Config, train_sb3

    torch.set_num_threads(1)
    algo, n_envs, kw = VARIANTS[variant]
    t = time.perf_counter()
    pol = train_sb3(exp, 0.5, 1000, seed, SB3Config(algo, n_envs, kw), progress=False, name=f"{variant}-s{seed}")
    wall = time.perf_counter() - t
    pol.save(out)
    return out, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exp", default="ungm-ukf")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--runs", type=int, default=2000)
    ap.add_argument("--first-seed", type=int, default=FIRST_SEED, help="training seeds of the variants start here")
    ap.add_argument("--eval-seed", type=int, default=EVAL_SEED, help="seed of the evaluation runs")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default="bench-out/fast-tuning")
    args = ap.parse_args()
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.seed_stats import aggregate, difference
    from adaptfilt.experiments.sweep import run_jobs
    from adaptfilt.learned import load_policy

    variants = [v for v in args.variants.split(",") if v]
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        ap.error(f"unknown variants {unknown}; choose from {sorted(VARIANTS)}")
    out = Path(args.out) / args.exp
    out.mkdir(parents=True, exist_ok=True)
    times_file = out / "times.json"
    times = json.loads(times_file.read_text()) if times_file.exists() else {}
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    if args.first_seed < 8 or args.eval_seed == 0:
        print("warning: selection seeds overlap the reproduction's (training 0-7, evaluation 0): "
              "the choice would be judged on the runs it is made on")
    jobs = [(args.exp, v, s, str(out / f"{v}-s{s}.npz")) for v in variants for s in seeds
            if not (out / f"{v}-s{s}.npz").exists()]
    for path, wall in run_jobs(train_variant, jobs, workers=args.workers, desc="train variants"):
        times[Path(path).stem] = wall
    times_file.write_text(json.dumps(times, indent=1))

    exp = get_experiment(args.exp)
    pols = [p for p in exp.baselines() if p.name in ("default", "greedy", "ml")]
    groups = {"faithful": [f"adaptive-faithful-s{s}" for s in range(args.seeds)]}
    pols += [load_policy(Path("data/policies") / f"{args.exp}-{n}.npz", experiment=args.exp, name=n)
             for n in groups["faithful"]]
    for v in variants:
        groups[v] = [f"{v}-s{s}" for s in seeds]
        pols += [load_policy(out / f"{n}.npz", experiment=args.exp, name=n) for n in groups[v]]
    res = evaluate(exp, pols, n_runs=args.runs, seed=args.eval_seed)
    print(f"\n{args.exp}, gamma 0.5, {args.seeds} seeds per group (variants: training seeds {seeds.start}-{seeds.stop - 1}), "
          f"M = {args.runs} paired runs (evaluation seed {args.eval_seed})\n")
    print("| group | wall s/policy | objective | cost | RMSE | ANEES | minus faithful: objective | cost | RMSE | ANEES |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    metrics = ("objective", "cost", "rmse", "anees")
    for g, names in groups.items():
        cells = []
        for m in metrics:
            a = aggregate(res, names, m)
            cells.append(f"{a.iqm:.4g} [{a.iqm_ci[0]:.4g}, {a.iqm_ci[1]:.4g}]")
        diffs = [""] * 4 if g == "faithful" else [
            "{:+.3g} [{:+.3g}, {:+.3g}]".format(*difference(res, names, groups["faithful"], m)["iqm"]) for m in metrics]
        w = [times[n] for n in names if n in times]
        wall = f"{sum(w) / len(w):.1f}" if w else ""
        print(f"| {g} | {wall} | " + " | ".join(cells + diffs) + " |")
    for n in ("default", "ml", "greedy"):
        if n in res.names:
            p = res[n]
            print(f"| {n} | | {p.objective:.4g} | {p.cost:.4g} | {p.rmse:.4g} | {p.anees:.4g} | | | | |")


if __name__ == "__main__":
    main()
