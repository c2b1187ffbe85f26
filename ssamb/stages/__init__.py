"""The workflow stages: file in, file out, nothing else.

One module per Snakemake rule family; each ``run_*`` function reads its input files, calls the
numerics of the core modules and writes its output files (atomically). Whatever a rule does, a
user can do from Python with the same function. Only the workflow scripts and the CLI import
these modules; the core modules never do.

=============== ================================ ============================================================
module          rule                             numerics
=============== ================================ ============================================================
simulate        ``simulate`` (per experiment)    :mod:`ssamb.sim`
identify        ``identify`` (per subsystem)     :mod:`ssamb.identification`
select          ``select`` (paper's way)         :mod:`ssamb.identification.joint`
assemble        ``assemble``                     :mod:`ssamb.closed_loop`
uncertainty     ``uncertainty`` (per subsystem)  :mod:`ssamb.uncertainty`
mu              ``mu`` (per case)                :mod:`ssamb.generalized_plant`, :mod:`ssamb.robustness`
baseline        ``baseline``                     :mod:`ssamb.robustness`
validate        ``validate``                     :mod:`ssamb.validation`
summary         ``summary``                      (collects the stage outputs)
=============== ================================ ============================================================
"""
from __future__ import annotations

import sys
import traceback
from contextlib import contextmanager
from typing import Any, Callable, Iterable

import numpy as np

from ..model_io import Failed, write_failed

__all__ = ["NUMERICAL_FAILURES", "run_guarded", "job_log", "check_closeloop_settings"]

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


@contextmanager
def job_log(path: str, stage: str):
    """Send a workflow job's stdout and stderr to its log file, and its failure too.

    A Snakemake script runs its job inside ``with job_log(snakemake.log[0], "stage"):``. The
    failure is written into the log *before* the log is closed and the console's streams are
    restored (an exception that leaves a plain ``with open(log)`` block finds ``sys.stderr``
    closed, and its message is lost with it):

    * bad input (:class:`ssamb.errors.InputError`): the command line's one line,
      ``ssamb <stage>: error: <message>``, in the log and on the console; the job exits with
      status 2 (Snakemake reports the job as failed and names the log);
    * anything else: the traceback in the log, then the exception goes on (the console shows
      it too, the job exits with status 1).

    Parameters
    ----------
    path : str
        The job's log file (``snakemake.log[0]``), created or truncated.
    stage : str
        The stage's name, the first word of the one-line message.

    Notes
    -----
    The job is an entry point: BLAS is pinned to one thread first
    (:func:`ssamb.pin_blas_threads`), for the same bits in every job.
    """
    from .._threads import pin_blas_threads
    from ..errors import InputError

    pin_blas_threads()

    saved = sys.stdout, sys.stderr
    with open(path, "w", encoding="utf-8", buffering=1) as log:
        sys.stdout = sys.stderr = log
        try:
            yield log
        except InputError as exc:
            line = f"ssamb {stage}: error: {' '.join(str(exc).split())}\n"
            log.write(line)
            sys.stdout, sys.stderr = saved
            sys.stderr.write(line)
            raise SystemExit(2) from None
        except BaseException as exc:
            if not isinstance(exc, SystemExit):
                traceback.print_exc(file=log)
            raise
        finally:
            sys.stdout, sys.stderr = saved


def check_closeloop_settings(cfg, device="amb", source: str | None = None) -> None:
    """Check a config's ``closeloop`` section as an analysis reads it (its settings and the
    calibrated parameters' keys); raise :class:`ssamb.config.ConfigError` naming the key, and
    ``source`` (the config file) when given. The command line and the workflow call it while
    they read the config, before any analysis."""
    from ..closeloop.calibration import parameter_specs
    from ..closeloop.settings import settings_from_config
    from ..config import ConfigError
    from ..device import get_device

    try:
        parameter_specs(cfg, settings_from_config(cfg, get_device(device)).calibration or {})
    except ConfigError as exc:
        if source is None:
            raise
        raise ConfigError(f"{source}: {exc}") from None
