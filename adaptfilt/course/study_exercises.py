r"""Checkers of the implement-it-yourself exercises of chapters 8-17, the chapters that read studies.

As in :mod:`adaptfilt.course.exercises` (chapters 1-5 and 18): the reader writes a short function in an
empty cell and hands it to a checker, which compares it with the library on cases chosen so that the
usual slips give other answers, prints "right: ..." or "not yet: ..." with what differs and, where the
answer is one of the usual slips, which one, and returns whether the answer is right.
``tests/test_course_exercises.py`` feeds every checker at least three wrong answers and a correct
alternative.

==============================  =======  ====================================================================
checker                         chapter  the reader writes
==============================  =======  ====================================================================
check_switch_curve              8        a policy's probability of a large kappa in equal-count bins of a feature
check_greedy_kappa              9        greedy's kappa on UNGM from the closed form of P^zz(kappa): the gate
check_line_of_sight             10       a position error and claimed spread along and across the line of sight
check_break_even                11       the price of a deciding iteration at which two charged costs are equal
check_model                     12       a ``StateSpaceModel`` of a described system
check_two_level_iqm             13       the IQM over seeds with its two-level (seed x run) bootstrap interval
check_candidate_costs           14       every candidate's one-step cost, what greedy and ``cand`` features see
check_mismatched_nis            15       the steady-state mean NIS of a Kalman filter whose Q and R are wrong
check_rollout_value             16       the one-step rollout value of every candidate over greedy as base policy
check_kld_count                 17       KLD-sampling's particle count from the Wilson-Hilferty bound
==============================  =======  ====================================================================
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from adaptfilt.course.checking import run_answer as _run
from adaptfilt.course.checking import verdict as _verdict
from adaptfilt.course.checking import within_a_replicate as _within_a_replicate

__all__ = ["check_switch_curve", "check_greedy_kappa", "check_line_of_sight", "check_break_even", "check_model",
           "check_two_level_iqm", "check_candidate_costs", "check_mismatched_nis", "check_rollout_value",
           "check_kld_count"]


def _close(a, b, rtol: float = 1e-8, atol: float = 1e-10) -> bool:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=rtol, atol=atol, equal_nan=True))


def _slip(mine, ref, slips: dict, close=_close) -> str | None:
    """The name of the first slip whose answer is the reader's and not the right one, or None."""
    return next((what for what, alt in slips.items() if close(mine, alt) and not close(alt, ref)), None)


def _array(out, shape: tuple, what: str) -> tuple[np.ndarray | None, str | None]:
    """``out`` as a float array of ``shape``, or why not."""
    try:
        a = np.asarray(out, dtype=float)
    except (TypeError, ValueError):
        return None, f"returned {type(out).__name__}, not {what}"
    if a.shape != shape:
        return None, f"returned shape {a.shape}, {what} has shape {shape}"
    return a, None


# ======================================================================== chapter 8
def _switch_cases():
    """``(name, probs (N, G), grid, feature (N,), at_least, n_bins)``: action probabilities that rise
    with the size of a signed feature, N a multiple of the bin count (equal-count bins are then one
    partition, whatever the binning convention), ``at_least`` a grid value (so ``>`` and ``>=`` differ)."""
    from adaptfilt.experiment_registry import get_experiment

    rng = np.random.default_rng(8)
    grid = np.asarray(get_experiment("ungm-ukf").grid)
    out = []
    for N, n_bins, at_least, scale in ((600, 12, 100.0, 1.0), (480, 8, 1000.0, 3.0), (300, 10, 20.0, 0.3)):
        feature = rng.standard_normal(N) * scale * rng.lognormal(0.0, 1.0, N)
        logits = rng.standard_normal((N, grid.size)) + np.log1p(grid)[None] * (np.abs(feature)[:, None] / scale - 1)
        probs = np.exp(logits - logits.max(1, keepdims=True))
        out.append((f"N = {N} states, {n_bins} bins, kappa >= {at_least:g}", probs / probs.sum(1, keepdims=True),
                    grid, feature, at_least, n_bins))
    return out


def switch_curve(probs: np.ndarray, grid, feature: np.ndarray, at_least: float, n_bins: int):
    """The reference: ``policy_reading.plot_switch_off``'s curve, the medians of ``|feature|`` and the
    means of :math:`\\pi(\\theta \\ge` ``at_least`` :math:`| s)` in ``n_bins`` bins of equal count."""
    from adaptfilt.course.policy_reading import equal_count_bins

    return equal_count_bins(np.abs(feature), probs[:, np.asarray(grid) >= at_least].sum(axis=1), n_bins)


def check_switch_curve(my_switch_curve: Callable) -> bool:
    r"""Chapter 8: ``my_switch_curve(probs, grid, feature, at_least, n_bins) -> (mid, share)``, the curve of
    Figure 8.3 for one policy: ``probs (N, G)`` its action probabilities at ``N`` information states
    (``policy.probs(states)``), ``feature (N,)`` one feature of those states; ``mid (n_bins,)`` the median
    of ``|feature|`` in each of ``n_bins`` bins of equal count, ``share (n_bins,)`` the mean probability of
    the grid values ``>= at_least`` in each bin. Compared with the helper behind the figure
    (``policy_reading.plot_switch_off``) on three synthetic policies. Names ``>`` for ``>=``, the share of
    states whose *most probable* value is large, the signed feature, bins of equal width, means for
    medians, the complement, and a sum for a mean."""
    problems = []
    for name, probs, grid, feature, at_least, n_bins in _switch_cases():
        mid, share = switch_curve(probs, grid, feature, at_least, n_bins)
        out, why = _run(my_switch_curve, (probs.copy(), grid, feature.copy(), at_least, n_bins))
        if why is None:
            try:
                mine = np.stack([np.asarray(a, dtype=float).ravel() for a in out])
            except (TypeError, ValueError):
                why = f"returned {type(out).__name__}, not the pair (mid, share)"
            else:
                if mine.shape != (2, n_bins):
                    why = f"returned arrays of shape {mine.shape[1:]}, not two of ({n_bins},)"
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        ref = np.stack([mid, share])
        if _close(mine, ref):
            continue
        x, g = np.abs(feature), np.asarray(grid)
        parts = np.array_split(np.argsort(x), n_bins)
        edges = np.linspace(x.min(), x.max(), n_bins + 1)
        width = np.clip(np.digitize(x, edges[1:-1]), 0, n_bins - 1)
        large = probs[:, g >= at_least].sum(1)
        slips = {"the grid values > at_least: the value at_least itself belongs to the large ones (>=)":
                     np.stack([mid, [probs[p][:, g > at_least].sum(1).mean() for p in parts]]),
                 "the share of states whose most probable value is large: average the probability itself":
                     np.stack([mid, [(g[probs[p].argmax(1)] >= at_least).mean() for p in parts]]),
                 "binned by the signed feature: bin its size |feature|":
                     np.stack(_signed(probs, g, feature, at_least, n_bins)),
                 "bins of equal width: the figure's bins hold equal counts (np.array_split of the sorted states)":
                     np.stack([[np.median(x[width == b]) if (width == b).any() else np.nan for b in range(n_bins)],
                               [large[width == b].mean() if (width == b).any() else np.nan for b in range(n_bins)]]),
                 "the bins' means of |feature|: the figure puts each bin at its median":
                     np.stack([[x[p].mean() for p in parts], share]),
                 "the probability of the small values (< at_least), the complement": np.stack([mid, 1 - share]),
                 "the sum of the probabilities in a bin, not their mean":
                     np.stack([mid, [large[p].sum() for p in parts]])}
        what = _slip(mine, ref, slips)
        wrong = "the medians" if not _close(mine[0], mid) else "the shares"
        problems.append(f"{name}: {wrong} differ from the library's (largest difference "
                        f"{np.nanmax(np.abs(mine - ref)):.3g})" + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your switch-off curve is the library's (the curve of plot_switch_off) on all "
                              "three policies",
                    "share per state = probs[:, grid >= at_least].sum(axis=1); x = |feature|; parts = "
                    "np.array_split(np.argsort(x), n_bins); per part the median of x and the mean of the share")


