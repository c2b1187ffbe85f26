r"""Parameterisations of the library effects for fitting by simulation.

Each effect module of the device turns the hints of its evidence into an
:class:`ssamb.device.EffectModel` (:meth:`ssamb.device.Device.effect_model`): the fitted parameters
:math:`\theta` (scaled to order one by their finite-difference steps), the start point, bounds, the
effects the replay receives for a given :math:`\theta`, and the entries of ``closeloop.json``
(:meth:`ssamb.device.Device.report_entries`). This module combines and restarts them.

"""
from __future__ import annotations

import numpy as np

from ..device import EffectModel

__all__ = ["EffectModel", "restart", "combine", "basin_points"]


def restart(model: EffectModel, theta: np.ndarray) -> EffectModel:
    """The same parameterisation started at ``theta`` (to refit with other effects present)."""
    import dataclasses

    return dataclasses.replace(model, theta0=np.asarray(theta, float).copy())


def combine(models: list) -> EffectModel:
    """Several effects fitted jointly: parameters concatenated (one model is returned as is)."""
    if len(models) == 1:
        return models[0]
    sizes = [len(m.params) for m in models]
    cuts = np.cumsum([0] + sizes)

    def build(t):
        return [e for m, a, b in zip(models, cuts[:-1], cuts[1:]) for e in m.build(t[a:b])]
    return EffectModel("+".join(m.name for m in models), tuple(f"{m.name}.{p}" for m in models for p in m.params),
                       np.concatenate([m.theta0 for m in models]), np.concatenate([m.step for m in models]),
                       np.concatenate([m.lower for m in models]), np.concatenate([m.upper for m in models]),
                       build, {})


def basin_points(model: EffectModel, theta: np.ndarray) -> list:
    r"""Starts in other basins of an effect's cost than a fitted ``theta``: the points of the
    model's coarse grid (:attr:`ssamb.device.EffectModel.grid`), and each parameter at every value
    the grid gives it with the others at ``theta``, within the bounds; none closer to ``theta``
    than one finite-difference step in every parameter, none twice.

    The grid's own points pair the parameters as the evidence hinted (both delays together, one
    axis at its hint); a fit that ended with one parameter right and another in a wrong basin
    (a y delay right beside an x delay several samples off) is one coordinate away from the truth.
    Empty for a model without a grid (a fit from its evidence's hint has no other basin to try).
    """
    theta = np.clip(np.asarray(theta, float), model.lower, model.upper)
    grid = [np.clip(np.asarray(g, float), model.lower, model.upper) for g in model.grid]
    pts = list(grid)
    for j in range(len(theta)):
        for v in sorted({float(g[j]) for g in grid}):
            t = theta.copy()
            t[j] = v
            pts.append(t)
    out, seen = [], set()
    for t in pts:
        key = tuple(np.round(t / model.step, 6))
        if key in seen or np.all(np.abs(t - theta) <= model.step):
            continue
        seen.add(key)
        out.append(t)
    return out
