r"""Checkers of the implement-it-yourself exercises of chapters 1, 3, 4, 5, 6 and 18.

Each chapter of 1-7 has one exercise in which the reader writes a function in an empty cell and
hands it to a checker, which compares it with the library on several fixed cases, says what
differs and, where it can, why (the pattern of :func:`adaptfilt.course.moments.check_unscented`,
:func:`~adaptfilt.course.moments.check_update` of chapter 2 and
:func:`adaptfilt.course.training.check_actor_update` of chapter 6 and
:func:`adaptfilt.course.ppo_step.check_gae` of chapter 7). Every checker prints its
verdict and returns whether the answer is right; ``tests/test_course_exercises.py`` feeds each
one the right answer and several wrong ones.

==============================  ===========  ==============================================
checker                         chapter      the reader writes
==============================  ===========  ==============================================
check_bayes_step                1            one step of the Bayesian recursion on a grid
check_discounted_choice         3            the per-run kappa of least discounted cost
check_nis_cost                  4            the one-step NIS cost of a batch of updates
check_paired_ci                 5            a paired bootstrap interval of a difference
check_score_gradient            6            REINFORCE's estimate of the policy gradient
check_kalmannet_step            16           one step of KalmanNet: features, gain, update
==============================  ===========  ==============================================
"""
from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["check_bayes_step", "check_discounted_choice", "check_nis_cost", "check_paired_ci",
           "check_score_gradient", "check_kalmannet_step"]


def _run(fn, args):
    """``fn(*args)`` as an array, or the reason it failed (the reader's code: no traceback)."""
    try:
        out = fn(*args)
    except Exception as e:  # noqa: BLE001 - any error of the reader's code is reported, not raised
        return None, f"raised {type(e).__name__}: {e}"
    if out is None:
        return None, "returned None (fill in the function and return the result)"
    return out, None


def _verdict(problems: list[str], right: str, hint: str) -> bool:
    if problems:
        print("not yet:\n  " + "\n  ".join(problems))
        print("hint: " + hint)
        return False
    print("right: " + right)
    return True


# ======================================================================== chapter 1
def _bayes_cases():
    """``(name, model, grid, prev, z, t)``: UNGM at three steps and a linear-Gaussian model."""
    from adaptfilt.models import linear_gaussian, ungm as ungm_model

    grid = np.linspace(-45, 45, 901)
    ungm = ungm_model()
    prior = np.exp(-0.5 * grid ** 2 / 5) / np.sqrt(2 * np.pi * 5)
    bimodal = 0.5 * (np.exp(-0.5 * (grid - 6) ** 2) + np.exp(-0.5 * (grid + 6) ** 2)) / np.sqrt(2 * np.pi)
    lin = linear_gaussian(F=[[0.9]], H=[[0.5]], Q=[[1.0]], R=[[0.5]], m0=[0.0], P0=[[5.0]])
    return [("UNGM from the prior, z = 1, t = 1", ungm, grid, prior, 1.0, 1),
            ("UNGM from a two-peaked density, z = 3, t = 40", ungm, grid, bimodal, 3.0, 40),
            ("UNGM from a two-peaked density, z = 0.2, t = 7", ungm, grid, bimodal, 0.2, 7),
            ("linear-Gaussian model, z = -1.5, t = 3", lin, grid, prior, -1.5, 3)]