def _signed(probs, g, feature, at_least, n_bins):
    from adaptfilt.course.policy_reading import equal_count_bins

    return equal_count_bins(feature, probs[:, g >= at_least].sum(axis=1), n_bins)


# ======================================================================== chapter 9
def _greedy_cases():
    """``(name, grid, m, P, z, R)``: UNGM information states (predicted mean and variance, measurement)
    with a spread of surprises: about half with NIS0 < 1 (the gate open), the rest up to NIS0 ~ 10^4."""
    from adaptfilt.experiment_registry import get_experiment

    rng = np.random.default_rng(9)
    grid = np.asarray(get_experiment("ungm-ukf").grid)
    out = []
    for M, R, spread in ((400, 0.1, 1.0), (300, 1.0, 3.0)):
        m = rng.normal(0.0, 10.0, M)
        P = rng.lognormal(0.0, 1.5, M)
        z_hat = (m * m + P) / 20.0
        pzz0 = 4 * m * m * P / 400.0 + R
        z = z_hat + np.sqrt(pzz0) * rng.standard_normal(M) * np.exp(rng.uniform(-1, 1, M) * 2.5 * spread)
        out.append((f"M = {M} states, R = {R:g}", grid, m, P, z, R))
    return out


def greedy_kappa(grid, x_pred, P_pred, z, R: float) -> np.ndarray:
    """The reference: the grid value minimising ``(NIS(kappa) - 1)^2`` with the closed-form NIS
    (:func:`adaptfilt.course.ungm_ukf.ungm_nis`), per state."""
    from adaptfilt.course.ungm_ukf import ungm_nis

    g = np.asarray(grid, dtype=float)
    nis = ungm_nis(g[:, None], x_pred[None], P_pred[None], z[None], R=R)
    return g[np.argmin((nis - 1.0) ** 2, axis=0)]


def _closed_form_choice(grid, m, P, z, R, z_hat=None, pzz=None, cost=None):
    g = np.asarray(grid, dtype=float)[:, None]
    z_hat = (m * m + P) / 20.0 if z_hat is None else z_hat
    pzz = (4 * m * m * P + g * P * P) / 400.0 + R if pzz is None else pzz(g)
    nis = (z - z_hat) ** 2 / pzz
    return g[:, 0][np.argmin((nis - 1.0) ** 2 if cost is None else cost(nis, pzz), axis=0)]


def check_greedy_kappa(my_greedy_kappa: Callable) -> bool:
    r"""Chapter 9: ``my_greedy_kappa(grid, x_pred, P_pred, z, R) -> (M,)``, the grid value greedy chooses on
    UNGM at ``M`` information states (predicted mean :math:`m` and variance :math:`P`, measurement
    :math:`z`, each ``(M,)``) from the closed form :math:`\hat z = (m^2 + P)/20`,
    :math:`P^{zz}(\kappa) = (4 m^2 P + \kappa P^2)/400 + R`, :math:`\mathrm{NIS} = (z - \hat z)^2 / P^{zz}`
    and the cost :math:`(\mathrm{NIS} - 1)^2`, against :func:`greedy_kappa` (which the tests check against
    the library's ``GreedyPolicy`` on the real UKF) on two sets of states. Names :math:`\hat z = m^2/20`,
    :math:`P^{zz}` without :math:`R` or with :math:`\kappa P`, the least NIS, an argmax, grid indices for
    values, and the maximum-likelihood choice; then checks the gate: full update (the smallest
    :math:`\kappa`) wherever :math:`\mathrm{NIS}_0 < 1`."""
    from adaptfilt.course.ungm_ukf import ungm_nis

    problems, gate = [], []
    for name, grid, m, P, z, R in _greedy_cases():
        ref = greedy_kappa(grid, m, P, z, R)
        out, why = _run(my_greedy_kappa, (np.asarray(grid, dtype=float).copy(), m.copy(), P.copy(), z.copy(), R))
        mine, why = (None, why) if why else _array(out, ref.shape, "one kappa per state")
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        open_ = ungm_nis(grid[0], m, P, z, R=R) < 1.0
        gate.append(f"{open_.mean():.0%} of the {len(m)} states with R = {R:g}")
        if np.array_equal(mine, ref):
            continue
        g = np.asarray(grid, dtype=float)
        slips = {"the predicted measurement m^2 / 20: for a Gaussian prior E[x^2] = m^2 + P, so z_hat = "
                 "(m^2 + P) / 20": _closed_form_choice(grid, m, P, z, R, z_hat=m * m / 20.0),
                 "P^zz without R: the measurement noise adds R": _closed_form_choice(
                     grid, m, P, z, R, pzz=lambda k: (4 * m * m * P + k * P * P) / 400.0),
                 "P^zz with kappa P, not kappa P^2": _closed_form_choice(
                     grid, m, P, z, R, pzz=lambda k: (4 * m * m * P + k * P) / 400.0 + R),
                 "the kappa of the least NIS: the cost is (NIS - 1)^2, not the NIS":
                     _closed_form_choice(grid, m, P, z, R, cost=lambda nis, pzz: nis),
                 "the argmax of the cost, not its argmin":
                     _closed_form_choice(grid, m, P, z, R, cost=lambda nis, pzz: -(nis - 1.0) ** 2),
                 "grid indices: return the kappa values, grid[index]": np.searchsorted(g, ref).astype(float),
                 "the maximum-likelihood choice (the largest log-likelihood), greedy's twin, which differs from "
                 "it on some states of a discrete grid": _closed_form_choice(
                     grid, m, P, z, R, cost=lambda nis, pzz: nis + np.log(pzz))}
        what = _slip(mine, ref, slips, close=lambda a, b: np.array_equal(np.asarray(a), np.asarray(b)))
        problems.append(f"{name}: your kappa differs from greedy's at {np.mean(mine != ref):.0%} of the states"
                        + (f"; yours is {what}" if what else ""))
    right = ("your greedy kappa is the library's on every state, and it opens fully (kappa = 0) exactly where "
             "NIS0 < 1 (" + ", ".join(gate) + "): the gate")
    return _verdict(problems, right,
                    "z_hat = (m^2 + P)/20; Pzz = (4 m^2 P + kappa P^2)/400 + R for every kappa (grid[:, None]); "
                    "NIS = (z - z_hat)^2 / Pzz; the kappa of the least (NIS - 1)^2 per state (argmin over axis 0)")


