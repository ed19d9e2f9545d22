"""Equal numbers, as far as the CPU lets them be (tests of the particle filter's backends and stored runs).

Integer work, IEEE sums and products in a fixed order are exact on any CPU; ``exp`` and ``log`` are
not (numpy's AVX-512 code, the C library's FMA variant). So the particle filter's backends, and a stored
evaluation rerun, are asserted equal bit for bit where :func:`adaptfilt.particle_kernels.exp_log_agree`
says this CPU's numpy and the kernels' C library agree, and to :data:`~adaptfilt.particle_kernels.TOLERANCE`
(relative, on the scale of the array) everywhere else. `.ci/run` reruns the tests marked ``crosscpu`` with
numpy's SIMD dispatch switched off, so that both branches run in CI.
"""
from __future__ import annotations

import functools

import numpy as np

from adaptfilt import particle_kernels


@functools.lru_cache(maxsize=1)
def bit_for_bit() -> bool:
    return particle_kernels.exp_log_agree()


def assert_same_numbers(got, want, err_msg: str = "", exact: bool | None = None,
                        diverged_above: float | None = None) -> None:
    """``got == want`` bit for bit where this CPU allows it (``exact=None``: :func:`bit_for_bit`), else to
    the stated relative tolerance. ``exact=False`` for numbers another CPU made (stored ``data/``): whether
    that CPU's C library took the same ``exp`` variant as this one's is not recorded.

    ``diverged_above``: values above it (or not finite) are one class, "diverged", compared as such. An
    (A)NEES of a numerically singular covariance (a particle cloud collapsed onto fewer points than state
    dimensions) is 1e15-1e17 or infinite depending on the rounding of a Cholesky factorisation, which
    differs between BLAS kernels (OpenBLAS on another CPU): its value is not a reproducible number, its
    class is."""
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    if diverged_above is not None:
        gone = ~(want <= diverged_above)
        np.testing.assert_array_equal(~(got <= diverged_above), gone, err_msg=f"{err_msg}: diverged steps")
        got, want = got[~gone], want[~gone]
    if bit_for_bit() if exact is None else exact:
        np.testing.assert_array_equal(got, want, err_msg=err_msg)
        return
    finite = np.isfinite(want)
    np.testing.assert_array_equal(finite, np.isfinite(got), err_msg=err_msg)  # an inf stays an inf
    np.testing.assert_array_equal(got[~finite], want[~finite], err_msg=err_msg)
    scale = float(np.abs(want[finite]).max()) if finite.any() else 0.0
    np.testing.assert_allclose(got[finite], want[finite], rtol=particle_kernels.TOLERANCE,
                               atol=particle_kernels.TOLERANCE * scale, err_msg=err_msg)
