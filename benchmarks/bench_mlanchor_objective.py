"""Which objective for the ML-anchored learner on the CTM? A probe on selection runs, before the study.

    python benchmarks/bench_mlanchor_objective.py [--seeds 4] [--runs 2000]

The ``mlanchor`` study (``adaptfilt beyond --studies mlanchor``) trains the learner anchored on maximum
likelihood (``adaptfilt.anchor``, ``anchor="ml"``; strength 3, KL weight 0.01, shield 1, the candidate-aware
state, the PPO fast mode, 1000 episodes) on ``log(1 + L)`` and on ``L`` itself, and may add "any objective
found better". This probe trains it with four objectives, ``log(1 + L)`` at gamma 0.5 (the study's), the
same with the reward divided by its running spread (SB3's ``VecNormalize``, ``lognorm``), ``L`` so divided
(``rawnorm``: ``L`` alone leaves the policy at ML, the scale of ``L`` swamps PPO's updates), and
``log(1 + L)`` at gamma 0.9, and prints each group's mean cost per seed and its IQM minus ML's (seed-level
95 % interval) in cost and ``log(1 + L)`` on ``--runs`` *selection* runs (seed 1: not the evaluation's).

Measured (2026-12, 4 seeds, 2000 runs, 2 shared cores, about 12 minutes; ML 3.596, greedy 4.769)::

    lognorm [3.331, 4.091, 4.112, 3.413] IQM-ml cost [ 0.155 -0.589  0.802] obj [0.0042 0.0005 0.0066]
    rawnorm [3.596, 3.792, 3.596, 3.693] IQM-ml cost [ 0.048 -0.108  0.34 ] obj [0.0002 0.     0.003 ]
    log-g09 [4.314, 4.203, 3.674, 3.695] IQM-ml cost [ 0.353 -0.303  0.976] obj [ 0.0014 -0.0003  0.003 ]
    log [3.561, 3.747, 3.454, 3.326] IQM-ml cost [-0.089 -0.773  0.45 ] obj [ 0.0023 -0.0004  0.006 ]

None is better than ``log(1 + L)`` at gamma 0.5: the study trains no third objective. Nothing is stored.
"""
from __future__ import annotations

import argparse

import numpy as np

#: name -> (cost transform, reward normalisation, gamma)
VARIANTS = {"lognorm": ("log1p", True, 0.5), "rawnorm": ("none", True, 0.5), "log-g09": ("log1p", False, 0.9),
            "log": ("log1p", False, 0.5)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--runs", type=int, default=2000)
    args = ap.parse_args()
    from adaptfilt.anchor import Anchor
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.studies.sif import SELECTION_SEED
    from adaptfilt.seed_stats import difference, seed_groups
    from adaptfilt.trainers import FAST, train_sb3

    pols = []
    for v, (transform, norm, gamma) in VARIANTS.items():
        for s in range(args.seeds):
            pols.append(train_sb3("ctm-ukf", gamma, 1000, s, FAST, features="paper+circ+cand", progress=False,
                                  anchor=Anchor("ml", 3.0, 0.01, 1.0), cost_transform=transform, normalize_reward=norm,
                                  name=f"{v}-s{s}"))
    exp = get_experiment("ctm-ukf")
    res = evaluate(exp, [b for b in exp.baselines() if b.name in ("ml", "greedy")] + pols, n_runs=args.runs,
                   seed=SELECTION_SEED, progress=False)
    for g, names in seed_groups(res.names).items():
        print(g, [round(res[n].cost, 3) for n in names],
              "IQM-ml cost", np.round(difference(res, names, ["ml"], "cost")["iqm"], 3),
              "obj", np.round(difference(res, names, ["ml"], "objective")["iqm"], 4))
    print("ml", res["ml"].cost, "greedy", res["greedy"].cost)


if __name__ == "__main__":
    main()
