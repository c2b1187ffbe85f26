"""Independent replays on several processes.

A fit's design (the mirror pairs and centre runs of :func:`ssamb.closeloop.estimate.map_fit`)
and a prediction's replays (distinct seeds) are independent simulations. Two ways run them on
forked processes; every replay is seeded, so the results do not depend on either or on the
number of workers (tested):

* :func:`pmap` forks a pool per call: the function mapped may be any closure (the children
  inherit it by ``fork``). Each call pays the fork and the teardown of a pool, and fresh children
  copy the parent's pages they touch: for the close-the-loop analysis (a parent of several
  hundred MB, 150 batches) that was 10 s of the fork and the pool's teardown alone
  (``bench/closeloop_speed.py`` under ``cProfile``).
* :class:`Workers` forks once and serves data: the function is fixed when the workers are
  forked, a call's arguments are pickled, and an object the calls of a batch share (a
  residual's whitener and layout) is sent to each worker once (:meth:`Workers.map`'s
  ``shared``) and kept there under the hash of its pickle.

Where ``fork`` is not available (or ``workers <= 1``) both run in this process.
"""
from __future__ import annotations

import hashlib
import multiprocessing as mp
import os
import pickle
import signal
import traceback
from collections import deque
from multiprocessing.connection import wait
from typing import Callable, Iterable, Sequence

__all__ = ["pmap", "available", "Workers", "Shared"]

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


class Shared:
    """An object the calls of a batch share, pickled once and named by the hash of its pickle.

    Parameters
    ----------
    obj : object
        Any picklable object (it reaches each worker at most once while the worker keeps it).
    """

    def __init__(self, obj):
        self.obj = obj
        self.raw = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        self.key = hashlib.sha1(self.raw).hexdigest()


_KEEP = 4           # shared objects a worker keeps (least recently installed dropped first)


def _serve(conn, fn: Callable, inherited: Sequence = ()) -> None:
    """A worker's loop: ``("put", key, raw)`` installs a shared object, ``("call", i, key, args)``
    answers ``("ok", i, fn(shared, *args))`` or ``("err", i, exception, traceback)``; the end of
    the pipe ends the worker. ``inherited``: the parent's ends of this and the earlier workers'
    pipes, which fork copied here and which would keep those pipes from ever ending."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # the parent handles Ctrl-C and closes the pipes
    for c in inherited:
        c.close()
    store: dict = {}
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            break
        if msg[0] == "put":
            store[msg[1]] = pickle.loads(msg[2])
            while len(store) > _KEEP:
                store.pop(next(iter(store)))
            continue
        _, i, key, args = msg
        try:
            out = ("ok", i, fn(store[key] if key is not None else None, *args))
        except BaseException as exc:           # noqa: BLE001 -- handed to the parent, which raises it
            out = ("err", i, exc, traceback.format_exc())
        try:
            conn.send(out)
        except OSError:                        # the parent is gone (or closed the pool mid-batch)
            break
        except Exception as exc:               # noqa: BLE001 -- e.g. an exception that does not pickle
            tb = out[3] if out[0] == "err" else ""
            conn.send(("err", i, RuntimeError(f"worker could not return its result: {exc!r}"), tb))
    os._exit(0)


class Workers:
    """``workers`` processes forked once, each running ``fn(shared, *args)`` for the calls sent.

    Parameters
    ----------
    fn : callable
        The function the workers run (fixed at fork: a closure is fine; neither it nor what it
        references is pickled). Its first argument is the batch's shared object (or None).
    workers : int
        Processes (:meth:`map` runs in this process when fork is not available).

    Notes
    -----
    Calls go to whichever worker is idle (one call in flight per worker); the results come back
    in the order of the arguments. An exception in a worker is raised here, after the calls in
    flight have answered (the workers stay usable). A worker that dies (killed, out of memory)
    closes the pool with a ``RuntimeError``. The workers end with :meth:`close`, with the pipe's
    end when this process ends, and they ignore Ctrl-C (this process handles it).
    """

    def __init__(self, fn: Callable, workers: int):
        self._fn = fn if not available() else None
        self._procs, self._conns, self._have = [], [], []
        if not available():
            return
        ctx = mp.get_context("fork")
        for _ in range(max(int(workers), 1)):
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_serve, args=(child, fn, [parent, *self._conns]), daemon=True)
            p.start()
            child.close()
            self._procs.append(p)
            self._conns.append(parent)
            self._have.append([])

    @property
    def alive(self) -> bool:
        return bool(self._conns) or self._fn is not None

    def map(self, args: Iterable[Sequence], shared: Shared | None = None) -> list:
        """``[fn(shared.obj, *a) for a in args]`` on the workers.

        Parameters
        ----------
        args : iterable of tuples
            Picklable argument tuples, one per call.
        shared : Shared, optional
            The object every call of the batch receives first (sent to a worker only if it does
            not hold it yet).
        """
        args = [tuple(a) for a in args]
        if self._fn is not None:
            obj = shared.obj if shared is not None else None
            return [self._fn(obj, *a) for a in args]
        if not self._conns:
            raise RuntimeError("the workers are closed")
        key = shared.key if shared is not None else None
        todo, out, busy, error = deque(enumerate(args)), [None] * len(args), {}, None
        idle = list(range(len(self._conns)))
        while todo or busy:
            while todo and idle and error is None:
                w = idle.pop()
                i, a = todo.popleft()
                self._send(w, i, key, a, shared)
                busy[self._conns[w]] = w
            if not busy:
                break
            for conn in wait(list(busy)):
                w = busy.pop(conn)
                try:
                    msg = conn.recv()
                except (EOFError, OSError):
                    self.close()
                    raise RuntimeError("a replay worker died (killed, or out of memory)") from None
                if msg[0] == "err" and error is None:
                    error = msg
                elif msg[0] == "ok":
                    out[msg[1]] = msg[2]
                idle.append(w)
        if error is not None:
            exc = error[2]
            if isinstance(exc, BaseException):
                raise exc.with_traceback(None) from RuntimeError(f"in a replay worker:\n{error[3]}")
            raise RuntimeError(f"in a replay worker:\n{error[3]}")
        return out

    def _send(self, w: int, i: int, key, a: tuple, shared: Shared | None) -> None:
        conn, have = self._conns[w], self._have[w]
        if key is not None and key not in have:
            conn.send(("put", key, shared.raw))
            have.append(key)
            del have[:-_KEEP]
        conn.send(("call", i, key, a))

    def close(self) -> None:
        """End the workers (idempotent)."""
        for conn in self._conns:
            conn.close()
        for p in self._procs:
            p.join(timeout=5)
            if p.is_alive():
                p.kill()
                p.join()
        self._procs, self._conns, self._have = [], [], []