# ======================================================================== chapter 10
def _los_cases():
    """``(name, x, mean, cov)``: the default UKF on a few CTM runs, and a synthetic filter whose
    covariance is far from isotropic (so that the claimed spread differs by direction)."""
    from adaptfilt.gaf import UKF
    from adaptfilt.models import coordinated_turn

    model = coordinated_turn()
    traj = model.simulate(n_runs=6, n_steps=40, rng=np.random.default_rng(10))
    run = UKF(model).run(traj.z)
    rng = np.random.default_rng(11)
    x = traj.x + rng.normal(0.0, 50.0, traj.x.shape)
    A = rng.standard_normal(x.shape + (4,)) * np.array([30.0, 3.0, 10.0, 2.0])
    cov = A @ np.swapaxes(A, -1, -2) + np.eye(4)
    mean = x + rng.normal(0.0, 20.0, x.shape)
    return [("the UKF on 6 CTM runs x 40 steps", traj.x, run.mean, run.cov),
            ("a synthetic filter on 6 x 40 states", x, mean, cov)]


def check_line_of_sight(my_line_of_sight: Callable) -> bool:
    r"""Chapter 10: ``my_line_of_sight(x, mean, cov) -> (err_range, err_cross, sd_range, sd_cross)``, each
    ``(M, T)``: the position error :math:`\tilde{\mathbf p} = \mathbf p - \hat{\mathbf p}` (position: state
    components 0 and 2) along the true line of sight :math:`\mathbf u = \mathbf p/\|\mathbf p\|` and across
    it, :math:`\mathbf v = [-u_2, u_1]`, and the standard deviations the filter claims there,
    :math:`\sqrt{\mathbf u^T \mathbf P^{pp} \mathbf u}` and :math:`\sqrt{\mathbf v^T \mathbf P^{pp} \mathbf v}`.
    Compared with :func:`adaptfilt.course.ctm_ukf.line_of_sight` on a UKF run and a synthetic filter; the
    signs of the errors are a convention (either sign is right). Names the line of sight taken from the
    estimate, variances for standard deviations, the wrong position components, the inverse covariance and
    the swapped directions."""
    from types import SimpleNamespace

    from adaptfilt.course.ctm_ukf import line_of_sight

    def los(x, mean, cov, u_from=None, pos=(0, 2)):
        r = line_of_sight(x if u_from is None else u_from, SimpleNamespace(mean=mean, cov=cov), pos)
        if u_from is not None:  # the directions of u_from, the errors of x
            p, ph = np.asarray(x)[..., list(pos)], mean[..., list(pos)]
            u = u_from[..., list(pos)] / np.linalg.norm(u_from[..., list(pos)], axis=-1, keepdims=True)
            v = np.stack([-u[..., 1], u[..., 0]], -1)
            e = p - ph
            return np.stack([(e * u).sum(-1), (e * v).sum(-1), r.sd_range, r.sd_cross])
        return np.stack([r.err_range, r.err_cross, r.sd_range, r.sd_cross])

    def same(a, b):  # either sign of each error is a convention
        return a.shape == b.shape and all(_close(np.abs(a[i]), np.abs(b[i]), 1e-8, 1e-8) for i in range(4))

    problems = []
    for name, x, mean, cov in _los_cases():
        ref = los(x, mean, cov)
        out, why = _run(my_line_of_sight, (x.copy(), mean.copy(), cov.copy()))
        if why is None:
            try:
                mine = np.stack([np.asarray(a, dtype=float) for a in out])
            except (TypeError, ValueError):
                mine, why = None, f"returned {type(out).__name__}, not four arrays"
            else:
                if mine.shape != ref.shape:
                    why = f"returned four arrays of shape {mine.shape[1:]} (or not four), expected {ref.shape[1:]}"
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        if same(mine, ref):
            continue
        inv = np.linalg.inv(cov)
        slips = {"the line of sight of the estimate: u = p / |p| of the true position (the estimate's "
                 "direction moves with its own error)": los(x, mean, cov, u_from=mean),
                 "variances, not standard deviations: take the square root of u^T P u":
                     np.stack([ref[0], ref[1], ref[2] ** 2, ref[3] ** 2]),
                 "the components 0 and 1 as the position: the state is [px, vx, py, vy], position (0, 2)":
                     los(x, mean, cov, pos=(0, 1)),
                 "the inverse covariance: the claimed variance along u is u^T P u, not u^T P^-1 u":
                     los(x, mean, inv),
                 "range and cross-range swapped": ref[[1, 0, 3, 2]]}
        what = _slip(mine, ref, slips, close=same)
        parts = ["range error", "cross-range error", "range sd", "cross-range sd"]
        bad = [p for p, a, b in zip(parts, mine, ref) if not _close(np.abs(a), np.abs(b), 1e-8, 1e-8)]
        problems.append(f"{name}: your {', '.join(bad)} differ from the library's"
                        + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your line-of-sight split is the library's (ctm_ukf.line_of_sight) on the UKF "
                              "and on the synthetic filter",
                    "p = x[..., [0, 2]], u = p / norm(p), v = [-u_y, u_x]; e = p - mean[..., [0, 2]]; errors e . u and "
                    "e . v; Ppp = cov[..., [0, 2], :][..., [0, 2]]; sd = sqrt(u^T Ppp u) (np.einsum)")


# ======================================================================== chapter 11
def _break_even_cases():
    """``(name, a, b)``: Table-I-like columns (``cost``, ``n_iter_spent``, ``mean_n_iter``) of two policies."""
    col = lambda cost, spent, chosen: {"cost": cost, "n_iter_spent": spent, "mean_n_iter": chosen}  # noqa: E731
    return [("a learned policy against a constant", col(4.602, 2.90, 1.90), col(4.648, 5.0, 5.0)),
            ("a learned policy against greedy", col(4.602, 2.90, 1.90), col(4.339, 30.0, 3.30)),
            ("a constant against greedy", col(3.756, 20.0, 20.0), col(4.357, 30.0, 1.85)),
            ("two policies that look equally (no break-even price)", col(0.50, 3.0, 2.0), col(0.52, 2.5, 1.5))]


