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

import functools
import math

import numpy as np

from ...device import EffectModel, log10_p_upper
from ._common import EffectError, axes_of, merge_axes, ratio_path, sensor_keep, sensor_restart

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
                       {"axes": axes}, _grid(th, hinted, 1.0 / float(record.fs_hz)),
                       mirrors=functools.partial(_mirrors, ts=1.0 / float(record.fs_hz)),
                       aliases=functools.partial(_aliases, ts=1.0 / float(record.fs_hz)),
                       comb=functools.partial(_comb, ts=1.0 / float(record.fs_hz)),
                       restart=functools.partial(_restart, axes=axes))


def _restart(theta: np.ndarray, hints: dict, axes: tuple) -> np.ndarray | None:
    r"""The fitted delays plus the delays their residual still shows on the axes where its
    evidence is significant (``hints``: :func:`evidence` of the residual), :math:`\tau + \hat\tau_r`
    (not below zero); None when no axis shows one."""
    return sensor_restart(theta, hints, axes, "delay_", lambda d, r: max(d + r, 0.0))


#: the longest delay the coarse starts try and the comb reaches (ten 12 us controller samples)
SEARCH_TOP_S = 120e-6


def _mirrors(theta: np.ndarray, ts: float, near: float = 0.25) -> list:
    r"""The fitted delays reflected across the nearest whole controller sample :math:`kT_s`
    (:math:`k \ge 1`), one axis at a time, where a delay lies within ``near`` of a sample of it:
    the cost has a kink there and similar values at :math:`kT_s \pm \delta` (:func:`_grid`), so a
    fit that ended at :math:`kT_s - \delta` may have its truth at :math:`kT_s + \delta`."""
    out = []
    for i, d in enumerate(np.asarray(theta, float)):
        k = round(d / ts)
        if k >= 1 and abs(d - k * ts) <= near * ts:
            t = np.array(theta, float)
            t[i] = 2 * k * ts - d
            out.append(t)
    return out


def _aliases(theta: np.ndarray, ts: float) -> list:
    r"""The fitted delays one whole controller sample longer and shorter, one axis at a time
    (not below zero). The interpolating delay line (:func:`_grid`) fixes the fraction of a
    sample through the controller outputs near the Nyquist frequency, but the whole number of
    samples only through the phase it adds at every line: on an axis whose sensor the PWM's
    ripple does not reach (the x probe's bandwidth), one sample, a phase of 0.002 rad at 25 Hz,
    can lie within the noise."""
    out = []
    for i, d in enumerate(np.asarray(theta, float)):
        for s in (-ts, ts):
            if d + s >= 0.0:
                t = np.array(theta, float)
                t[i] = d + s
                out.append(t)
    return out


def _comb(theta: np.ndarray, ts: float, top: float = SEARCH_TOP_S) -> list:
    r"""The fitted delays every whole controller sample :math:`kT_s` longer and shorter within the
    search range :math:`[0, \max(\text{top}, \tau + T_s)]` (the coarse starts' range,
    :func:`_grid`), one axis at a time: the aliases (:func:`_aliases`) at every distance. On an
    axis the excitation does not drive, the whole number of samples shows only in the phase of
    the loop's noise response, and two samples off can fit the record as well as one."""
    out = []
    for i, d in enumerate(np.asarray(theta, float)):
        hi = max(top, d + ts)
        for k in range(-int(np.floor(d / ts + 1e-9)), int(np.floor((hi - d) / ts + 1e-9)) + 1):
            if k != 0:
                t = np.array(theta, float)
                t[i] = max(d + k * ts, 0.0)
                out.append(t)
    return out


def _grid(th: np.ndarray, hinted: tuple, ts: float, top: float = SEARCH_TOP_S) -> tuple:
    r"""Coarse starts of a fit: four per controller sample interval, at its eighths 1, 3, 5 and 7
    of each interval :math:`[kT_s, (k+1)T_s)` up to ``top``, and no delay.

    The model delays the sensed position by :math:`\tau = (m + r) T_s` through linear
    interpolation between two stored samples, :math:`(1-r)x_{n-m} + r x_{n-m-1}`, a filter whose
    gain near the Nyquist frequency, :math:`|1 - 2r|`, falls to zero at half a sample and rises
    again: the controller outputs at the PWM carrier's aliased lines (up to the Nyquist frequency)
    change with the fraction :math:`r`, the cost has a kink at every whole sample and similar
    values at :math:`r` and :math:`1 - r`. A local fit crosses neither, so it must start near the
    truth: an axis whose evidence gives no delay is started in every interval up to ``top`` (the
    other axis at its start; both axes together as well when neither has a delay), an axis with
    one (the excited lines' slope, blind to a few microseconds at tens of hertz) in the interval
    of its hint and the two beside it.
    """
    q = [0.0] + [(k + f) * ts for k in range(int(np.ceil(top / ts))) for f in (0.125, 0.375, 0.625, 0.875)
                 if (k + f) * ts <= top]
    q = np.array(q)
    pts = []
    if not any(hinted):
        pts += [np.array([d, d]) for d in q[1:]]
    for i, h in enumerate(hinted):
        for d in (q[np.abs(q - th[i]) <= 1.5 * ts] if h else q):
            t = th.copy()
            t[i] = d
            pts.append(t)
    return tuple(pts)


def report(m: EffectModel, theta, se, significant) -> list[dict]:
    axes = m.fixed["axes"]
    keep = sensor_keep(axes, se, significant)
    return merge_axes(NAME, "delay_s", tuple(axes[i] for i in keep), theta[keep], se[keep], 0.0)