def check_bayes_step(my_bayes_step: Callable) -> bool:
    r"""Check a reader's ``my_bayes_step(model, grid, prev, z, t) -> posterior (N,)``, one step of
    eq. (3) on an equally spaced grid (``prev`` the filtering density at ``t - 1``, ``z`` the
    measurement at ``t``), against :func:`adaptfilt.course.bayes.grid_bayes_step` on four cases.
    Names the usual slips: a density that does not integrate to 1, the prediction step left out
    (likelihood times the *previous* posterior), the likelihood left out (the predictive density),
    and a prediction that forgot the grid spacing without normalising at the end."""
    from adaptfilt.course.bayes import grid_bayes_step

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
        if np.allclose(mine, ref.posterior, rtol=1e-6, atol=1e-9 * ref.posterior.max()):
            continue
        dx = grid[1] - grid[0]
        area = float(mine.sum() * dx)
        no_predict = ref.likelihood * prev
        no_predict = no_predict / (no_predict.sum() * dx)
        why = f"{name}: your posterior differs from the library's (largest difference " \
              f"{np.abs(mine - ref.posterior).max():.3g}, the posterior's peak {ref.posterior.max():.3g})"
        if np.allclose(mine, no_predict, rtol=1e-6, atol=1e-9 * no_predict.max()):
            why += "; it is likelihood x the previous density: the prediction step (3b) is missing"
        elif np.allclose(mine, ref.predictive, rtol=1e-6, atol=1e-9 * ref.predictive.max()):
            why += "; it is the predictive density: multiply by the likelihood p(z_k | x_k) (3a)"
        elif area > 0 and np.allclose(mine / area, ref.posterior, rtol=1e-6, atol=1e-9 * ref.posterior.max()):
            why += f"; it has the right shape but integrates to {area:.4g}: divide by sum * spacing"
        problems.append(why)
    return _verdict(problems, "your Bayes step is the library's (grid_bayes_step) on all four cases",
                    "predictive = sum_j N(x_i; f(x_j), Q) prev_j dx; posterior = N(z; h(x_i), R) "
                    "predictive_i, divided by its sum times dx (f at step t, h at step t + 1, as "
                    "grid_bayes_step calls them)")


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
    myopic choice, a sum that starts at step 0, an undiscounted sum and an argmax."""
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
                 "the argmax, not the argmin": ref.discounted.argmax(0)}
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
    itself (no cost), ``- 1`` in the place of ``- n_z``, the diagonal of :math:`\mathbf P^{zz}` alone
    and a missing square."""
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
                 "NIS - n_z without the square": nis - nz, "|NIS - n_z|, not its square": np.abs(nis - nz)}
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
    return cases