def break_even(a, b) -> float:
    """The reference: the price ``p`` per deciding iteration at which ``cost + p * look`` is the same for
    ``a`` and ``b`` (``look = n_iter_spent - mean_n_iter``, the iterations computed only to decide); ``inf``
    when both look equally (the charged costs never meet unless the costs are equal)."""
    la, lb = a["n_iter_spent"] - a["mean_n_iter"], b["n_iter_spent"] - b["mean_n_iter"]
    return float("inf") if np.isclose(la, lb) else (b["cost"] - a["cost"]) / (la - lb)


def check_break_even(my_break_even: Callable) -> bool:
    r"""Chapter 11: ``my_break_even(a, b) -> price``: ``a`` and ``b`` are columns of Table I (dicts with the
    uncharged ``cost``, the iterations spent per step ``n_iter_spent`` and those of the update that ran,
    ``mean_n_iter``); the price per iteration computed only to decide at which the charged costs
    :math:`c_a + p\,\ell_a = c_b + p\,\ell_b` are equal (:math:`\ell = ` ``n_iter_spent - mean_n_iter``),
    ``inf`` (or ``nan``) when :math:`\ell_a = \ell_b`. Against :func:`break_even` on four pairs. Names a
    look counted as every iteration spent or as the update's, a flipped sign, the inverse and a price in
    units of the charge 1/50."""
    problems = []
    for name, a, b in _break_even_cases():
        ref = break_even(a, b)
        out, why = _run(my_break_even, (dict(a), dict(b)))
        mine, why = (None, why) if why else _array(out, (), "one price")
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        mine = float(mine)
        if np.isinf(ref) and not np.isfinite(mine) or np.isclose(mine, ref, rtol=1e-9, atol=0):
            continue
        ca, cb = a["cost"], b["cost"]
        sa, sb, na, nb = a["n_iter_spent"], b["n_iter_spent"], a["mean_n_iter"], b["mean_n_iter"]
        slips = {"the look counted as every iteration spent: the update's own iterations are already in the "
                 "cost (N_it / 50), only n_iter_spent - mean_n_iter is computed to decide": (cb - ca) / (sa - sb),
                 "the look counted as the update's iterations (mean_n_iter): those are charged by the cost "
                 "already": (cb - ca) / (na - nb) if na != nb else np.inf,
                 "the sign flipped: cost_a + p look_a = cost_b + p look_b gives p = (cost_b - cost_a) / "
                 "(look_a - look_b)": -ref,
                 "the inverse of the price": 1.0 / ref if ref not in (0.0, np.inf) else np.nan,
                 "the price in units of the charge 1/50 (a factor 50 off)": ref * 50.0,
                 "the price divided by 50": ref / 50.0}
        what = _slip(mine, ref, slips, close=lambda x, y: bool(np.isclose(x, y, rtol=1e-9, atol=0)))
        problems.append(f"{name}: yours {mine:.4g}, the library's {ref:.4g}" + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your break-even price is right on all four pairs",
                    "look = n_iter_spent - mean_n_iter for each; price = (cost_b - cost_a) / (look_a - look_b); "
                    "np.inf when look_a == look_b")


# ======================================================================== chapter 12
#: The system of chapter 12's exercise: a pendulum with a periodic push, observed by the bob's horizontal
#: position (``h`` at step ``k``), step ``dt``.
PENDULUM = dict(dt=0.1, g_over_l=9.81 / 2.0, length=2.0, push=0.5, omega=0.3, q=(1e-4, 1e-2), r=0.01,
                m0=(0.5, 0.0), p0=(0.1, 0.1), n_steps=100)


def pendulum_model():
    """The reference model of chapter 12's exercise (:data:`PENDULUM`): state ``[theta, omega]``,

    ``theta' = theta + dt omega``, ``omega' = omega - dt (g/l) sin(theta) + dt push cos(omega_d k) + w``,
    ``z = l sin(theta) + v``, ``w ~ N(0, diag(q))``, ``v ~ N(0, r)``."""
    from adaptfilt.models import StateSpaceModel

    c = PENDULUM

    def f(x, k):
        th, om = x[..., 0], x[..., 1]
        return np.stack([th + c["dt"] * om, om - c["dt"] * c["g_over_l"] * np.sin(th)
                         + c["dt"] * c["push"] * np.cos(c["omega"] * k)], axis=-1)

    def h(x, k):
        return c["length"] * np.sin(x[..., :1])

    return StateSpaceModel(f=f, h=h, Q=np.diag(c["q"]), R=[[c["r"]]], m0=list(c["m0"]), P0=np.diag(c["p0"]),
                           name="pendulum", n_steps=c["n_steps"])


