r"""Parameterisations of the library effects for fitting by simulation.

:func:`effect_model` turns an effect name and the hints of its evidence into an
:class:`EffectModel`: the fitted parameters :math:`\theta` (scaled to order one by their
finite-difference steps), the start point, bounds, the effects the simulator receives for a
given :math:`\theta`, and the entries of ``closeloop.json``.

Parameterisations (chosen so that the model output is close to linear in :math:`\theta`):

* ``sensor_delay``: :math:`(\tau_x, \tau_y)` for the axes with evidence, :math:`\tau \ge 0`;
* ``sensor_gain``: :math:`(g_x - 1, g_y - 1)`;
* ``static_load``: :math:`(F_x, F_y)` for the axes with evidence;
* ``unbalance``: :math:`(a, b) = m e\,(\cos\varphi, \sin\varphi)`, so that the force
  :math:`m e \omega^2 \cos(\omega t + \varphi)` is linear in them, and the spin speed, started
  at the frequency of the line (its sensitivity is zero until the force is nonzero, so it joins
  the fit after the first step);
* ``amplifier_deadtime``: :math:`t_d \ge 0`;
* ``cross_coupling``: the coefficient :math:`c`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["EffectModel", "effect_model", "restart", "combine", "report_entries"]


@dataclass(frozen=True)
class EffectModel:
    """A library effect with free parameters.

    Attributes
    ----------
    name : str
    params : tuple of str
        Names of the fitted parameters (SI units in the names).
    theta0, step, lower, upper : numpy.ndarray
        Start point, finite-difference step (also the natural scale), bounds.
    build : callable
        ``theta -> list of effect specs`` for :func:`ssamb.sim.simulate`.
    fixed : dict
        What the parameterisation holds fixed (the axes of a sensor effect).
    grid : tuple of numpy.ndarray
        Coarse start points to try before the fit (:func:`ssamb.closeloop.fit.fit_candidate`)
        for an effect whose signature gives no size: its response is far from linear over
        its range (a dead time of 1.5 us moves the currents by orders of magnitude more than
        its finite-difference step), so a local fit from zero may not reach it.
    """

    name: str
    params: tuple
    theta0: np.ndarray
    step: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    build: Callable
    fixed: dict
    grid: tuple = ()


def effect_model(name: str, hints: dict, excited_axes: tuple) -> EffectModel:
    """The parameterisation of ``name`` given its evidence hints (see module docstring)."""
    axes = tuple(a for a in (hints.get("axes") or excited_axes) if a in ("x", "y")) or excited_axes or ("x", "y")
    if name in ("sensor_delay", "sensor_gain"):
        # every excited axis is fitted (an axis without evidence costs one simulation and is
        # left out of the report when its estimate is not significant)
        axes = tuple(a for a in ("x", "y") if a in excited_axes or a in axes)
    if name == "sensor_delay":
        th = np.array([max(float(hints.get("delay_" + a, 0.0)), 0.0) for a in axes])
        return EffectModel(name, tuple(f"delay_{a}_s" for a in axes), th, np.maximum(0.2 * th, 5e-6),
                           np.zeros(len(axes)), np.full(len(axes), 2.4e-3),
                           lambda t: [{"name": "sensor_delay", "axis": a, "delay_s": float(v)} for a, v in zip(axes, t)],
                           {"axes": axes})
    if name == "sensor_gain":
        th = np.array([float(hints.get("gain_" + a, 1.0)) - 1.0 for a in axes])
        return EffectModel(name, tuple(f"gain_{a}_minus_1" for a in axes), th, np.maximum(0.2 * np.abs(th), 1e-2),
                           np.full(len(axes), -0.9), np.full(len(axes), 9.0),
                           lambda t: [{"name": "sensor_gain", "axis": a, "gain": float(1.0 + v)} for a, v in zip(axes, t)],
                           {"axes": axes})
    if name == "static_load":
        def build(t, axes=axes):
            f = dict(zip(axes, (float(v) for v in t)))
            return [{"name": "static_load", "fx_n": f.get("x", 0.0), "fy_n": f.get("y", 0.0)}]
        n = len(axes)
        return EffectModel(name, tuple(f"f{a}_n" for a in axes), np.zeros(n), np.full(n, 1.0), np.full(n, -1e3),
                           np.full(n, 1e3), build, {"axes": axes})
    if name == "unbalance":
        f_hz = float(hints["speed_hz"])
        w = 2 * math.pi * f_hz

        def build(t):
            me = float(math.hypot(t[0], t[1]))
            return [{"name": "unbalance", "speed_hz": float(t[2]), "mass_ecc_kgm": me,
                     "phase_rad": float(math.atan2(t[1], t[0]))}]
        s = 1.0 / (w * w)     # 1 N of force
        df = float(hints.get("speed_step_hz", 0.01))
        return EffectModel(name, ("me_cos_kgm", "me_sin_kgm", "speed_hz"), np.array([0.0, 0.0, f_hz]),
                           np.array([s, s, df]), np.array([-1.0, -1.0, max(f_hz - 5 * df, 0.0)]),
                           np.array([1.0, 1.0, f_hz + 5 * df]), build, {"speed_hz": f_hz})
    if name == "amplifier_deadtime":
        # dead times of PWM bridges: 0.1-2 us (a grid an octave apart)
        return EffectModel(name, ("deadtime_s",), np.zeros(1), np.full(1, 2.5e-7), np.zeros(1), np.full(1, 9.9e-6),
                           lambda t: [{"name": "amplifier_deadtime", "deadtime_s": float(t[0])}], {},
                           tuple(np.array([v]) for v in (0.25e-6, 0.5e-6, 1e-6, 2e-6, 4e-6)))
    if name == "cross_coupling":
        # either sign, 5-20 % of the other axis' force (the library's range, issue 6): the
        # coupling's response is nearly linear, so the grid only saves iterations from zero
        return EffectModel(name, ("coefficient",), np.zeros(1), np.full(1, 0.03), np.full(1, -0.5), np.full(1, 0.5),
                           lambda t: [{"name": "cross_coupling", "coefficient": float(t[0])}], {},
                           tuple(np.array([v]) for v in (-0.2, -0.1, -0.05, 0.05, 0.1, 0.2)))
    raise KeyError(f"effect '{name}': not in the library")


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


def _merge_axes(name: str, key: str, axes: tuple, vals: np.ndarray, ses: np.ndarray, offset: float = 0.0) -> list[dict]:
    """One entry per axis, or one ``axis: both`` entry when the axes agree."""
    if len(axes) == 2:
        d = abs(vals[0] - vals[1])
        s = math.hypot(ses[0], ses[1])
        # the same within 3 standard errors, or within 2 % (standard errors of a long record
        # can be far below any practical difference)
        if d <= 3 * s or d <= 0.02 * max(abs(vals[0]), abs(vals[1]), 1e-12):
            w = 1 / np.maximum(ses, 1e-300) ** 2
            m = float(np.sum(w * vals) / np.sum(w))
            se = float(1 / math.sqrt(np.sum(w)))
            return [{"name": name, "params": {"axis": "both", key: m + offset},
                     "uncertainty": {key: se}, "per_axis": {a: {key: float(v + offset), "se": float(e)}
                                                          for a, v, e in zip(axes, vals, ses)}}]
    return [{"name": name, "params": {"axis": a, key: float(v + offset)}, "uncertainty": {key: float(e)}}
            for a, v, e in zip(axes, vals, ses)]


def report_entries(model: EffectModel, theta: np.ndarray, se: np.ndarray, significant: np.ndarray) -> list[dict]:
    """``closeloop.json`` entries (``name``, ``params``, ``uncertainty``) of a fitted effect.

    Axes whose parameter is not significant (|value| < 3 standard errors) are left out.
    """
    name = model.name
    if name in ("sensor_delay", "sensor_gain"):
        axes = model.fixed["axes"]
        # significant axes; else the axes the data determine (a standard error of 1e4 marks
        # a direction the data left to its prior); else all
        keep = ([i for i in range(len(axes)) if significant[i]]
                or [i for i in range(len(axes)) if np.isfinite(se[i]) and se[i] < 1e3] or list(range(len(axes))))
        ax = tuple(axes[i] for i in keep)
        key = "delay_s" if name == "sensor_delay" else "gain"
        return _merge_axes(name, key, ax, theta[keep], se[keep], 0.0 if name == "sensor_delay" else 1.0)
    if name == "static_load":
        f = dict(zip(model.fixed["axes"], zip(theta, se)))
        fx, sx = f.get("x", (0.0, 0.0))
        fy, sy = f.get("y", (0.0, 0.0))
        return [{"name": name, "params": {"fx_n": float(fx), "fy_n": float(fy)},
                 "uncertainty": {"fx_n": float(sx), "fy_n": float(sy)}}]
    if name == "unbalance":
        a, b, f_hz = theta
        me = math.hypot(a, b)
        w = 2 * math.pi * f_hz
        se_me = float(math.sqrt(0.5 * (se[0] ** 2 + se[1] ** 2)))
        return [{"name": name, "params": {"speed_hz": float(f_hz), "mass_ecc_kgm": float(me),
                                          "phase_rad": float(math.atan2(b, a))},
                 "uncertainty": {"speed_hz": float(se[2]), "mass_ecc_kgm": se_me,
                                 "phase_rad": float(se_me / max(me, 1e-300))},
                 "force_n": float(me * w * w)}]
    if name == "amplifier_deadtime":
        return [{"name": name, "params": {"deadtime_s": float(theta[0])}, "uncertainty": {"deadtime_s": float(se[0])}}]
    if name == "cross_coupling":
        return [{"name": name, "params": {"coefficient": float(theta[0])}, "uncertainty": {"coefficient": float(se[0])}}]
    raise KeyError(name)
