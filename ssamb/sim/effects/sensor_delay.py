r"""``sensor_delay``: a transport delay between the position and the controller.

Physics: the position the controller receives is :math:`x(t - \tau)` (the x probe's
conditioning, the y DCM estimate's pipeline), a fractional number of controller samples
(kernel parameters ``DELAY_X``, ``DELAY_Y``).

Signature: the sensor path's measured/model ratio (position over coil current at the excited
lines; for y the self-sensing estimate over the evaluation probe, where plant changes cancel)
has a phase lag linear in frequency, :math:`\angle R = -2\pi f\tau`, and a flat gain of 1.
Evidence: :math:`(\hat\tau/\sigma_\tau)^2` per axis, one-sided.

Fit: :math:`(\tau_x, \tau_y)` on both axes (excited or not), :math:`\tau \ge 0`, started at the ratio's
slope.
"""
from __future__ import annotations

import math

import numpy as np

from ...device import EffectModel, log10_p_upper
from ._common import EffectError, axes_of, merge_axes, ratio_path, sensor_keep

NAME = "sensor_delay"
REQUIRED = ("axis", "delay_s")
OPTIONAL = ()
SIGNATURE = "phase lag of the sensor path linear in frequency (slope -2 pi tau), gain flat at 1"
SEARCHABLE = True
NEEDS_HINT = False
ORDER = 1


def validate(p: dict, where: str) -> dict:
    if not 0 <= float(p["delay_s"]) < 2.5e-3:
        raise EffectError(f"{where}: delay_s must be in [0, 2.5e-3) s (got {p['delay_s']})")
    return p


def apply(e: dict, ov: dict, f_x, f_y, t, base_dir) -> None:
    for ax in axes_of(e["axis"]):
        key = "DELAY_" + ax.upper()
        ov[key] = ov.get(key, 0.0) + float(e["delay_s"])


def sensor_evidence(name: str, ft, alpha: float, kind: str, st) -> dict:
    """Evidence of a sensor effect (``kind`` ``tau``: delay; ``alpha``: gain) on the sensor paths."""
    axes, score, lp_min, det, hints = [], 0.0, 0.0, {}, {}
    n_tests = 2
    for ax in ("x", "y"):
        r = ratio_path(ft, ax, st)
        if r is None:
            continue
        if kind == "tau":
            z = r["z_tau"]
            lp = log10_p_upper(z) + math.log10(n_tests)
            det[ax] = {"tau_s": r["tau_s"], "se_s": r["se_tau_s"], "z": z, "path": r["path"], "lines": r["n_lines"],
                       "chi2_per_dof_phase": r["chi2_phase"] / max(r["dof"], 1)}
            chi = r["chi2_tau"]
        else:
            from ...device import log10_p_two_sided

            z = r["z_alpha"]
            lp = log10_p_two_sided(z) + math.log10(n_tests)
            det[ax] = {"gain": r["gain"], "se_log_gain": r["se_alpha"], "z": z, "path": r["path"],
                       "lines": r["n_lines"], "chi2_per_dof_gain": r["chi2_gain"] / max(r["dof"], 1)}
            chi = r["chi2_alpha"]
        lp_min = min(lp_min, lp)
        if lp < math.log10(alpha):
            axes.append(ax)
            score += chi
            hints[("delay_" if kind == "tau" else "gain_") + ax] = r["tau_s"] if kind == "tau" else r["gain"]
    hints["axes"] = axes
    return {"score": score, "log10_p": lp_min, "significant": bool(axes), "hints": hints, "details": det}


def evidence(ft, alpha: float, st) -> dict:
    return sensor_evidence(NAME, ft, alpha, "tau", st)


def sensor_claim(ft, st, key: str) -> float:
    tot = 0.0
    for ax in ("x", "y"):
        r = ratio_path(ft, ax, st)
        if r is not None:
            tot += r[key]
    return tot


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return sensor_claim(ft, st, "chi2_tau")


def fit_axes(hints: dict, excited_axes: tuple) -> tuple:
    """Every sensor axis is fitted, excited or not: an axis the excitation does not drive still
    closes its loop through the sensor (its noise response, the PWM ripple's aliased lines), and a
    delay left out there stays in that axis' residual (an axis without evidence costs one
    parameter, and its estimate is left out of the report when the data do not determine it)."""
    return ("x", "y")


def model(hints: dict, record, st) -> EffectModel | str:
    axes = fit_axes(hints, tuple(record.excited_axes))
    hinted = tuple(a in (hints.get("axes") or ()) and ("delay_" + a) in hints for a in axes)
    th = np.array([max(float(hints.get("delay_" + a, 0.0)), 0.0) for a in axes])
    # a step of 1 us: at the PWM's aliased lines (to 40 kHz) a delay is a phase of 0.25 rad per
    # microsecond, and a finite difference over several microseconds is no longer linear
    return EffectModel(NAME, tuple(f"delay_{a}_s" for a in axes), th, np.full(len(axes), 1e-6),
                       np.zeros(len(axes)), np.full(len(axes), 2.4e-3),
                       lambda t: [{"name": NAME, "axis": a, "delay_s": float(v)} for a, v in zip(axes, t)],
                       {"axes": axes}, _grid(th, hinted))


def _grid(th: np.ndarray, hinted: tuple) -> tuple:
    r"""Coarse starts of a fit for the axes whose evidence gives no delay: each such axis alone
    every 10 us from 0 to 120 us (the other at its start), and both at 5-120 us every 5 us when
    neither has one. The PWM carrier's aliased lines (6.7-40 kHz) turn a delay into phases
    :math:`2\pi f\tau` of a cycle or more, so the cost has a minimum every few tens of
    microseconds, and a local fit from far below the truth (the excited lines' slope is blind to
    a delay of a few tens of microseconds at 26 Hz) stops at the wrong one."""
    pts = []
    if not any(hinted):
        pts += [np.array([d, d]) for d in np.arange(5e-6, 121e-6, 5e-6)]
    for i, h in enumerate(hinted):
        if not h:
            for d in np.arange(0.0, 121e-6, 10e-6):
                t = th.copy()
                t[i] = d
                pts.append(t)
    return tuple(pts)


def report(m: EffectModel, theta, se, significant) -> list[dict]:
    axes = m.fixed["axes"]
    keep = sensor_keep(axes, se, significant)
    return merge_axes(NAME, "delay_s", tuple(axes[i] for i in keep), theta[keep], se[keep], 0.0)
