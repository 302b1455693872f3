"""Linear solves that never raise: a diverging run finishes and says so.

A filter whose estimates blow up (an unstable ``Phi``, a prior of 1e100,
overflow to ``inf``) feeds non-finite numbers into its solves, and LAPACK
then reports a singular matrix.  dkfsim does not stop a run for that: the
slices that cannot be solved become NaN, the run goes on, and the result
reports which estimates diverged (``RunResult.diverged``).  For finite,
well-posed input these are exactly ``numpy.linalg.solve`` and
LAPACK ``dsysv``: the fallback runs only after they raised.
:func:`solve_posdef` instead reports failure (a matrix that is not positive
definite) to its caller, which picks another method.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.linalg.lapack


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


_SYSV = scipy.linalg.lapack.dsysv
_SYSV_LWORK: dict[int, int] = {}


def solve_symmetric(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^-1 B`` for one symmetric (indefinite) ``A`` (LAPACK ``dsysv``); NaN if it fails.

    LAPACK is called directly (what ``scipy.linalg.solve(assume_a="sym")`` does
    minus its checks and condition estimate, which cost more than the solve at
    fusion sizes).  ``A`` and ``B`` are not modified.
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    n = A.shape[0]
    lwork = _SYSV_LWORK.get(n)
    if lwork is None:
        lwork = _SYSV_LWORK[n] = int(scipy.linalg.lapack.dsysv_lwork(n)[0])
    one = B.ndim == 1
    _, _, x, info = _SYSV(A, B[:, None] if one else B, lwork=lwork)
    if info != 0:
        return np.full(np.shape(B), np.nan)
    return x[:, 0] if one else x


_POTRF = scipy.linalg.lapack.dpotrf
_POTRS = scipy.linalg.lapack.dpotrs


def solve_posdef(A: np.ndarray, B: np.ndarray, overwrite_a: bool = False) -> np.ndarray | None:
    """``A^-1 B`` for one symmetric positive definite ``A`` by Cholesky (LAPACK ``dpotrf``,
    ``dpotrs``, lower triangle); None when ``A`` is not numerically positive definite.

    ``B`` is not modified; ``A`` only with ``overwrite_a`` (a Fortran-ordered or symmetric
    C-ordered scratch the caller no longer needs).
    """
    c, info = _POTRF(A, lower=1, clean=0, overwrite_a=overwrite_a)
    if info != 0:
        return None
    x, info = _POTRS(c, B, lower=1)
    if info != 0:
        return None
    return x
