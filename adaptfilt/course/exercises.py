r"""Checkers of the implement-it-yourself exercises of chapters 1, 3, 4, 5, 6 and 18.

Each chapter of 1-7 has one exercise in which the reader writes a function in an empty cell and
hands it to a checker, which compares it with the library on several fixed cases, says what
differs and, where it can, why (the pattern of :func:`adaptfilt.course.moments.check_unscented`,
:func:`~adaptfilt.course.moments.check_update` of chapter 2 and
:func:`adaptfilt.course.training.check_actor_update` of chapter 6 and
:func:`adaptfilt.course.ppo_step.check_gae` of chapter 7). Every checker prints its
verdict and returns whether the answer is right; ``tests/test_course_exercises.py`` feeds each
one the right answer, correct alternatives and several wrong ones. The checkers of the chapters that
read studies are in :mod:`adaptfilt.course.study_exercises`; what all checkers share is in
:mod:`adaptfilt.course.checking`.

==============================  ===========  ==============================================
checker                         chapter      the reader writes
==============================  ===========  ==============================================
check_bayes_step                1            one step of the Bayesian recursion on a grid
check_discounted_choice         3            the per-run kappa of least discounted cost
check_nis_cost                  4            the one-step NIS cost of a batch of updates
check_paired_ci                 5            a paired bootstrap interval of a difference
check_score_gradient            6            REINFORCE's estimate of the policy gradient
check_kalmannet_step            18           one step of KalmanNet: features, gain, update
==============================  ===========  ==============================================
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from adaptfilt.course.checking import run_answer as _run
from adaptfilt.course.checking import verdict as _verdict
from adaptfilt.course.checking import within_a_replicate as _within_a_replicate

__all__ = ["check_bayes_step", "check_discounted_choice", "check_nis_cost", "check_paired_ci",
           "check_score_gradient", "check_kalmannet_step"]


# ======================================================================== chapter 1
def _bayes_cases():
    """``(name, model, grid, prev, z, t)``: UNGM at three steps (its f changes with the step), a
    linear-Gaussian model, UNGM with Q = 2.5 and R = 0.5 (so that Q ignored, Q as a standard deviation
    and the same slips of R differ from the right answer) and a model whose sensor changes with the
    step (so that h at step t, not t + 1, differs)."""
    from adaptfilt.models import StateSpaceModel, linear_gaussian, ungm as ungm_model

    grid = np.linspace(-45, 45, 901)
    ungm = ungm_model()
    prior = np.exp(-0.5 * grid ** 2 / 5) / np.sqrt(2 * np.pi * 5)
    bimodal = 0.5 * (np.exp(-0.5 * (grid - 6) ** 2) + np.exp(-0.5 * (grid + 6) ** 2)) / np.sqrt(2 * np.pi)
    lin = linear_gaussian(F=[[0.9]], H=[[0.5]], Q=[[1.0]], R=[[0.5]], m0=[0.0], P0=[[5.0]])
    drifting = StateSpaceModel(f=lambda x, k: 0.8 * x + 2.0 * np.cos(0.5 * k),
                               h=lambda x, k: x + 3.0 * np.sin(0.9 * k),     # a sensor whose offset drifts
                               Q=[[0.5]], R=[[0.3]], m0=[0.0], P0=[[5.0]], name="drifting sensor")
    return [("UNGM from the prior, z = 1, t = 1", ungm, grid, prior, 1.0, 1),
            ("UNGM from a two-peaked density, z = 3, t = 40", ungm, grid, bimodal, 3.0, 40),
            ("UNGM from a two-peaked density, z = 0.2, t = 7", ungm, grid, bimodal, 0.2, 7),
            ("linear-Gaussian model, z = -1.5, t = 3", lin, grid, prior, -1.5, 3),
            ("UNGM with Q = 2.5, R = 0.5, z = 2, t = 12", ungm_model(Q=2.5, R=0.5), grid, bimodal, 2.0, 12),
            ("a sensor drifting with the step (h = x + 3 sin 0.9k), Q = 0.5, z = 1, t = 4", drifting, grid,
             prior, 1.0, 4)]


def _bayes_variant(model, grid, prev, z, t, Q=None, R=None, tf=None, th=None) -> np.ndarray:
    """The Bayes step with the given transition and measurement variances and time indices (defaults:
    the model's Q and R, ``f`` at ``t``, ``h`` at ``t + 1``): the right step, or a slip to name."""
    from adaptfilt.course.bayes import gauss_pdf

    dx = grid[1] - grid[0]
    Q = float(model.Q[0, 0]) if Q is None else Q
    R = float(model.R[0, 0]) if R is None else R
    fx = model.f(grid[:, None], t if tf is None else tf)[:, 0]
    predictive = gauss_pdf(grid[:, None] - fx[None, :], Q) @ prev * dx
    posterior = gauss_pdf(z - model.h(grid[:, None], t + 1 if th is None else th)[:, 0], R) * predictive
    return posterior / (posterior.sum() * dx)


def check_bayes_step(my_bayes_step: Callable) -> bool:
    r"""Check a reader's ``my_bayes_step(model, grid, prev, z, t) -> posterior (N,)``, one step of
    eq. (3) on an equally spaced grid (``prev`` the filtering density at ``t - 1``, ``z`` the
    measurement at ``t``), against :func:`adaptfilt.course.bayes.grid_bayes_step` on six cases
    (among them Q = 2.5 and a sensor that changes with the step). Names the usual slips: a density
    that does not integrate to 1, the prediction step left out (likelihood times the *previous*
    posterior), the likelihood left out (the predictive density), Q or R ignored or used as a
    standard deviation, and ``f`` or ``h`` at the wrong step."""
    from adaptfilt.course.bayes import grid_bayes_step

    def close(a, b):
        return np.allclose(a, b, rtol=1e-6, atol=1e-9 * b.max())

    problems = []
    for name, model, grid, prev, z, t in _bayes_cases():
        ref = grid_bayes_step(model, grid, prev, z, t)
        out, why = _run(my_bayes_step, (model, grid.copy(), prev.copy(), z, t))
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        mine = np.asarray(out, dtype=float).ravel()
        if mine.shape != ref.posterior.shape:
            problems.append(f"{name}: your density has shape {mine.shape}, not the grid's {ref.posterior.shape}")
            continue
        if close(mine, ref.posterior):
            continue
        dx = grid[1] - grid[0]
        area = float(mine.sum() * dx)
        no_predict = ref.likelihood * prev
        Q, R = float(model.Q[0, 0]), float(model.R[0, 0])
        slips = {"it is likelihood x the previous density: the prediction step (3b) is missing":
                     no_predict / (no_predict.sum() * dx),
                 "it is the predictive density: multiply by the likelihood p(z_k | x_k) (3a)": ref.predictive,
                 f"the transition has variance 1: Q (here {Q:g}) is ignored": dict(Q=1.0),
                 f"the transition has variance Q^2 = {Q * Q:g}: Q is a variance, not a standard deviation":
                     dict(Q=Q * Q),
                 f"the likelihood has variance 1: R (here {R:g}) is ignored": dict(R=1.0),
                 f"the likelihood has variance R^2 = {R * R:g}: R is a variance, not a standard deviation":
                     dict(R=R * R),
                 "h is taken at step t: the measurement at t is h(x, t + 1)": dict(th=t),
                 "f is taken at step t + 1: the transition from t - 1 to t is f(x, t)": dict(tf=t + 1),
                 "f is taken at step t - 1: the transition from t - 1 to t is f(x, t)": dict(tf=t - 1)}
        why = f"{name}: your posterior differs from the library's (largest difference " \
              f"{np.abs(mine - ref.posterior).max():.3g}, the posterior's peak {ref.posterior.max():.3g})"
        for what, variant in slips.items():
            if isinstance(variant, dict):
                variant = _bayes_variant(model, grid, prev, z, t, **variant)
            if close(mine, variant) and not close(variant, ref.posterior):
                why += "; " + what
                break
        else:
            if area > 0 and close(mine / area, ref.posterior):
                why += f"; it has the right shape but integrates to {area:.4g}: divide by sum * spacing"
        problems.append(why)
    return _verdict(problems, "your Bayes step is the library's (grid_bayes_step) on all six cases",
                    "predictive = sum_j N(x_i; f(x_j), Q) prev_j dx; posterior = N(z; h(x_i), R) "
                    "predictive_i, divided by its sum times dx (Q and R are variances; f at step t, h at "
                    "step t + 1, as grid_bayes_step calls them)")


# ======================================================================== chapter 3
def _discount_cases():
    """Synthetic ``(G, M, T)`` cost arrays: costs before ``t0`` differ too, so a sum from the
    start is caught, and costs are spread so that discounting changes the choice often."""
    rng = np.random.default_rng(3)
    out = []
    for G, M, T, t0, gamma in ((5, 40, 12, 4, 0.5), (3, 30, 8, 0, 0.9), (7, 25, 15, 9, 0.3)):
        costs = rng.gamma(0.7, 1.0, size=(G, M, T)) * rng.uniform(0.5, 2.0, size=(G, 1, T))
        out.append((f"G = {G} values, M = {M} runs, T = {T}, t0 = {t0}, gamma = {gamma}", costs, t0, gamma))
    return out


def check_discounted_choice(my_choice: Callable) -> bool:
    r"""Check a reader's ``my_choice(costs, t0, gamma) -> (M,)``: for every run the index of the
    parameter value whose discounted cost :math:`\sum_{j\ge0}\gamma^j \bar L_{t_0+j}` is least,
    ``costs (G, M, T)`` as :func:`adaptfilt.course.myopia.deviation_costs` returns them, against
    :func:`adaptfilt.course.myopia.myopic_vs_discounted` on three synthetic cases. Names the
    myopic choice, a sum that starts at step 0 or at ``t0 + 1``, one that stops a step early, an
    undiscounted sum, weights that run backwards and an argmax. Weights ``gamma^(j + 1)`` or
    ``gamma^t`` scale every value's sum alike and are as right."""
    from adaptfilt.course.myopia import myopic_vs_discounted

    problems = []
    for name, costs, t0, gamma in _discount_cases():
        ref = myopic_vs_discounted(costs, t0, gamma)
        out, why = _run(my_choice, (costs.copy(), t0, gamma))
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        mine = np.asarray(out).ravel()
        if mine.shape != ref.farsighted.shape:
            problems.append(f"{name}: you returned shape {mine.shape}, one index per run is {ref.farsighted.shape}")
            continue
        if np.array_equal(mine, ref.farsighted):
            continue
        T = costs.shape[-1]
        wrong = {"the myopic choice (the cost at t0 alone)": ref.myopic,
                 "the sum from step 0, not from t0": (costs * gamma ** np.arange(T)).sum(-1).argmin(0),
                 "an undiscounted sum (gamma = 1)": costs[:, :, t0:].sum(-1).argmin(0),
                 "the argmax, not the argmin": ref.discounted.argmax(0),
                 "the sum from t0 + 1: the cost at t0 itself is left out":
                     (costs[:, :, t0 + 1:] * gamma ** np.arange(T - t0 - 1)).sum(-1).argmin(0),
                 "the sum stops one step early: the last step is left out":
                     (costs[:, :, t0:-1] * gamma ** np.arange(T - t0 - 1)).sum(-1).argmin(0),
                 "the weights run backwards (gamma^0 on the last step)":
                     (costs[:, :, t0:] * gamma ** np.arange(T - t0)[::-1]).sum(-1).argmin(0)}
        what = next((k for k, v in wrong.items() if np.array_equal(mine, v) and not np.array_equal(v, ref.farsighted)),
                    None)
        problems.append(f"{name}: your choice differs in {np.mean(mine != ref.farsighted):.0%} of the runs"
                        + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your discounted choice is the library's (myopic_vs_discounted) in every run",
                    "weights gamma^j for j = 0, 1, ... from t0 on: (costs[:, :, t0:] * gamma ** "
                    "np.arange(T - t0)).sum(axis=-1), then the argmin over the G values (axis 0)")


# ======================================================================== chapter 4
def _nis_cases():
    """``(name, innovation (M, nz), Pzz (M, nz, nz))``: one and two measurements, correlated."""
    rng = np.random.default_rng(4)
    cases = []
    for nz, M in ((1, 20), (2, 15), (3, 10)):
        A = rng.standard_normal((M, nz, nz))
        Pzz = A @ np.swapaxes(A, 1, 2) + 0.3 * np.eye(nz)
        cases.append((f"n_z = {nz}, M = {M} runs", rng.standard_normal((M, nz)) * 2.0, Pzz))
    return cases


def check_nis_cost(my_nis_cost: Callable) -> bool:
    r"""Check a reader's ``my_nis_cost(innovation (M, nz), Pzz (M, nz, nz)) -> (M,)``, the one-step
    cost :math:`\bar L_\text{NIS} = (\tilde{\mathbf z}^T (\mathbf P^{zz})^{-1}\tilde{\mathbf z} - n_z)^2`
    of eq. (32) for a batch of runs, against a linear solve (``np.linalg.solve``, never an explicit
    inverse) on one, two and three measurements. Names the NIS
    itself (no cost), ``- 1`` in the place of ``- n_z``, the diagonal of :math:`\mathbf P^{zz}` alone,
    :math:`\mathbf P^{zz}` in the place of its inverse, a missing square, a log-transformed cost and the
    NIS divided by ``n_z``."""
    problems = []
    for name, nu, Pzz in _nis_cases():
        nz = nu.shape[1]
        nis = np.einsum("mi,mi->m", nu, np.linalg.solve(Pzz, nu[..., None])[..., 0])
        ref = (nis - nz) ** 2
        out, why = _run(my_nis_cost, (nu.copy(), Pzz.copy()))
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        mine = np.asarray(out, dtype=float).ravel()
        if mine.shape != ref.shape:
            problems.append(f"{name}: you returned shape {mine.shape}, one cost per run is {ref.shape}")
            continue
        if np.allclose(mine, ref, rtol=1e-8, atol=1e-10):
            continue
        diag_nis = (nu ** 2 / np.diagonal(Pzz, axis1=1, axis2=2)).sum(1)
        wrong = {"the NIS itself, not the cost (NIS - n_z)^2": nis, "(NIS - 1)^2: the NIS of a consistent "
                 "filter has mean n_z, not 1": (nis - 1) ** 2,
                 "computed with the diagonal of Pzz only (the correlations are lost)": (diag_nis - nz) ** 2,
                 "NIS - n_z without the square": nis - nz, "|NIS - n_z|, not its square": np.abs(nis - nz),
                 "computed with Pzz itself, not its inverse (nu^T Pzz nu)":
                     (np.einsum("mi,mij,mj->m", nu, Pzz, nu) - nz) ** 2,
                 "log(1 + cost): the trainers' transform, not the cost of eq. (32)": np.log1p((nis - nz) ** 2),
                 "(NIS / n_z - 1)^2: the NIS divided by n_z before the square": (nis / nz - 1) ** 2}
        what = next((k for k, v in wrong.items() if np.allclose(mine, v, rtol=1e-8, atol=1e-10)
                     and not np.allclose(v, ref)), None)
        problems.append(f"{name}: your costs differ (largest difference {np.abs(mine - ref).max():.3g})"
                        + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your NIS cost is (NIS - n_z)^2 of the library's NIS on all three cases",
                    "NIS = nu^T Pzz^-1 nu per run: np.linalg.solve(Pzz, nu[..., None])[..., 0], then "
                    "the row-wise dot product with nu; the cost is (NIS - n_z)^2 with n_z = nu.shape[1]")


# ======================================================================== chapter 5
def _paired_cases():
    """``(name, a (M,), b (M,), counts (B, M))``: per-run values of two policies on the same runs,
    strongly correlated (common random numbers), and one set of bootstrap counts."""
    from adaptfilt.metrics import bootstrap_counts

    rng = np.random.default_rng(5)
    cases = []
    for M, rho in ((200, 0.95), (500, 0.8)):
        common = rng.gamma(2.0, 1.0, M)
        a = common + np.sqrt(1 - rho) * rng.standard_normal(M)
        b = common + 0.05 + np.sqrt(1 - rho) * rng.standard_normal(M)
        cases.append((f"M = {M} runs, correlation about {rho}", a, b, bootstrap_counts(M, n_boot=1000, rng=M)))
    # a skewed difference (a heavy right tail in a, as a NEES has): the percentile interval is then
    # lopsided about the estimate, unlike a normal approximation or the reflected (basic) interval
    common = rng.gamma(2.0, 1.0, 100)
    a, b = common + rng.lognormal(0.0, 1.2, 100), common + 2.0 + 0.1 * rng.standard_normal(100)
    cases.append(("M = 100 runs, a heavy right tail in a", a, b, bootstrap_counts(100, n_boot=1000, rng=100)))
    return cases


def check_paired_ci(my_paired_ci: Callable) -> bool:
    r"""Check a reader's ``my_paired_ci(a, b, counts) -> (diff, lo, hi)``: the difference of the mean
    over runs of two policies' per-run values ``a``, ``b`` ``(M,)`` and its 95 % percentile
    interval from the bootstrap ``counts (B, M)`` (:func:`adaptfilt.metrics.bootstrap_counts`,
    the same counts for both: paired), against :func:`adaptfilt.metrics.bootstrap_mean` and
    :func:`~adaptfilt.metrics.percentile_ci` on three cases. Any standard percentile convention is
    right: an end counts as the library's when it lies within one replicate of ``np.quantile``'s
    (between the order statistics next to the ones it interpolates), so the 25th and 975th of 1000
    sorted replicates pass, and the verdict says which convention differed. Names an unpaired
    interval (the difference of the two intervals' ends), a 90 % interval, ``b - a``, normal
    approximations, the reflected (basic) interval and an interval as wide as resampling ``a`` and ``b``
    independently gives (the third case has a skewed difference, so the last three are told apart from
    the percentiles)."""
    from adaptfilt.metrics import bootstrap_mean, percentile_ci

    problems, conventions = [], []
    for name, a, b, counts in _paired_cases():
        rep = bootstrap_mean(a - b, counts)
        ref = np.array([float(np.mean(a - b)), *percentile_ci(rep)])
        out, why = _run(my_paired_ci, (a.copy(), b.copy(), counts.copy()))
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        try:
            mine = np.asarray(out, dtype=float).ravel()
        except (TypeError, ValueError):
            mine = np.array([])
        if mine.shape != (3,):
            problems.append(f"{name}: return three numbers (diff, lo, hi), got {out!r}")
            continue
        if np.allclose(mine, ref, rtol=1e-9, atol=1e-12):
            continue
        if np.isclose(mine[0], ref[0], rtol=1e-9, atol=1e-12) and _within_a_replicate(mine[1:], rep):
            conventions.append(name)
            continue
        ia, ib = percentile_ci(bootstrap_mean(a, counts)), percentile_ci(bootstrap_mean(b, counts))
        wrong = {"b - a, not a - b": -ref[[0, 2, 1]],
                 "a 90 % interval (the 5th and 95th percentiles), not 95 %":
                     np.array([ref[0], *percentile_ci(rep, level=0.90)]),
                 "unpaired: the ends of the two policies' own intervals subtracted":
                     np.array([ref[0], ia[0] - ib[1], ia[1] - ib[0]]),
                 "the basic (reflected) interval 2 diff - the percentiles, not the percentiles themselves":
                     np.array([ref[0], 2 * ref[0] - ref[2], 2 * ref[0] - ref[1]])}
        d = a - b
        for ddof in (0, 1):
            half = 1.96 * d.std(ddof=ddof) / np.sqrt(len(d))
            wrong[f"a normal approximation (diff +- 1.96 standard errors, ddof = {ddof}), not the "
                  "percentiles of the replicates"] = np.array([ref[0], ref[0] - half, ref[0] + half])
            half = 1.96 * rep.std(ddof=ddof)
            wrong[f"diff +- 1.96 standard deviations of the replicates (ddof = {ddof}): a normal "
                  "approximation, not their percentiles"] = np.array([ref[0], ref[0] - half, ref[0] + half])
        what = next((k for k, v in wrong.items() if np.allclose(mine, v, rtol=1e-6, atol=1e-12)), None)
        width, ref_width = mine[2] - mine[1], ref[2] - ref[1]
        line = (f"{name}: yours {np.round(mine, 4).tolist()}, the library's {np.round(ref, 4).tolist()}"
                + (f"; yours is {what}" if what else ""))
        if what is None and ref_width > 0 and width > 2 * ref_width:
            line += (f"; your interval is {width / ref_width:.1f} times as wide: resample the per-run "
                     "differences a - b with the counts (paired), not a and b separately")
        problems.append(line)
    right = "your paired interval is the library's (bootstrap_mean, percentile_ci)"
    if conventions and not problems:
        right += (" up to the percentile convention: your ends are order statistics within one replicate "
                  "of np.quantile's linear interpolation (" + "; ".join(conventions) + "), which is as right")
    return _verdict(problems, right,
                    "the replicates are counts @ (a - b) / M, one per row of counts; the interval is "
                    "their 2.5th and 97.5th percentiles (np.quantile), the estimate mean(a - b)")


# ======================================================================== chapter 6
def _score_cases():
    """``(name, theta (K,), actions (N,), costs (N,), baseline)``: the bandit toy's three actions at
    uniform and uneven logits, four actions, and a batch in which one action was never drawn."""
    from adaptfilt.course.policy_gradient import sample_costs

    rng = np.random.default_rng(6)
    cases = []
    for name, theta, mean, n, b in (
            ("3 actions, uniform logits, no baseline", [0.0, 0.0, 0.0], [1.0, 0.0, 2.0], 12, 0.0),
            ("3 actions, uneven logits, baseline 0.4", [0.5, 1.5, -1.0], [1.0, 0.0, 2.0], 9, 0.4),
            ("4 actions, baseline 1.3", [0.2, -0.4, 0.9, 0.0], [0.5, 2.0, 1.0, 3.0], 15, 1.3)):
        a, c = sample_costs(np.array(theta), np.array(mean), n, rng)
        cases.append((name, np.array(theta), a, c, b))
    cases.append(("3 actions, a batch that never drew action 2, baseline 1.0", np.array([0.0, 0.3, -0.3]),
                  np.array([0, 1, 1, 0, 1]), np.array([0.2, 1.1, 0.9, -0.1, 1.3]), 1.0))
    return cases


def check_score_gradient(my_estimate: Callable) -> bool:
    r"""Check a reader's ``my_estimate(theta, actions, costs, baseline) -> (K,)``, REINFORCE's estimate
    :math:`\hat g = \frac1N\sum_n (L_n - b)(e_{a_n} - \pi)` of the gradient of the expected cost with
    respect to the logits ``theta (K,)`` of a softmax policy, from ``N`` sampled ``actions`` and the
    ``costs`` observed after them, against
    :func:`adaptfilt.course.policy_gradient.score_function_estimate` on four batches. Names the usual
    slips: a reward's sign, the score :math:`e_a` without :math:`-\pi`, :math:`\nabla\pi_a` in the
    place of :math:`\nabla\log\pi_a`, the baseline left out, and a sum over the batch, not the mean."""
    from adaptfilt.course.policy_gradient import score_function_estimate, softmax

    problems = []
    for name, theta, a, c, b in _score_cases():
        ref = score_function_estimate(theta, a, c, b)
        out, why = _run(my_estimate, (theta.copy(), a.copy(), c.copy(), b))
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        mine = np.asarray(out, dtype=float).ravel()
        if mine.shape != ref.shape:
            problems.append(f"{name}: you returned shape {mine.shape}, one number per logit is {ref.shape}")
            continue
        if np.allclose(mine, ref, rtol=1e-9, atol=1e-12):
            continue
        pi, onehot = softmax(theta), np.eye(len(theta))[a]
        wrong = {"the gradient of a reward, -g (for a cost it is +(L - b) grad log pi)": -ref,
                 "(L - b) e_a: the score without -pi (grad log pi_a = e_a - pi)":
                     ((c - b)[:, None] * onehot).mean(0),
                 "(L - b) grad pi_a, not grad log pi_a (the score-function identity divides by pi_a)":
                     ((c - b)[:, None] * pi[a][:, None] * (onehot - pi)).mean(0),
                 "without the baseline": score_function_estimate(theta, a, c, 0.0),
                 "a sum over the batch, not the mean": len(a) * ref}
        what = next((k for k, v in wrong.items() if np.allclose(mine, v, rtol=1e-9, atol=1e-12)
                     and not np.allclose(v, ref)), None)
        problems.append(f"{name}: your gradient differs (largest difference {np.abs(mine - ref).max():.3g})"
                        + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your estimate is REINFORCE's, (L - b)(e_a - pi) averaged over the batch, "
                    "on all four batches",
                    "pi = softmax(theta); for each sample the score is grad log pi(a_n) = e_{a_n} - pi "
                    "(np.eye(K)[actions] - pi); weight it by L_n - b and average over the samples")


# ======================================================================== chapter 18
def _crossing_runs(model, n: int = 4, n_steps: int = 12, seed: int = 3) -> np.ndarray:
    """``n`` simulated bearing sequences ``(n, n_steps, 1)`` of the CTM in each of which two consecutive
    bearings straddle +-pi (the target passes behind the sensor), the first such runs of a fixed draw:
    an unwrapped difference of bearings is then off by 2 pi at that step."""
    z = model.simulate(64, n_steps, rng=seed).z
    crossing = (np.abs(np.diff(z[..., 0], axis=1)) > np.pi).any(1)
    return z[np.flatnonzero(crossing)[:n]]


def _kalmannet_cases():
    """``(name, model, z)``: the chapter's linear model, UNGM (its f changes with the step), a model
    whose sensor drifts with the step (so that h at the wrong step differs) and the bearing-only CTM on
    runs whose bearings cross +-pi (so that an unwrapped difference differs); each is filtered by an
    untrained KalmanNet of seed 0 whose features are scaled, not L2-normalised (L2 leaves a scalar
    feature only its sign, which would hide a feature passed as its sign)."""
    from adaptfilt.course.learned_gain import linear_model
    from adaptfilt.models import StateSpaceModel, coordinated_turn, ungm

    lin, ctm, ungm_model = linear_model(), coordinated_turn(), ungm()
    drifting = StateSpaceModel(f=lambda x, k: 0.8 * x + 2.0 * np.cos(0.5 * k),
                               h=lambda x, k: x + 3.0 * np.sin(0.9 * k),     # a sensor whose offset drifts
                               Q=[[0.5]], R=[[0.3]], m0=[0.0], P0=[[5.0]], name="drifting sensor", n_steps=100)
    return [("linear model, 4 runs x 12 steps", lin, lin.simulate(4, 12, rng=3).z),
            ("UNGM, 4 runs x 12 steps", ungm_model, ungm_model.simulate(4, 12, rng=3).z),
            ("a sensor drifting with the step (h = x + 3 sin 0.9k), 4 runs x 12 steps", drifting,
             drifting.simulate(4, 12, rng=3).z),
            ("bearing-only CTM, 4 runs x 12 steps whose bearings cross +-pi", ctm, _crossing_runs(ctm))]


def _kalmannet_net(model):
    from adaptfilt.kalmannet import KalmanNet

    return KalmanNet(model, feature_norm="scale", seed=0)


def check_kalmannet_step(my_step: Callable) -> bool:
    r"""Chapter 18: ``my_step(model, gain, t, z_t, z_prev, x_filt, x_filt_prev, x_pred) -> (x_pred_new,
    x_filt_new)``, one step of KalmanNet (``x_filt`` is :math:`\hat x_{t-1|t-1}`, ``x_filt_prev``
    :math:`\hat x_{t-2|t-2}`, ``x_pred`` :math:`\hat x_{t-1|t-2}`, each ``(M, nx)``; ``gain(F1, F2, F3,
    F4)`` the network, :func:`adaptfilt.course.learned_gain.gain_function`). Run over 12 steps on four
    models (linear, UNGM, a drifting sensor, the CTM with bearings that cross +-pi) and compared with
    :meth:`adaptfilt.kalmannet.KalmanNet.run`; names the first step that differs and the slip where it
    is one of the usual ones (the first step's convention, a wrap left out of F1 or the innovation, f or
    h at the wrong step, a feature swapped, replaced or passed as its sign)."""
    from adaptfilt.course.learned_gain import gain_function

    problems = []
    for name, model, z in _kalmannet_cases():
        knet = _kalmannet_net(model)
        ref = knet.run(z).mean
        M, T, _ = z.shape
        gain = gain_function(knet, M)
        m0 = np.broadcast_to(model.m0, (M, model.nx)).copy()
        x_filt, x_filt_prev, x_pred = m0.copy(), m0.copy(), m0.copy()
        z_prev = np.asarray(model.h(m0, 1), dtype=float)
        for t in range(T):
            out, why = _run(my_step, (model, gain, t, z[:, t].copy(), z_prev.copy(), x_filt.copy(),
                                      x_filt_prev.copy(), x_pred.copy()))
            if why is None:
                try:
                    new_pred, new_filt = (np.asarray(a, dtype=float) for a in out)
                except (TypeError, ValueError):
                    why = f"returned {type(out).__name__}, not the pair (x_pred_new, x_filt_new)"
                else:
                    if new_pred.shape != (M, model.nx) or new_filt.shape != (M, model.nx):
                        why = f"returned shapes {new_pred.shape} and {new_filt.shape}, expected two of {(M, model.nx)}"
            if why:
                problems.append(f"{name}, step {t}: your function {why}")
                break
            if not np.allclose(new_filt, ref[:, t], rtol=1e-8, atol=1e-8):
                slip = next((what for what, kw in _KALMANNET_SLIPS.items()
                             if _slip_shows(model, z, t, new_filt, ref[:, t], kw)), None)
                problems.append(f"{name}: step {t} differs from the library's (max |difference| "
                                f"{np.abs(new_filt - ref[:, t]).max():.3g})"
                                + (f"; yours is {slip}" if slip else ""))
                break
            z_prev, x_filt_prev, x_filt, x_pred = z[:, t], x_filt, new_filt, new_pred
    return _verdict(problems, "your KalmanNet step is the library's, on the linear model, UNGM, a drifting "
                              "sensor and the bearing-only CTM",
                    "x_pred_new = m0 at t = 0, else f(x_filt, t); innovation = diff_z(z_t, h(x_pred_new, "
                    "t + 1)); K = gain(diff_z(z_t, z_prev), innovation, x_filt - x_filt_prev, x_filt - x_pred); "
                    "x_filt_new = x_pred_new + K @ innovation (per run)")


#: The usual slips of the KalmanNet step, as switches of :func:`_kalmannet_variant`.
_KALMANNET_SLIPS = {
    "f applied at the first step: at t = 0 the prediction is the prior mean m0 itself (no f), and the "
    "differences F3, F4 are zero": dict(first=False),
    "the bearing's differences unwrapped: both the innovation and F1 must go through model.diff_z "
    "(wrapped to [-pi, pi))": dict(wrap_f1=False, wrap_innov=False),
    "F1 = z_t - z_prev unwrapped: the wrapped innovation is not enough, F1 must go through model.diff_z too":
        dict(wrap_f1=False),
    "the innovation unwrapped: z_t - h(x_pred_new) must go through model.diff_z": dict(wrap_innov=False),
    "f taken at step t - 1: the prediction to step t is model.f(x_filt, t)": dict(tf=-1),
    "f taken at step t + 1: the prediction to step t is model.f(x_filt, t)": dict(tf=1),
    "h taken at step t: the measurement at step t is model.h(x, t + 1)": dict(th=0),
    "h taken at step t + 2: the measurement at step t is model.h(x, t + 1)": dict(th=2),
    "F4 taken against the new prediction: F4 = x_{t-1|t-1} - x_{t-1|t-2}, the previous one": dict(f4="new"),
    "F3 and F4 swapped: F3 = x_{t-1|t-1} - x_{t-2|t-2}, F4 = x_{t-1|t-1} - x_{t-1|t-2}": dict(swap34=True),
    "F1 replaced by the innovation: F1 = diff_z(z_t, z_prev), the change of the measurement":
        dict(f1_innov=True),
    "the features passed as their signs: pass them whole, the network scales them itself": dict(signs=True),
}


def _slip_shows(model, z, t, mine, ref_t, slip: dict) -> bool:
    """Whether the step a slip gives matches the reader's at step ``t`` and differs from the library's."""
    alt = _kalmannet_variant(model, z, t, **slip)
    return (np.allclose(mine, alt, rtol=1e-8, atol=1e-8)
            and not np.allclose(alt, ref_t, rtol=1e-8, atol=1e-8))


def _kalmannet_variant(model, z, t_stop: int, first: bool = True, wrap_f1: bool = True, wrap_innov: bool = True,
                       tf: int = 0, th: int = 1, f4: str = "prev", swap34: bool = False, f1_innov: bool = False,
                       signs: bool = False) -> np.ndarray:
    """The KalmanNet recursion (a fresh network of the checker's) up to step ``t_stop``, with the
    given slip switched on: ``x_{t_stop|t_stop}``. With every switch at its default it is the library's
    (``tests/test_course_exercises.py`` checks it against :meth:`KalmanNet.run`)."""
    from adaptfilt.course.learned_gain import gain_function

    M = z.shape[0]
    gain = gain_function(_kalmannet_net(model), M)
    plain = lambda a, b: a - b  # noqa: E731
    d1, dv = (model.diff_z if wrap_f1 else plain), (model.diff_z if wrap_innov else plain)
    m0 = np.broadcast_to(model.m0, (M, model.nx)).copy()
    x_filt, x_filt_prev, x_pred = m0.copy(), m0.copy(), m0.copy()
    z_prev = np.asarray(model.h(m0, 1), dtype=float)
    for t in range(t_stop + 1):
        new_pred = m0.copy() if (t == 0 and first) else model.f(x_filt, t + tf)
        innov = dv(z[:, t], model.h(new_pred, t + th))
        F1, F3, F4 = d1(z[:, t], z_prev), x_filt - x_filt_prev, x_filt - (x_pred if f4 == "prev" else new_pred)
        feats = [innov if f1_innov else F1, innov, *((F4, F3) if swap34 else (F3, F4))]
        K = gain(*(np.sign(F) if signs else F for F in feats))
        new_filt = new_pred + (K @ innov[..., None])[..., 0]
        z_prev, x_filt_prev, x_filt, x_pred = z[:, t], x_filt, new_filt, new_pred
    return x_filt
