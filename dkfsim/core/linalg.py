"""Linear solves that never raise: a diverging run finishes and says so.

A filter whose estimates blow up (an unstable ``Phi``, a prior of 1e100,
overflow to ``inf``) feeds non-finite numbers into its solves, and LAPACK
then reports a singular matrix.  dkfsim does not stop a run for that: the
slices that cannot be solved become NaN, the run goes on, and the result
reports which estimates diverged (``RunResult.diverged``).  For finite,
well-posed input these are exactly ``numpy.linalg.solve`` and
``scipy.linalg.solve``: the fallback runs only after they raised.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg


def solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Batched ``A^-1 B`` (``B`` has matrix slices); slices that fail are NaN."""
    try:
        return np.linalg.solve(A, B)
    except np.linalg.LinAlgError:
        pass
    A, B = np.asarray(A, float), np.asarray(B, float)
    batch = np.broadcast_shapes(A.shape[:-2], B.shape[:-2])
    A = np.broadcast_to(A, batch + A.shape[-2:])
    B = np.broadcast_to(B, batch + B.shape[-2:])
    out = np.full(batch + B.shape[-2:], np.nan)
    for idx in np.ndindex(*batch):
        try:
            out[idx] = np.linalg.solve(A[idx], B[idx])
        except np.linalg.LinAlgError:
            pass
    return out


def solve_symmetric(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^-1 B`` for one symmetric (indefinite) ``A`` (LAPACK ``sysv``); NaN if it fails."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        try:
            return scipy.linalg.solve(A, B, assume_a="sym", check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return np.full(np.shape(B), np.nan)
