"""Replay: drive the nonlinear model with the excitation recorded in the data.

The model is :func:`ssamb.sim.simulate` with explicit ``arrays`` (the recorded references and
injections), the start state the data's ``meta`` names (default: levitated, from the static
equilibrium, after the config's pre-roll) and any effects of the library. The simulator is
deterministic, so a replay of data made by the nominal model reproduces it exactly apart from
the logging noise.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np

from .data import CHANNELS, Record

__all__ = ["Replayer"]


@dataclass
class Replayer:
    """Simulate the model on (a prefix of) a record, with effects; results are memoised.

    Attributes
    ----------
    cfg : dict
        Validated configuration of the nominal model.
    record : Record
    n_sims, wall_s : int, float
        Simulations run and their wall time (for the report).
    cache_size : int
        Results kept (least recently used dropped first).
    """

    cfg: Mapping
    record: Record
    n_sims: int = 0
    wall_s: float = 0.0
    cache_size: int = 8
    _cache: dict = field(default_factory=dict, repr=False)

    def run(self, effects: Iterable[Mapping] = (), n: int | None = None) -> dict:
        """Model channels (:data:`CHANNELS`) for the first ``n`` samples (default: all).

        Parameters
        ----------
        effects : iterable of mappings
            Library effects added to the nominal model (``{name, **params}``).
        n : int, optional
            Simulate only the first ``n`` samples (the fitting part needs no more).
        """
        from ..sim import simulate

        effects = [dict(e) for e in effects]
        n = self.record.n if n is None else int(n)
        key = (json.dumps(effects, sort_keys=True, default=float), n)
        if key in self._cache:
            out = self._cache.pop(key)          # most recently used last
            self._cache[key] = out
            return out
        arrays = {k: v[:n] for k, v in self.record.inputs.items()}
        t0 = time.perf_counter()
        res = simulate(self.cfg, arrays=arrays, effects=effects, start=self.record.start,
                       settle_s=self.record.settle_s, progress=False)
        self.wall_s += time.perf_counter() - t0
        self.n_sims += 1
        out = {c: np.asarray(res.data[c], float) for c in CHANNELS}
        out["delevitated"] = res.meta.get("delevitation_s") is not None
        self._cache[key] = out
        while len(self._cache) > self.cache_size:
            self._cache.pop(next(iter(self._cache)))
        return out
