"""BLAS threads pinned, so that every entry point gives the same bits.

Multi-threaded BLAS splits matrix products and factorisations into blocks whose partial sums
are added in an order that depends on the thread count, so results differ in the last bits
(about 1e-10 relative once the SIPPY identification amplifies them) between a process with 2
threads and one with 1. The command line, the Snakemake scripts (:func:`ssamb.stages.job_log`),
the benchmarks and the test session call :func:`pin_blas_threads` before any work: every BLAS
loaded (NumPy and SciPy each bundle their own OpenBLAS; both are loaded here first) runs with
:data:`BLAS_THREADS` threads. Importing :mod:`ssamb` does not: a process-wide setting is the
calling program's choice. One thread is also the fastest setting for this project's small
matrices (``bench/mu_speed.py``, ``bench/ident_speed.py``); parallelism comes from Snakemake
running jobs side by side.
"""
from __future__ import annotations

__all__ = ["BLAS_THREADS", "pin_blas_threads"]

#: threads every BLAS library in the process may use
BLAS_THREADS = 1


def pin_blas_threads() -> None:
    """Limit every loaded BLAS (NumPy's and SciPy's OpenBLAS, MKL, ...) to :data:`BLAS_THREADS`.

    For the whole process, from the call on; NumPy and SciPy are imported first so that their
    BLAS libraries are among those limited.

    Examples
    --------
    >>> import ssamb
    >>> ssamb.pin_blas_threads()   # before any numerical work in a program of your own
    """
    import numpy  # noqa: F401  (loads NumPy's BLAS)
    import scipy.linalg  # noqa: F401  (loads SciPy's BLAS, a separate library in the wheels)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=BLAS_THREADS, user_api="blas")
