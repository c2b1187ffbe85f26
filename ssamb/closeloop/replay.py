"""Replay: drive the model with the excitation recorded in the data -- the engine's one contact
with the device.

The statistics of close the loop (features, estimation, signatures, search) see the model only
through :meth:`Replayer.mean`: *given parameter overrides (dotted config keys), library effects
and a set of seeds, return the logged channels*. The device does the replay
(:meth:`ssamb.device.Device.replay`): the model driven by what the record says drove the rig,
from the start state it names, with the data's logging chain. A replay is one realisation of the
loop's noise, seeded; :meth:`Replayer.mean` averages several (the model's *expected* response,
with its noise reduced by the number of seeds).
"""
from __future__ import annotations

import functools
import json
import time
import weakref
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np

from ..device import Record

__all__ = ["Replayer"]


@dataclass
class Replayer:
    """Simulate the model on (a prefix of) a record; results are memoised.

    Attributes
    ----------
    cfg : dict
        Validated configuration of the nominal model.
    record : Record
    n_sims, wall_s : int, float
        Simulations run and their wall time (for the log).
    cache_size : int
        Results kept (least recently used dropped first).
    workers : int
        Processes that run independent replays (:meth:`map`, :meth:`runs`); the results do not
        depend on it (every replay is seeded).
    """

    cfg: Mapping
    record: Record
    n_sims: int = 0
    wall_s: float = 0.0
    cache_size: int = 32
    workers: int = 1
    _cache: dict = field(default_factory=dict, repr=False)
    _cfgs: dict = field(default_factory=dict, repr=False)
    _pool: tuple | None = field(default=None, repr=False)
    _finalizer: object = field(default=None, repr=False)

    def map_runs(self, tasks, post=None) -> list:
        """:meth:`run` (uncached) for each ``(effects, n, overrides, seed)`` of ``tasks``, on
        :attr:`workers` processes, with ``post`` (a picklable callable, e.g. a residual of the
        channels) applied to each result where it was simulated; the simulations the workers run
        are counted here.

        The workers (:class:`ssamb.closeloop.parallel.Workers`) are forked at the first call
        and kept until :meth:`close` (or a new record): a batch costs its replays, not a fork.
        """
        tasks = [tuple(t) for t in tasks]
        from .parallel import Shared, available

        if self.workers <= 1 or len(tasks) < 2 or not available():
            return [_replay(self, post, *t)[0] for t in tasks]

        res = self._workers().map(tasks, Shared(post) if post is not None else None)
        self.n_sims += sum(r[1] for r in res)
        self.wall_s += sum(r[2] for r in res)
        return [r[0] for r in res]

    def _workers(self):
        from .parallel import Workers

        ident = (id(self.record), id(self.cfg))
        if self._pool is None or self._pool[0] != ident or not self._pool[1].alive:
            self.close()
            # the simulator compiled (or loaded from numba's cache) here, once, before the fork:
            # the workers inherit the machine code instead of each compiling it (tens of seconds
            # on an empty cache); the bits are the same either way (tests/test_sim_bits.py)
            n0, w0 = self.n_sims, self.wall_s
            self.run((), min(int(self.record.n), 64), None, 0, cache=False)
            self.n_sims, self.wall_s = n0, w0
            pool = Workers(functools.partial(_replay, self), self.workers)
            self._pool = (ident, pool)
            self._finalizer = weakref.finalize(self, pool.close)
        return self._pool[1]

    def close(self) -> None:
        """End the worker processes (if any; a later :meth:`map_runs` forks new ones)."""
        if self._pool is not None:
            self._finalizer()
            self._pool = None

    @staticmethod
    def _key(effects, n, ov, seed) -> str:
        return json.dumps([effects, n, ov, seed], sort_keys=True, default=float)

    def _store(self, key: str, out: dict) -> None:
        self._cache[key] = out
        while len(self._cache) > self.cache_size:
            self._cache.pop(next(iter(self._cache)))

    def runs(self, effects: Iterable[Mapping] = (), n: int | None = None, overrides: Mapping | None = None,
             seeds: Iterable[int] = (None,)) -> list:
        """:meth:`run` for each of ``seeds`` (those not cached on :attr:`workers` processes)."""
        effects = [dict(e) for e in effects]
        nn = self.record.n if n is None else int(n)
        ov = {k: float(v) for k, v in sorted((overrides or {}).items())}
        seeds = list(seeds)
        todo = [s for s in dict.fromkeys(seeds) if self._key(effects, nn, ov, s) not in self._cache]
        if len(todo) > 1 and self.workers > 1:
            for s, out in zip(todo, self.map_runs([(effects, n, overrides, s) for s in todo])):
                self._store(self._key(effects, nn, ov, s), out)
        return [self.run(effects, n, overrides, s) for s in seeds]

    def run(self, effects: Iterable[Mapping] = (), n: int | None = None, overrides: Mapping | None = None,
            seed: int | None = None, cache: bool = True) -> dict:
        """Model channels (the device's) for the first ``n`` samples (default: all).

        Parameters
        ----------
        effects : iterable of mappings
            Library effects added to the model (``{name, **params}``).
        n : int, optional
            Simulate only the first ``n`` samples.
        overrides : mapping, optional
            Dotted config keys and values (calibrated parameters).
        seed : int, optional
            Seed of the converter noise (default: the config's).
        cache : bool
            Keep the result (an estimator's design runs are never asked for twice).
        """
        from ..config import overridden

        effects = [dict(e) for e in effects]
        n = self.record.n if n is None else int(n)
        ov = {k: float(v) for k, v in sorted((overrides or {}).items())}
        key = self._key(effects, n, ov, seed)
        if key in self._cache:
            out = self._cache.pop(key)          # most recently used last
            self._cache[key] = out
            return out
        cfg = self.cfg
        if ov:                    # one configuration per parameter set, shared by its seeds (never written)
            ck = json.dumps(ov, sort_keys=True)
            cfg = self._cfgs.pop(ck, None) or overridden(self.cfg, ov)
            self._cfgs[ck] = cfg
            while len(self._cfgs) > 8:
                self._cfgs.pop(next(iter(self._cfgs)))
        t0 = time.perf_counter()
        rep = self.record.device.replay(cfg, self.record, effects, n, seed)
        self.wall_s += time.perf_counter() - t0
        self.n_sims += 1
        out = {c: np.asarray(rep.channels[c], float) for c in self.record.device.channels}
        out["delevitated"] = bool(rep.contact)
        if cache:
            self._store(key, out)
        return out

    def mean(self, effects: Iterable[Mapping] = (), n: int | None = None, overrides: Mapping | None = None,
             seeds: Iterable[int] = (None,)) -> dict:
        """The channels averaged over replays with ``seeds`` (``delevitated`` if any replay did).

        Averaging keeps the response the excitation determines and divides the variance of the
        model's own noise by the number of seeds.
        """
        runs = self.runs(effects, n, overrides, seeds)
        out = {c: np.mean([r[c] for r in runs], axis=0) if len(runs) > 1 else runs[0][c]
               for c in self.record.device.channels}
        out["delevitated"] = any(r["delevitated"] for r in runs)
        return out


def _replay(replayer: Replayer, post, effects, n, overrides, seed) -> tuple:
    """One uncached replay, ``post`` applied: ``(result, simulations, their wall time)`` (a
    worker's counters reach the parent this way)."""
    n0, w0 = replayer.n_sims, replayer.wall_s
    out = replayer.run(effects, n, overrides, seed, cache=False)
    return (post(out) if post is not None else out), replayer.n_sims - n0, replayer.wall_s - w0
