"""BLAS threads, pinned once for the whole library so that every entry point gives the same bits.

Multi-threaded BLAS splits matrix products and factorisations into blocks whose partial sums
are added in an order that depends on the thread count, so results differ in the last bits
(1e-10 relative after the SIPPY identification amplifies them) between a process with 2
threads and one with 1. The command line, the Snakemake scripts, the notebooks and the tests
all import :mod:`ssamb`, which calls :func:`pin_blas_threads` once: every BLAS already loaded
(NumPy and SciPy each bundle their own OpenBLAS; both are loaded here first) runs with
:data:`BLAS_THREADS` threads. One thread is also the fastest setting for this project's small
matrices (measured in ``bench/mu_speed.py`` and ``bench/ident_speed.py``), and parallelism
comes from Snakemake running jobs side by side.
"""
from __future__ import annotations

__all__ = ["BLAS_THREADS", "pin_blas_threads"]

#: threads every BLAS library in the process may use
BLAS_THREADS = 1


def pin_blas_threads() -> None:
    """Limit every loaded BLAS (NumPy's and SciPy's OpenBLAS, MKL, ...) to :data:`BLAS_THREADS`."""
    import numpy  # noqa: F401  (loads NumPy's BLAS)
    import scipy.linalg  # noqa: F401  (loads SciPy's BLAS, a separate library in the wheels)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=BLAS_THREADS, user_api="blas")
