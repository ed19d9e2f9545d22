"""What the revised MDP recipe buys, at the seed level: the time feature, the bootstrap at the time limit,
and the feature scaler.

Trains the fast mode (SB3 A2C, :data:`adaptfilt.trainers.FAST`) on UNGM-UKF with gamma 0.5 for --seeds
seeds in each variant and evaluates all of them, with the baselines, on the same M paired runs; prints the
IQM over seeds [two-level 95 % CI] of the objective (mean log(1 + L), what the learners minimise), cost,
RMSE and ANEES, and each variant minus the recipe:

  recipe         paper+time features, scaler on a mix of grid values with asinh, bootstrap at the limit
  no-time        the paper's features (no phase of the UNGM dynamics)
  terminal       the horizon treated as terminal (no bootstrap at T), as the first policies did
  old-scaler     scaler fitted on default-policy states, clipped at +-10, as the first policies did

    python benchmarks/bench_recipe.py [--seeds 8] [--runs 4000] [--out bench-out/recipe]
"""
from __future__ import annotations

import argparse
from pathlib import Path

VARIANTS = {
    "recipe": {},
    "no-time": {"features": "paper"},
    "terminal": {"bootstrap": False},
    "old-scaler": {"scaler": ("default", "clip")},
}


def train_variant(variant: str, seed: int, out: str) -> str:
    import torch

    import adaptfilt.gym as afg
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.features import fit_scaler
    from adaptfilt.trainers import FAST, train_sb3

    torch.set_num_threads(1)
    v = VARIANTS[variant]
    if not v:
        pol = train_sb3("ungm-ukf", 0.5, 1000, seed, FAST, progress=False, name=f"{variant}-s{seed}")
    else:
        # the same training with one ingredient changed, through the adapter's own options
        from stable_baselines3 import A2C
        from stable_baselines3.common.logger import Logger

        exp = get_experiment("ungm-ukf")
        feats = v.get("features", exp.features)
        env = exp.make_env(seed=seed)
        visit, squash = v.get("scaler", ("mix", "asinh"))
        scaler = fit_scaler(env, feats, seed=seed, visit=visit, squash=squash)
        venv = afg.SB3VecEnv(afg.FilterVectorEnv("ungm-ukf", FAST.n_envs, feats, scaler, seed=seed))
        if not v.get("bootstrap", True):
            venv.venv.env = _Terminal(venv.venv.env)
        venv.seed(seed)
        model = A2C("MlpPolicy", venv, gamma=0.5, seed=seed, device="cpu",
                    policy_kwargs={"activation_fn": torch.nn.ReLU, "net_arch": {"pi": [64, 64], "vf": [64, 64]}},
                    **FAST.kwargs)
        model.set_logger(Logger(folder=None, output_formats=[]))  # else an SB3-<time> folder in /tmp per policy
        model.learn(1000 * env.n_steps)
        pol = afg.to_learned_policy(model, venv, gamma=0.5, name=f"{variant}-s{seed}")
    pol.save(out)
    return out


class _Terminal:
    """A FilterEnv whose last step has no next state: learners cannot bootstrap there."""

    def __init__(self, env):
        self._env = env

    def __getattr__(self, name):
        return getattr(self._env, name)

    def step(self, actions, predict_param=None):
        d, cost, done, info = self._env.step(actions, predict_param)
        if done:
            info = {**info, "final_decision": None, "terminated": True, "truncated": False}
        return d, cost, done, info


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--runs", type=int, default=4000)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default="bench-out/recipe")
    args = ap.parse_args()
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.seed_stats import aggregate, difference
    from adaptfilt.experiments.sweep import run_jobs
    from adaptfilt.learned import load_policy

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(v, s, str(out / f"{v}-s{s}.npz")) for v in VARIANTS for s in range(args.seeds)
            if not (out / f"{v}-s{s}.npz").exists()]
    run_jobs(train_variant, jobs, workers=args.workers, desc="train variants")
    exp = get_experiment("ungm-ukf")
    pols = [p for p in exp.baselines() if p.name in ("default", "greedy")]
    groups = {}
    for v in VARIANTS:
        groups[v] = [f"{v}-s{s}" for s in range(args.seeds)]
        pols += [load_policy(out / f"{n}.npz", experiment="ungm-ukf", name=n) for n in groups[v]]
    res = evaluate(exp, pols, n_runs=args.runs, seed=0)
    print(f"\nUNGM-UKF, fast mode, gamma 0.5, {args.seeds} seeds per variant, M = {args.runs} paired runs\n")
    print("| variant | objective | cost | RMSE | ANEES | minus recipe: objective | RMSE | ANEES |")
    print("|---|---|---|---|---|---|---|---|")
    for v, names in groups.items():
        cells = []
        for m in ("objective", "cost", "rmse", "anees"):
            a = aggregate(res, names, m)
            cells.append(f"{a.iqm:.4g} [{a.iqm_ci[0]:.4g}, {a.iqm_ci[1]:.4g}]")
        diffs = []
        for m in ("objective", "rmse", "anees"):
            if v == "recipe":
                diffs.append("")
                continue
            d = difference(res, names, groups["recipe"], m)["iqm"]
            diffs.append(f"{d[0]:+.4g} [{d[1]:+.4g}, {d[2]:+.4g}]")
        print(f"| {v} | " + " | ".join(cells + diffs) + " |")
    for n in ("default", "greedy"):
        p = res[n]
        print(f"| {n} | {p.objective:.4g} | {p.cost:.4g} | {p.rmse:.4g} | {p.anees:.4g} | | | |")


if __name__ == "__main__":
    main()
