"""Compiled kernel of the harmonic references (:mod:`sqpmpc.problem.references`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["harmonic_positions"]



@numba.njit(cache=True, nogil=True)
def harmonic_positions(coeffs: np.ndarray, times: np.ndarray, out: np.ndarray) -> None:
    """Harmonic references ``coeffs (m, 7)`` (omega, c, s, k of x and y) at ``times (T,)``.

    The same arithmetic as :meth:`HarmonicReference.position`:
    ``c + s sin(omega t) + k cos(omega t)``.
    """
    for r in range(coeffs.shape[0]):
        w = coeffs[r, 0]
        for i in range(times.shape[0]):
            wt = w * times[i]
            sn, cs = np.sin(wt), np.cos(wt)
            out[r, i, 0] = coeffs[r, 1] + coeffs[r, 2] * sn + coeffs[r, 3] * cs
            out[r, i, 1] = coeffs[r, 4] + coeffs[r, 5] * sn + coeffs[r, 6] * cs