def check_paired_ci(my_paired_ci: Callable) -> bool:
    r"""Check a reader's ``my_paired_ci(a, b, counts) -> (diff, lo, hi)``: the difference of the mean
    over runs of two policies' per-run values ``a``, ``b`` ``(M,)`` and its 95 % percentile
    interval from the bootstrap ``counts (B, M)`` (:func:`adaptfilt.metrics.bootstrap_counts`,
    the same counts for both: paired), against :func:`adaptfilt.metrics.bootstrap_mean` and
    :func:`~adaptfilt.metrics.percentile_ci` on two cases. Names an unpaired interval (the
    difference of the two intervals' ends), a 90 % interval and ``b - a``."""
    from adaptfilt.metrics import bootstrap_mean, percentile_ci

    problems = []
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
        ia, ib = percentile_ci(bootstrap_mean(a, counts)), percentile_ci(bootstrap_mean(b, counts))
        wrong = {"b - a, not a - b": -ref[[0, 2, 1]],
                 "a 90 % interval (the 5th and 95th percentiles), not 95 %":
                     np.array([ref[0], *percentile_ci(rep, level=0.90)]),
                 "unpaired: the ends of the two policies' own intervals subtracted":
                     np.array([ref[0], ia[0] - ib[1], ia[1] - ib[0]])}
        what = next((k for k, v in wrong.items() if np.allclose(mine, v, rtol=1e-9, atol=1e-12)), None)
        width, ref_width = mine[2] - mine[1], ref[2] - ref[1]
        line = (f"{name}: yours {np.round(mine, 4).tolist()}, the library's {np.round(ref, 4).tolist()}"
                + (f"; yours is {what}" if what else ""))
        if what is None and ref_width > 0 and width > 2 * ref_width:
            line += (f"; your interval is {width / ref_width:.1f} times as wide: resample the per-run "
                     "differences a - b with the counts (paired), not a and b separately")
        problems.append(line)
    return _verdict(problems, "your paired interval is the library's (bootstrap_mean, percentile_ci)",
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
def _kalmannet_cases():
    """``(name, model, z)``: the chapter's linear model and the bearing-only CTM (wrapped bearings), with
    an untrained KalmanNet of seed 0 (any weights test the update; untrained ones keep it short)."""
    from adaptfilt.course.learned_gain import linear_model
    from adaptfilt.models import coordinated_turn

    lin, ctm = linear_model(), coordinated_turn()
    return [("linear model, 4 runs x 12 steps", lin, lin.simulate(4, 12, rng=3).z),
            ("bearing-only CTM, 4 runs x 12 steps", ctm, ctm.simulate(4, 12, rng=3).z)]


def check_kalmannet_step(my_step: Callable) -> bool:
    r"""Chapter 18: ``my_step(model, gain, t, z_t, z_prev, x_filt, x_filt_prev, x_pred) -> (x_pred_new,
    x_filt_new)``, one step of KalmanNet (``x_filt`` is :math:`\hat x_{t-1|t-1}`, ``x_filt_prev``
    :math:`\hat x_{t-2|t-2}`, ``x_pred`` :math:`\hat x_{t-1|t-2}`, each ``(M, nx)``; ``gain(F1, F2, F3,
    F4)`` the network, :func:`adaptfilt.course.learned_gain.gain_function`). Run over 12 steps on two
    models and compared with :meth:`adaptfilt.kalmannet.KalmanNet.run`; names the first step that
    differs and the likely slip (the first step's convention, the bearing's wrap, a feature)."""
    from adaptfilt.course.learned_gain import gain_function
    from adaptfilt.kalmannet import KalmanNet

    problems = []
    for name, model, z in _kalmannet_cases():
        knet = KalmanNet(model, seed=0)
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
                hint = ("at the first step the prediction is the prior mean m0 itself (no f), and the "
                        "differences F3, F4 are zero" if t == 0 else
                        "the bearing's differences (innovation and F1) must be wrapped to [-pi, pi): "
                        "model.diff_z(a, b)" if model.residual is not None and np.allclose(
                            new_filt, _unwrapped(model, gain_function(KalmanNet(model, seed=0), M), z, t), atol=1e-8)
                        else "F3 = x_{t-1|t-1} - x_{t-2|t-2}, F4 = x_{t-1|t-1} - x_{t-1|t-2}; the update "
                             "x_pred + K (z - h(x_pred)), with h at time t + 1")
                problems.append(f"{name}: step {t} differs from the library's (max |difference| "
                                f"{np.abs(new_filt - ref[:, t]).max():.3g}); {hint}")
                break
            z_prev, x_filt_prev, x_filt, x_pred = z[:, t], x_filt, new_filt, new_pred
    return _verdict(problems, "your KalmanNet step is the library's, on the linear model and on the "
                              "bearing-only CTM",
                    "x_pred_new = m0 at t = 0, else f(x_filt, t); innovation = diff_z(z_t, h(x_pred_new, "
                    "t + 1)); K = gain(diff_z(z_t, z_prev), innovation, x_filt - x_filt_prev, x_filt - x_pred); "
                    "x_filt_new = x_pred_new + K @ innovation (per run)")


def _unwrapped(model, gain, z, t_stop: int) -> np.ndarray:
    """The reference recursion with plain (unwrapped) measurement differences, up to step ``t_stop``: what a
    step that forgets the bearing's wrap gives (to name that slip)."""
    M = z.shape[0]
    m0 = np.broadcast_to(model.m0, (M, model.nx)).copy()
    x_filt, x_filt_prev, x_pred = m0.copy(), m0.copy(), m0.copy()
    z_prev = np.asarray(model.h(m0, 1), dtype=float)
    for t in range(t_stop + 1):
        new_pred = m0.copy() if t == 0 else model.f(x_filt, t)
        innov = z[:, t] - model.h(new_pred, t + 1)
        K = gain(z[:, t] - z_prev, innov, x_filt - x_filt_prev, x_filt - x_pred)
        new_filt = new_pred + (K @ innov[..., None])[..., 0]
        z_prev, x_filt_prev, x_filt, x_pred = z[:, t], x_filt, new_filt, new_pred
    return x_filt
