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

scipy's LAPACK wrappers are imported at the first solve that needs them
(:func:`lapack`), not with this module: a command that never fuses (``dkfsim
list``, ``validate``) does not pay scipy.linalg's import (docs/decisions.md, "Start-up").
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np


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


_SYSV_LWORK: dict[int, int] = {}
#: The LAPACK routines of the solves below, bound by :func:`lapack` on first use.
_LAPACK = SimpleNamespace(sysv=None, sysv_lwork=None, potrf=None, potrs=None)


def lapack() -> SimpleNamespace:
    """scipy's LAPACK routines these solves call (``dsysv``, ``dpotrf``, ``dpotrs``), imported
    on the first call."""
    if _LAPACK.sysv is None:
        import scipy.linalg.lapack as lp
        _LAPACK.sysv_lwork, _LAPACK.potrf, _LAPACK.potrs = lp.dsysv_lwork, lp.dpotrf, lp.dpotrs
        _LAPACK.sysv = lp.dsysv
    return _LAPACK


def solve_symmetric(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^-1 B`` for one symmetric (indefinite) ``A`` (LAPACK ``dsysv``); NaN if it fails.

    LAPACK is called directly (what ``scipy.linalg.solve(assume_a="sym")`` does
    minus its checks and condition estimate, which cost more than the solve at
    fusion sizes).  ``A`` and ``B`` are not modified.
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    n = A.shape[0]
    lp = _LAPACK if _LAPACK.sysv is not None else lapack()
    lwork = _SYSV_LWORK.get(n)
    if lwork is None:
        lwork = _SYSV_LWORK[n] = int(lp.sysv_lwork(n)[0])
    one = B.ndim == 1
    _, _, x, info = lp.sysv(A, B[:, None] if one else B, lwork=lwork)
    if info != 0:
        return np.full(np.shape(B), np.nan)
    return x[:, 0] if one else x


def solve_posdef(A: np.ndarray, B: np.ndarray, overwrite_a: bool = False) -> np.ndarray | None:
    """``A^-1 B`` for one symmetric positive definite ``A`` by Cholesky (LAPACK ``dpotrf``,
    ``dpotrs``, lower triangle); None when ``A`` is not numerically positive definite.

    ``B`` is not modified; ``A`` only with ``overwrite_a`` (a Fortran-ordered or symmetric
    C-ordered scratch the caller no longer needs).
    """
    lp = _LAPACK if _LAPACK.potrf is not None else lapack()
    c, info = lp.potrf(A, lower=1, clean=0, overwrite_a=overwrite_a)
    if info != 0:
        return None
    x, info = lp.potrs(c, B, lower=1)
    if info != 0:
        return None
    return x
