"""One BLAS thread per process: parallelism comes from processes, never from BLAS.

dkfsim's arithmetic is many tiny matrices (3 x 3 filters, a few hundred
squared for fusion).  A multi-threaded BLAS gains nothing on them and, on a
loaded machine, loses a lot: its threads spin and wait for cores that
other processes hold (measured: a 1 x 1 triangular solve taking 30 ms).  So:

* the ``dkfsim`` command and every worker process it starts call
  :func:`pin_process` first: the thread variables of OpenBLAS, MKL, BLIS,
  OpenMP and Accelerate are set to 1 (inherited by any process started
  later, Dask workers included) and the libraries already loaded are
  limited at run time with threadpoolctl;
* the Python API (``dkfsim.run``, ``montecarlo``, ``sweep``, ``maxdelay``)
  limits threads only for the duration of the call (:func:`single_thread`),
  leaving the caller's notebook as it was.
"""

from __future__ import annotations

import functools
import os

from threadpoolctl import threadpool_limits

#: Environment variables that set the thread count of the common BLAS / OpenMP runtimes.
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                    "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def pin_process() -> None:
    """Limit this process, and every process it starts, to one BLAS thread."""
    for name in THREAD_VARIABLES:
        os.environ[name] = "1"
    threadpool_limits(1)


def single_thread(fn):
    """Decorator: run ``fn`` with one BLAS thread, restoring the caller's setting after."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with threadpool_limits(1):
            return fn(*args, **kwargs)
    return wrapper


def call_single_threaded(fn, *args):
    """``fn(*args)`` with one BLAS thread (a Dask task: the worker may be anyone's)."""
    with threadpool_limits(1):
        return fn(*args)