def check_model(my_model: Callable) -> bool:
    r"""Chapter 12: ``my_model() -> StateSpaceModel`` of the pendulum of :data:`PENDULUM` (the exercise
    states it). Compares ``f`` and ``h`` with :func:`pendulum_model`'s on a batch of states at several steps
    (shapes ``(..., 2)``), then ``Q``, ``R``, ``m0``, ``P0`` and the horizon, then the moments of a
    simulation (2000 runs, the same seed: mean and variance of the measurement at three steps). Names a
    standard deviation given for a variance, the push at the wrong step, the state's components swapped,
    a missing ``dt`` and a function that is not batched."""
    from adaptfilt.models import StateSpaceModel

    ref = pendulum_model()
    out, why = _run(my_model, ())
    if why:
        return _verdict([f"your function {why}"], "", "return af.StateSpaceModel(f=..., h=..., Q=..., R=..., m0=..., "
                                                      "P0=..., n_steps=100)")
    if not isinstance(out, StateSpaceModel):
        return _verdict([f"your function returned {type(out).__name__}, not an af.StateSpaceModel"], "",
                        "return af.StateSpaceModel(...)")
    problems = []
    rng = np.random.default_rng(12)
    x = np.stack([rng.uniform(-2, 2, (5, 3)), rng.uniform(-3, 3, (5, 3))], axis=-1)
    c = PENDULUM
    for fname in ("f", "h"):
        for k in (1, 7, 40):
            got, why = _run(getattr(out, fname), (x.copy(), k))
            want = getattr(ref, fname)(x, k)
            if why is None:
                got, why = _array(got, want.shape, f"{fname}(x, k) on x of shape {x.shape}")
            if why:
                problems.append(f"{fname}(x, {k}): {why} (batched: index x[..., 0], not x[0])")
                break
            if _close(got, want):
                continue
            line = f"{fname}(x, {k}) differs (largest difference {np.abs(got - want).max():.3g})"
            if fname == "f":
                th, om = x[..., 0], x[..., 1]
                alts = {"the push at step k + 1 (it is cos(omega k) at step k)": lambda s: np.cos(c["omega"] * (k + s)),
                        "the push at step k - 1 (it is cos(omega k) at step k)": lambda s: np.cos(c["omega"] * (k - s))}
                for what, push in alts.items():
                    alt = np.stack([th + c["dt"] * om, om - c["dt"] * c["g_over_l"] * np.sin(th)
                                    + c["dt"] * c["push"] * push(1)], axis=-1)
                    if _close(got, alt):
                        line += f"; yours is {what}"
                if _close(got, np.stack([th + om, om - c["g_over_l"] * np.sin(th) + c["push"] * np.cos(c["omega"] * k)],
                                        axis=-1)):
                    line += "; yours has no time step dt (Euler: x' = x + dt * derivative)"
                if _close(got[..., ::-1], ref.f(x[..., ::-1], k)):
                    line += "; yours swaps theta and omega: the state is [theta, omega]"
            elif _close(got, c["length"] * np.sin(x[..., 1:2])):
                line += "; yours reads omega: the bob's position depends on the angle, x[..., 0]"
            problems.append(line)
            break
    for what, mat in (("Q", "Q"), ("R", "R"), ("P0", "P0"), ("m0", "m0")):
        a, b = np.asarray(getattr(out, mat), dtype=float), np.asarray(getattr(ref, mat), dtype=float)
        if a.shape != b.shape or not _close(a, b):
            hint = ("; yours is the standard deviations: the model takes variances" if a.shape == b.shape
                    and _close(a, np.sqrt(b)) else "")
            problems.append(f"{what} is {a.tolist()}, the system's is {b.tolist()}{hint}")
    if out.n_steps != ref.n_steps:
        problems.append(f"n_steps is {out.n_steps}, the system's horizon is {ref.n_steps}")
    if not problems:
        zs = [m.simulate(2000, rng=np.random.default_rng(5)).z[..., 0] for m in (out, ref)]
        for k in (1, 20, 99):
            if not (np.isclose(zs[0][:, k].mean(), zs[1][:, k].mean(), atol=1e-9)
                    and np.isclose(zs[0][:, k].var(), zs[1][:, k].var(), rtol=1e-9)):
                problems.append(f"the simulated measurements differ at step {k + 1}: mean {zs[0][:, k].mean():.4g} "
                                f"against {zs[1][:, k].mean():.4g}")
    moments = ""
    if not problems:
        z = zs[1]
        moments = (": f and h agree at every probed state, the matrices are the system's, and a simulation of 2000 "
                   f"runs has the same measurement moments (step 20: mean {z[:, 19].mean():.3f}, variance "
                   f"{z[:, 19].var():.3f})")
    return _verdict(problems, "your model is the pendulum" + moments,
                    "f(x, k) = np.stack([th + dt*om, om - dt*(g/l)*np.sin(th) + dt*push*np.cos(omega_d*k)], -1) with "
                    "th, om = x[..., 0], x[..., 1]; h(x, k) = l*np.sin(x[..., :1]); Q = np.diag(q) (variances)")


# ======================================================================== chapter 13
def _iqm_cases():
    """``(name, values (n,), boot (n, B), idx (B, n))``: per-seed values with run-level replicates (one
    seed far off, as a diverged one), and the seed draws of the two-level bootstrap."""
    rng = np.random.default_rng(13)
    out = []
    for n, B in ((8, 1000), (5, 800), (10, 1000)):
        values = rng.normal(2.9, 0.05, n)
        values[0] += 1.5                                   # one seed in a poor optimum
        boot = values[:, None] + rng.normal(0.0, 0.02, (n, B)) * rng.lognormal(0.0, 0.5, n)[:, None]
        out.append((f"{n} seeds, B = {B}", values, boot, rng.integers(0, n, size=(B, n))))
    return out


def two_level_iqm(values, boot, idx) -> np.ndarray:
    """The reference ``(iqm, lo, hi)``: the IQM of the per-seed values and the 95 % percentile interval of
    replicate ``b``'s IQM over the seeds ``idx[b]`` each at run-resample ``b`` (as :mod:`adaptfilt.seed_stats`
    draws it; the tests check that it is ``seed_stats.aggregate``'s)."""
    from adaptfilt.seed_stats import iqm

    rep = iqm(boot[idx, np.arange(idx.shape[0])[:, None]], axis=1)
    return np.array([float(iqm(values)), *np.quantile(rep, [0.025, 0.975])])


def check_two_level_iqm(my_two_level: Callable) -> bool:
    r"""Chapter 13: ``my_two_level(values, boot, idx) -> (iqm, lo, hi)``: the interquartile mean of the
    per-seed values ``(n,)`` and its two-level 95 % interval, where replicate ``b`` takes the seeds
    ``idx[b]`` (``(B, n)``, drawn with replacement) each at its run-level replicate ``boot[seed, b]``
    (``(n, B)``), against :func:`two_level_iqm` on three groups (8, 5 and 10 seeds, one far off). Any
    standard percentile convention is right (within one replicate). Names the mean or the median for the
    IQM, a wrong trim, the runs alone (no seeds resampled), the seeds alone (no run noise) and the
    replicate's seeds each at the wrong run-resample."""
    from adaptfilt.seed_stats import iqm

    problems = []
    for name, values, boot, idx in _iqm_cases():
        ref = two_level_iqm(values, boot, idx)
        out, why = _run(my_two_level, (values.copy(), boot.copy(), idx.copy()))
        mine, why = (None, why) if why else _array(out, (3,), "three numbers (iqm, lo, hi)")
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        B = idx.shape[0]
        rep = boot[idx, np.arange(B)[:, None]]
        if _close(mine[0], ref[0], 1e-9, 1e-12) and _within_a_replicate(mine[1:], iqm(rep, axis=1)):
            continue
        ci = lambda r: np.quantile(r, [0.025, 0.975])  # noqa: E731
        srt = np.sort(rep, axis=1)
        slips = {"the mean over seeds, not the IQM (one poor seed moves a mean)":
                     np.array([values.mean(), *ci(rep.mean(1))]),
                 "the median over seeds, not the IQM (the mean of the middle half)":
                     np.array([np.median(values), *ci(np.median(rep, 1))]),
                 "the mean without the extremes only: the IQM drops a quarter of the seeds at each end":
                     np.array([np.sort(values)[1:-1].mean(), *ci(srt[:, 1:-1].mean(1))]),
                 "the runs alone: every replicate takes all seeds once (no seed resampled), the interval of "
                 "'other runs, the same policies'": np.array([ref[0], *ci(iqm(boot, axis=0))]),
                 "the seeds alone: the seeds' point values resampled, without the run-level replicates":
                     np.array([ref[0], *ci(iqm(values[idx], axis=1))]),
                 "each drawn seed at a run-resample of its own index, not the replicate's b: boot[idx, b]":
                     np.array([ref[0], *ci(iqm(boot[idx, idx], axis=1))])}
        what = _slip(mine, ref, slips, close=lambda a, b: _close(a, b, 1e-6, 1e-12))
        problems.append(f"{name}: yours {np.round(mine, 4).tolist()}, the library's {np.round(ref, 4).tolist()}"
                        + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your two-level IQM interval is the library's (seed_stats) on all three groups",
                    "rep = boot[idx, np.arange(B)[:, None]] (B, n); the IQM of each row (scipy.stats.trim_mean(rep, "
                    "0.25, axis=1)); the 2.5th and 97.5th percentiles; the estimate trim_mean(values, 0.25)")


