"""ssamb: reproducible mu-analysis of a self-sensing active magnetic bearing.

Replication and extension of "mu-analysis applied to self-sensing active magnetic bearings"
(see ``README.md``). The library does the work; the Snakemake workflow only calls it.

Importing ssamb changes nothing in the process. The entry points (``python -m ssamb``, the
workflow's scripts, the benchmarks, the test session) call :func:`pin_blas_threads` first, so
that every one of them computes the same bits; a program that imports ssamb may do the same.
"""
from ._threads import pin_blas_threads

__version__ = "0.1.0"

#: Coil order used everywhere (the measured-data format): the electromagnet on the +y side first.
COILS = ("ypos", "yneg", "xpos", "xneg")

__all__ = ["COILS", "pin_blas_threads", "__version__"]
