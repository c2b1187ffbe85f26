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

__all__ = ["EffectModel", "restart", "combine"]


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