# ======================================================================== chapter 14
def _two_bearings():
    """The coordinated turn seen by two bearing sensors (the origin and (100, -50)): ``n_z = 2``."""
    from adaptfilt.models import StateSpaceModel, coordinated_turn, wrap_angle

    ctm = coordinated_turn()

    def h(x, k):
        return np.concatenate([np.arctan2(x[..., 2:3], x[..., 0:1]),
                               np.arctan2(x[..., 2:3] + 50.0, x[..., 0:1] - 100.0)], axis=-1)

    return StateSpaceModel(f=ctm.f, h=h, Q=ctm.Q, R=np.diag([0.04, 0.04]), m0=ctm.m0, P0=ctm.P0,
                           residual=lambda a, b: wrap_angle(a - b), name="ctm-two-bearings", n_steps=150,
                           F=ctm.F, circular_z=(0, 1))


def _candidate_cases():
    """``(name, filt, x_pred, P_pred, z, t, grid, ref (M, G))``: decisions of a UKF environment with the
    NIS cost, a few steps into an episode, and the environment's own candidate costs (one tiled update)."""
    from adaptfilt.costs import Cost
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.gaf import UKF
    from adaptfilt.mdp import FilterEnv
    from adaptfilt.models import coordinated_turn, ungm

    out = []
    for name, model, grid, t_at in (("UNGM", ungm(), get_experiment("ungm-ukf").grid, 5),
                                    # kappa >= 0 (a negative kappa can leave P_filt indefinite: the update raises)
                                    ("bearing-only CTM", coordinated_turn(), (0.0, 0.5, 2.0, 10.0, 50.0), 3),
                                    ("CTM with two bearing sensors (n_z = 2)", _two_bearings(), (0.0, 1.0, 5.0, 20.0), 4)):
        env = FilterEnv(UKF(model), grid, cost=Cost("nis"), n_steps=12)
        d = env.reset(traj=model.simulate(8, 12, rng=np.random.default_rng(14)))
        for _ in range(t_at):
            d, *_ = env.step(np.full(d.n_runs, env.default_index))
        ref = np.log1p(d.candidates()["cost"]).T
        out.append((f"{name}, step {d.t}", env.filt, d.x_pred.copy(), d.P_pred.copy(), d.z.copy(), d.t,
                    np.asarray(grid, dtype=float), ref))
    return out


def check_candidate_costs(my_candidate_costs: Callable) -> bool:
    r"""Chapter 14: ``my_candidate_costs(filt, x_pred, P_pred, z, t, grid) -> (M, G)``, the candidate-aware
    features: for every grid value :math:`\theta_g` the one-step cost :math:`\log(1 + \bar L_\text{NIS})`,
    :math:`\bar L_\text{NIS} = (\mathrm{NIS}(\theta_g) - n_z)^2`, of the update ``filt.update(x_pred, P_pred,
    z, t, param=theta_g)`` (``x_pred (M, nx)``, ``P_pred (M, nx, nx)``, ``z (M, nz)``). Against the
    environment's own tiled computation (``Decision.candidates``) on UNGM, the CTM and a CTM with two
    sensors. Names the NIS or the raw cost for the feature, ``- 1`` for ``- n_z``, the log without the 1,
    the default's NIS for every candidate and the log-likelihood."""
    problems = []
    for name, filt, m, P, z, t, grid, ref in _candidate_cases():
        out, why = _run(my_candidate_costs, (filt, m.copy(), P.copy(), z.copy(), t, grid.copy()))
        mine, why = (None, why) if why else _array(out, ref.shape, "(M, G): one cost per run and grid value")
        if why is None and mine.shape == ref.shape[::-1] and ref.shape[0] != ref.shape[1]:
            why = "returned (G, M): one row per run, one column per grid value"
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        if _close(mine, ref, 1e-7, 1e-9):
            continue
        ups = [filt.update(m, P, z, t, param=g) for g in grid]
        nis = np.stack([u.nis for u in ups], axis=1)
        nz = z.shape[1]
        default = filt.update(m, P, z, t).nis[:, None] + 0 * nis
        slips = {"the NIS itself: the feature is log(1 + (NIS - n_z)^2)": nis,
                 "the raw cost (NIS - n_z)^2, without the log": (nis - nz) ** 2,
                 "log(1 + (NIS - 1)^2): the cost subtracts n_z, not 1": np.log1p((nis - 1) ** 2),
                 "log((NIS - n_z)^2), without the 1 (a cost of 0 would be -inf)":
                     np.log(np.maximum((nis - nz) ** 2, 1e-300)),
                 "the default's NIS for every candidate: update with param=theta_g":
                     np.log1p((default - nz) ** 2),
                 "the log-likelihood, not the NIS cost": np.stack([u.loglik for u in ups], axis=1)}
        what = _slip(mine, ref, slips, close=lambda a, b: _close(a, b, 1e-7, 1e-9))
        problems.append(f"{name}: your costs differ from the environment's (largest difference "
                        f"{np.nanmax(np.abs(mine - ref)):.3g})" + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your candidate costs are the environment's (Decision.candidates) on UNGM, the "
                              "CTM and two bearing sensors",
                    "for each g of grid: u = filt.update(x_pred, P_pred, z, t, param=g); cost = np.log1p((u.nis - "
                    "z.shape[1]) ** 2); stack the G columns (axis=1)")


# ======================================================================== chapter 15
def _mismatch_cases():
    """``(name, F, H, Q, R, q_scale, r_scale)``: scalar linear models, the truth's noise scaled."""
    return [("F = 0.9, H = 1, Q = 1, R = 1; truth Q x 4", 0.9, 1.0, 1.0, 1.0, 4.0, 1.0),
            ("F = 0.9, H = 1, Q = 1, R = 1; truth R x 0.25", 0.9, 1.0, 1.0, 1.0, 1.0, 0.25),
            ("F = 1, H = 0.5, Q = 0.2, R = 2; truth Q x 0.25, R x 4", 1.0, 0.5, 0.2, 2.0, 0.25, 4.0),
            ("F = 0.5, H = 2, Q = 3, R = 0.5; truth Q x 4, R x 4", 0.5, 2.0, 3.0, 0.5, 4.0, 4.0)]


def _steady_gain(F, H, Q, R) -> tuple[float, float]:
    """The steady-state predicted variance and gain of the scalar Kalman filter (Riccati fixed point)."""
    P = Q
    for _ in range(2000):
        P = F * F * P * R / (H * H * P + R) + Q
    return P, P * H / (H * H * P + R)


