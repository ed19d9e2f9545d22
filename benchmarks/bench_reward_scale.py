"""The untransformed cost with its scale bounded: PPO on -L with SB3's reward normalisation.

    python benchmarks/bench_reward_scale.py [--exp ungm-ukf ctm-ukf] [--seeds 8] [--runs 2000]

Study 4 beyond the paper (``adaptfilt beyond --studies raw``) trains on -L itself: on UNGM learning
fails, on the CTM the policies become nearly constant. This probe keeps the reward -L but lets
``stable_baselines3.common.vec_env.VecNormalize`` divide it by a running estimate of the return's
standard deviation (``norm_reward=True``, observations untouched: they are already scaled), with
the reproduction's recipe otherwise (the PPO fast mode, gamma 0.5, 1000 episodes). It prints, on
``--runs`` paired runs (seed 0), the seed-level lines of these ``norm`` policies beside the stored
log-trained (``data/policies``) and raw-trained (``data/beyond/policies``) ones, greedy, ML and the
default, and the differences norm minus log and norm minus greedy with their seed-level intervals.
Nothing is stored: a probe, about 6 minutes on 2 cores for both experiments.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path


def train_norm(experiment: str, seed: int, out: str) -> str:
    """One PPO fast-mode policy on -L with reward normalisation (module level: runs in a worker)."""
    from adaptfilt.trainers import train_sb3

    train_sb3(experiment, 0.5, 1000, seed, progress=False, cost_transform="none", normalize_reward=True,
              name=f"norm-s{seed}").save(out)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exp", nargs="+", default=["ungm-ukf", "ctm-ukf"])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--runs", type=int, default=2000)
    args = ap.parse_args()
    from adaptfilt.experiments import artefacts
    from adaptfilt.course import seed_results
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.seed_stats import difference
    from adaptfilt.experiments.sweep import run_jobs
    from adaptfilt.learned import load_policy

    tmp, data, seeds = Path(tempfile.mkdtemp(prefix="reward-scale-")), artefacts.data_dir(), range(args.seeds)
    for e in args.exp:
        outs = run_jobs(train_norm, [(e, s, str(tmp / f"{e}-norm-s{s}.npz")) for s in seeds], desc=f"train {e}")
        exp = get_experiment(e)
        pols = [p for p in exp.baselines() if p.name in ("greedy", "ml", "default")]
        pols += [load_policy(o, experiment=exp, name=f"norm-s{s}") for s, o in zip(seeds, outs)]
        for kind, root in (("adaptive", data), ("adaptive-raw", data / "beyond")):
            pols += [load_policy(root / f"policies/{e}-{kind}-s{s}.npz", experiment=exp, name=f"{kind}-s{s}")
                     for s in seeds]
        res = evaluate(exp, pols, n_runs=args.runs, seed=0, progress=False)
        print(f"\n{e}, M = {args.runs}\n" + seed_results.seed_lines(res, ["norm", "adaptive-raw", "adaptive"],
                                                       ["greedy", "ml", "default"], ("cost", "objective", "rmse", "anees")))
        norm = [f"norm-s{s}" for s in seeds]
        for m in ("cost", "rmse", "anees"):
            for label, ref in (("log-trained", [f"adaptive-s{s}" for s in seeds]), ("greedy", ["greedy"])):
                d = difference(res, norm, ref, m)["iqm"]
                print(f"{m}: norm - {label} {d[0]:+.4g} [{d[1]:+.4g}, {d[2]:+.4g}]")


if __name__ == "__main__":
    main()
