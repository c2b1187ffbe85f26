"""ssamb: reproducible mu-analysis of a self-sensing active magnetic bearing.

Replication and extension of "mu-analysis applied to self-sensing active magnetic bearings"
(see ``README.md``). The library does the work; the Snakemake workflow only calls it.
"""
__version__ = "0.1.0"

#: Coil order used everywhere (ARCHITECTURE.md): the electromagnet on the +y side first.
COILS = ("ypos", "yneg", "xpos", "xneg")

from ._threads import pin_blas_threads as _pin_blas_threads

_pin_blas_threads()   # one thread per BLAS, for bit-identical numbers everywhere (see ssamb._threads)