def mismatched_nis(F, H, Q, R, q_scale, r_scale, mismatch_in_sigma: bool = True, with_kr: bool = True) -> float:
    r"""The reference: the steady-state mean NIS of the scalar Kalman filter designed with ``Q``, ``R`` on data
    whose noise variances are ``q_scale Q`` and ``r_scale R``. The filter's gain ``K`` and its claimed
    innovation variance :math:`S = H^2 P + R` come from its own Riccati recursion; the true predicted error
    variance :math:`\Sigma` is the fixed point of :math:`\Sigma = F^2 (1 - K H)^2 \Sigma + F^2 K^2 r R + q Q`, and
    :math:`E[\mathrm{NIS}] = (H^2 \Sigma + r R) / S` (the tests check it by simulation with the library's
    Kalman filter). The two switches make the slips the checker names."""
    P, K = _steady_gain(F, H, Q, R)
    qT, rT = (q_scale * Q, r_scale * R) if mismatch_in_sigma else (Q, R)
    S_true = 0.0
    A = F * F * (1 - K * H) ** 2
    sigma = (qT + (F * F * K * K * rT if with_kr else 0.0)) / (1 - A)
    S_true = H * H * sigma + rT
    return S_true / (H * H * P + R)


def check_mismatched_nis(my_nis_mean: Callable) -> bool:
    r"""Chapter 15: ``my_nis_mean(F, H, Q, R, q_scale, r_scale) -> float``, the steady-state mean NIS of a
    scalar Kalman filter that assumes the noise variances ``Q`` and ``R`` while the truth has ``q_scale Q``
    and ``r_scale R`` (chapter 15's out-of-distribution test in closed form), against
    :func:`mismatched_nis` on four models. Names the filter's own expectation (1), the truth's optimal
    filter's ratio, the mismatch taken into the gain, the inverse ratio and a true error variance without
    the measurement noise the gain feeds back."""
    problems = []
    for name, F, H, Q, R, q, r in _mismatch_cases():
        ref = mismatched_nis(F, H, Q, R, q, r)
        out, why = _run(my_nis_mean, (F, H, Q, R, q, r))
        mine, why = (None, why) if why else _array(out, (), "one number")
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        mine = float(mine)
        if np.isclose(mine, ref, rtol=1e-6):
            continue
        Pt, _ = _steady_gain(F, H, q * Q, r * R)
        P, _ = _steady_gain(F, H, Q, R)
        slips = {"1, the NIS the filter expects of itself: the mismatch is in the data, not in the filter": 1.0,
                 "the ratio of the truth's own optimal filter's S to the filter's: the filter keeps its own gain, "
                 "which the truth's noise then runs through": (H * H * Pt + r * R) / (H * H * P + R),
                 "the true error variance without F^2 K^2 R_true (the measurement noise the gain feeds back)":
                     mismatched_nis(F, H, Q, R, q, r, with_kr=False),
                 "the inverse ratio: NIS = the true innovation variance / the claimed one": 1.0 / ref,
                 "the q_scale and r_scale applied to R and Q the other way round": mismatched_nis(F, H, Q, R, r, q)}
        what = _slip(mine, ref, slips, close=lambda a, b: bool(np.isclose(a, b, rtol=1e-6)))
        problems.append(f"{name}: yours {mine:.4g}, the library's {ref:.4g}" + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your steady-state NIS mean is right on all four models",
                    "the filter's P from its own Riccati recursion with Q, R (iterate to the fixed point), K = P H / "
                    "(H^2 P + R); the true Sigma = (q Q + F^2 K^2 r R) / (1 - F^2 (1 - K H)^2); NIS = (H^2 Sigma + "
                    "r R) / (H^2 P + R)")


# ======================================================================== chapter 16
def _rollout_cases():
    """``(name, L0 (G, M), C (G, G, S, M), gamma)``: heavy-tailed synthetic one-step and next-step costs."""
    rng = np.random.default_rng(16)
    out = []
    for G, S, M, gamma in ((5, 10, 30, 0.5), (4, 3, 20, 0.9), (6, 7, 25, 0.3)):
        L0 = rng.gamma(0.8, 1.0, (G, M))
        C = rng.gamma(0.8, 1.0, (G, G, S, M)) * rng.uniform(0.3, 3.0, (G, 1, 1, 1))
        out.append((f"G = {G}, S = {S} continuations, M = {M} runs, gamma = {gamma}", L0, C, gamma))
    return out


def rollout_value(L0, C, gamma) -> np.ndarray:
    r"""The reference :math:`Q_1(\theta) = L_0(\theta) + \gamma\,\frac1S\sum_s \min_{\theta'} C(\theta, \theta', s)`,
    per run: greedy (the base policy) picks the cheapest next value in every continuation ``s``, the
    continuations are averaged (as :class:`adaptfilt.lookahead.RolloutPolicy` with ``horizon=1`` does; the
    tests check it on a real decision)."""
    return L0 + gamma * C.min(axis=1).mean(axis=1)


def check_rollout_value(my_rollout_value: Callable) -> bool:
    r"""Chapter 16: ``my_rollout_value(L0, C, gamma) -> (G, M)``: the one-step rollout value of every candidate,
    ``L0 (G, M)`` the one-step cost of each candidate :math:`\theta` and ``C (G, G, S, M)`` the next step's cost
    of every value :math:`\theta'` in continuation ``s`` after :math:`\theta`, with greedy as the base policy.
    Against :func:`rollout_value` on three cases. Names greedy's choice made once for all continuations
    (the min of the mean), no discount, a random base policy (the mean over the next values), the worst
    next value, the look-ahead alone (no ``L0``), the discount on ``L0`` and the wrong axis."""
    problems = []
    for name, L0, C, gamma in _rollout_cases():
        ref = rollout_value(L0, C, gamma)
        out, why = _run(my_rollout_value, (L0.copy(), C.copy(), gamma))
        mine, why = (None, why) if why else _array(out, ref.shape, "one value per candidate and run")
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        if _close(mine, ref):
            continue
        slips = {"greedy's next value chosen once for all continuations (the min of the mean over s): greedy "
                 "chooses in every continuation, after its measurement": L0 + gamma * C.mean(axis=2).min(axis=1),
                 "no discount on the next step": L0 + C.min(axis=1).mean(axis=1),
                 "the mean over the next values: a random base policy, not greedy": L0 + gamma * C.mean(axis=(1, 2)),
                 "the worst next value (max), not greedy's (min)": L0 + gamma * C.max(axis=1).mean(axis=1),
                 "the look-ahead without this step's cost L0": gamma * C.min(axis=1).mean(axis=1),
                 "the discount on L0 as well": gamma * (L0 + C.min(axis=1).mean(axis=1)),
                 "the min over the wrong axis (the candidates theta, axis 0, not the next values, axis 1)":
                     L0 + gamma * C.min(axis=0).mean(axis=1)}
        what = _slip(mine, ref, slips)
        problems.append(f"{name}: your values differ (largest difference {np.abs(mine - ref).max():.3g})"
                        + (f"; yours is {what}" if what else ""))
    return _verdict(problems, "your rollout value is the library's rule (RolloutPolicy, horizon 1) on all three "
                              "cases",
                    "C.min(axis=1): greedy's next cost in every continuation (G, S, M); .mean(axis=1) over the "
                    "continuations; Q = L0 + gamma * that")


