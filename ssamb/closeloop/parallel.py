"""Independent replays on several processes.

A fit's design (the mirror pairs and centre runs of :func:`ssamb.closeloop.estimate.map_fit`)
and a prediction's replays (distinct seeds) are independent simulations: :func:`pmap` runs them
on ``workers`` forked processes. The children inherit the parent's state (the compiled
simulator, the record, the whiteners) through ``fork``, so the function mapped may be any
closure; only its arguments' indices and its results cross the process boundary. Every replay
is seeded, so the results do not depend on the number of workers (tested).

Where ``fork`` is not available (or ``workers <= 1``) the map runs in this process.
"""
from __future__ import annotations

import multiprocessing as mp
from typing import Callable, Iterable, Sequence

__all__ = ["pmap", "available"]

_JOB: tuple | None = None


def available() -> bool:
    """Whether forked workers can run here."""
    return "fork" in mp.get_all_start_methods()


def _call(i: int):
    fn, args = _JOB
    return fn(*args[i])


def pmap(fn: Callable, args: Iterable[Sequence], workers: int = 1) -> list:
    """``[fn(*a) for a in args]``, on up to ``workers`` forked processes.

    Parameters
    ----------
    fn : callable
        Any callable (a closure is fine: the children inherit it by ``fork``).
    args : iterable of tuples
        Argument tuples, one per call.
    workers : int
        Processes (1: in this process).

    Returns
    -------
    list
        The results in the order of ``args``. An exception in a child is raised here.
    """
    global _JOB
    args = [tuple(a) for a in args]
    if workers <= 1 or len(args) < 2 or not available():
        return [fn(*a) for a in args]
    _JOB = (fn, args)
    try:
        with mp.get_context("fork").Pool(min(int(workers), len(args))) as pool:
            return pool.map(_call, range(len(args)), chunksize=1)
    finally:
        _JOB = None
