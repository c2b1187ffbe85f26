"""The workflow stages: file in, file out, nothing else.

One module per Snakemake rule family; each ``run_*`` function reads its input files, calls the
numerics of the core modules and writes its output files (atomically). Whatever a rule does, a
user can do from Python with the same function. Only the workflow scripts and the CLI import
these modules; the core modules never do.

=============== ============================== ==========================================
module          rule                           numerics
=============== ============================== ==========================================
simulate        ``simulate`` (per experiment)   :mod:`ssamb.sim`
identify        ``identify`` (per subsystem)    :mod:`ssamb.identification`
select          ``select`` (paper's way)        :mod:`ssamb.identification.joint`
assemble        ``assemble``                    :mod:`ssamb.closed_loop`
uncertainty     ``uncertainty`` (per subsystem) :mod:`ssamb.uncertainty`
mu              ``mu`` (per case)               :mod:`ssamb.generalized_plant`, :mod:`ssamb.robustness`
baseline        ``baseline``                    :mod:`ssamb.robustness`
validate        ``validate``                    :mod:`ssamb.validation`
summary         ``summary``                     (collects the stage outputs)
=============== ============================== ==========================================
"""
from __future__ import annotations

import sys
import traceback
from typing import Any, Callable, Iterable

import numpy as np

from ..model_io import Failed, write_failed

__all__ = ["NUMERICAL_FAILURES", "run_guarded"]

#: what a stage may fail with on legitimate data (numerics, physics, an upstream failure) --
#: programming errors (TypeError, KeyError, AttributeError, ...) are never caught
NUMERICAL_FAILURES = (ValueError, RuntimeError, ArithmeticError, np.linalg.LinAlgError, Failed)


def run_guarded(stage: str, outputs: Iterable[str], fn: Callable, *args, tolerate: bool = False, **kwargs) -> Any:
    """Run a stage; with ``tolerate`` (the scenario and study runs), a numerical failure writes a
    failure marker in place of every output (:func:`ssamb.model_io.write_failed`) so that the
    downstream stages and the study report it as failed; without, it is raised."""
    try:
        return fn(*args, **kwargs)
    except NUMERICAL_FAILURES as exc:
        if not tolerate:
            raise
        traceback.print_exc(file=sys.stderr)
        reason = " ".join(f"{type(exc).__name__}: {exc}".split())
        for path in outputs:
            write_failed(path, reason, stage)
        return None