# ======================================================================== chapter 17
def _kld_cases():
    """``(name, x (n, nx), bin_size, epsilon, delta, n_min)``: particles in draw order, one and two modes,
    one and two dimensions."""
    rng = np.random.default_rng(17)
    two = np.where(rng.random(4000) < 0.5, -8.0, 8.0) + rng.standard_normal(4000)
    return [("UNGM-like, two modes, bins of 1", two[:, None], 1.0, 0.05, 0.01, 50),
            ("one mode, bins of 0.25, epsilon = 0.1", rng.standard_normal((3000, 1)) * 2, 0.25, 0.1, 0.01, 50),
            ("two dimensions, bins of (1, 0.5), delta = 0.05", rng.standard_normal((5000, 2)) * [4.0, 1.0],
             np.array([1.0, 0.5]), 0.05, 0.05, 50),
            ("a narrow posterior: n_min decides", rng.standard_normal((2000, 1)) * 0.3, 1.0, 0.05, 0.01, 100)]


def _kld_variant(x, bin_size, epsilon, delta, n_min, bound=None, offset=0.0, all_bins=False,
                 use_n_min=True) -> int:
    """KLD-sampling's count with the given bound ``bound(k, epsilon, delta)`` (default: the library's
    Wilson-Hilferty :func:`~adaptfilt.particles.kld_bound`) and switches: the right count, an accepted
    convention or a slip to name."""
    from adaptfilt.particles import kld_bound

    q = np.floor(x / bin_size + offset).astype(np.int64)
    _, first = np.unique(q, axis=0, return_index=True)
    new = np.zeros(len(x), dtype=int)
    new[first] = 1
    k = np.full(len(x), new.sum()) if all_bins else np.cumsum(new)
    n = np.arange(1, len(x) + 1)
    b = (kld_bound if bound is None else bound)(k.astype(float), epsilon, delta)
    ok = (n >= b) & ((n >= n_min) if use_n_min else True)
    return int(n[ok.argmax()]) if ok.any() else len(x)


def _wh(k, epsilon, delta, dof=lambda k: k - 1, z=lambda d: 1 - d, two=2.0):
    """The Wilson-Hilferty bound with a choice of degrees of freedom, quantile and factor (the slips)."""
    from scipy import stats

    km1 = np.maximum(dof(k), 1.0)
    a = 2.0 / (9.0 * km1)
    return np.where(k > 1, km1 / (two * epsilon) * (1.0 - a + np.sqrt(a) * stats.norm.ppf(z(delta))) ** 3, 1.0)


def _chi2_bound(k, epsilon, delta):
    from scipy import stats

    return np.where(k > 1, stats.chi2.ppf(1 - delta, np.maximum(k - 1, 1)) / (2 * epsilon), 1.0)


def check_kld_count(my_kld_count: Callable) -> bool:
    r"""Chapter 17: ``my_kld_count(x, bin_size, epsilon, delta, n_min) -> int``, KLD-sampling's count for the
    particles ``x (n, nx)`` in the order they were drawn: the smallest ``n >= n_min`` with :math:`n \ge`
    the Wilson-Hilferty bound of the ``k(n)`` bins of width ``bin_size`` that the first ``n`` occupy,
    ``len(x)`` if never, against :func:`adaptfilt.particles.kld_count` on four cases. The exact chi-square
    quantile (which the chapter shows agrees with Wilson-Hilferty to a particle) and bins offset by half a
    width (rounding, another partition of the same width) are accepted as right. Names ``k`` for ``k - 1``,
    :math:`z_{1-\delta/2}`, a bound without the factor 2, the bins of all ``n`` particles from the start
    and ``n_min`` left out."""
    from adaptfilt.particles import kld_count

    problems, notes = [], set()
    for name, x, bin_size, eps, delta, n_min in _kld_cases():
        ref = kld_count(x, bin_size, eps, delta, n_min=n_min)
        out, why = _run(my_kld_count, (x.copy(), bin_size, eps, delta, n_min))
        if why is None:
            try:
                mine = int(np.asarray(out).item())
            except (TypeError, ValueError):
                why = f"returned {out!r}, not one count"
        if why:
            problems.append(f"{name}: your function {why}")
            continue
        if mine == ref:
            continue
        args = (x, bin_size, eps, delta, n_min)
        accepted = {"the exact chi-square quantile for the bound": _kld_variant(*args, bound=_chi2_bound),
                    "bins by rounding (offset by half a width)": _kld_variant(*args, offset=0.5)}
        ok = [what for what, alt in accepted.items() if mine == alt]
        if ok:
            notes.add(ok[0])
            continue
        slips = {"k, not k - 1, degrees of freedom": _kld_variant(*args, bound=lambda k, e, d: _wh(k, e, d, dof=lambda k: k)),
                 "z_{1 - delta/2}: the bound is one-sided, z_{1 - delta}":
                     _kld_variant(*args, bound=lambda k, e, d: _wh(k, e, d, z=lambda d: 1 - d / 2)),
                 "(k - 1) / epsilon, without the factor 2: n = (k - 1) / (2 epsilon) (...)^3":
                     _kld_variant(*args, bound=lambda k, e, d: _wh(k, e, d, two=1.0)),
                 "the bins of all the particles from the start: k(n) counts the bins the first n occupy":
                     _kld_variant(*args, all_bins=True),
                 "n_min left out: the count is at least n_min": _kld_variant(*args, use_n_min=False)}
        what = _slip(mine, ref, slips, close=lambda a, b: a == b)
        problems.append(f"{name}: yours {mine}, the library's {ref}" + (f"; yours is {what}" if what else ""))
    right = "your KLD count is the library's (particles.kld_count) on all four cases"
    if notes:
        right += " up to a convention (" + "; ".join(sorted(notes)) + "), which is as right"
    return _verdict(problems, right,
                    "bins = np.floor(x / bin_size); k(n) = the distinct bins among the first n (np.unique(bins, "
                    "axis=0, return_index=True) gives each bin's first particle; cumsum); bound = (k-1)/(2 eps) (1 - a "
                    "+ sqrt(a) z)^3, a = 2/(9(k-1)), z = norm.ppf(1 - delta) (1 for k = 1); the first n >= n_min "
                    "with n >= bound")
