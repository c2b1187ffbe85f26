r"""Physical checks of the levitated ball's model against its data.

Each check computes a number from the data alone and sets it beside what the model's
parameters predict:

* :func:`coil_time_constant` -- the current's response to the command. On levitated samples
  with the command off its limits, the one-step regression
  :math:`i_{k+1} = \alpha i_k + \beta u_k + \gamma` is the exact discretisation of
  :math:`L\,di/dt = g u - V_0 - R i` over a sample (the motion term is small at rest), so
  :math:`\tau = -T_s/\ln\alpha = L/R`, the incremental resistance seen by the command
  :math:`(1-\alpha)/\beta = R/g` and the command's offset :math:`-\gamma/\beta = V_0/g`.
  The model predicts :math:`\tau = L(\bar y)/(R_{coil} + R_{shunt})`, :math:`R/g` with
  :math:`g = V_{max}/V_{ref}`, and no offset.
* :func:`equilibrium_currents` -- on every plateau of the reference where the ball has settled,
  the mean current against the mean position, beside the force law's
  :math:`i_{eq}(y) = (1 + y/a)\sqrt{2 a m g/k}`; a straight line through the plateaus gives the
  law's length :math:`a` as the data see it (:math:`i_{eq} \propto a + y`).
* :func:`noise_levels` -- the sensors' noise before the ADCs: the current's from the one-step
  regression's residual (:math:`n_{k+1} - \alpha n_k` has variance :math:`(1+\alpha^2)\sigma^2`),
  the position's from the second difference :math:`y_k - (y_{k-1} + y_{k+1})/2` (variance
  :math:`1.5\sigma^2` for white noise), each less its ADC's rounding (:math:`q^2/12`). Upper
  bounds: what the ball and the coil do between samples adds to both.
* :func:`start_estimate` -- what these checks say of the calibratable parameters, with the
  published force law: the stage's output :math:`V_{max} = V_{ref} R/(R/g)` and drop
  :math:`V_0 g` (coil and shunt resistance as published), the gap-independent inductance
  :math:`k_0 = \tau R - k/(1 + \bar y/a)`, and the position sensor's scale and zero from the
  plateaus' line :math:`i = s (y + A)`: :math:`g_s = \sqrt{2 m g/(k a)}/s`, :math:`o_s = a g_s - A`
  (with one level, :math:`g_s = 1`); then the same model anchored at the face
  (:func:`face_anchored`: the sensor's zero where the ball stuck to the magnet reads, the law's
  length and force constant moved to keep every levitated replay). A start for the calibration,
  never its result.
* :func:`current_at_rest` -- the current reading with the stage off: after ``rest_s`` of zero
  command the coil's current has decayed (:math:`e^{-20}` at its 10-20 ms time constant), so the
  reading is the current sensor's zero; the model reads 0.
* :func:`face_reading` -- the position reading with the ball held at the magnet's face (readings
  within 15 counts of zero, steady to a count, with current in the coil): the sensor's reading of
  :math:`y = 0`, which the model puts at its zero :math:`o_s`. A reading clipped at the ADC's 0
  only bounds it from above.
* :func:`loop_poles` -- the linearised sampled loop (plant discretised exactly over a sample
  with the voltage held, the controller as it runs) at an operating point: its poles, and
  whether all lie inside the unit circle, and the least damped oscillation (damping ratio and
  frequency of :math:`s = \ln z / T_s`).
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.linalg as sla

from . import controller as _ctl
from .physics import equilibrium_current_a, inductance_h

__all__ = ["coil_time_constant", "equilibrium_currents", "noise_levels", "loop_poles", "start_estimate",
           "face_anchored", "mean_force_offset", "current_at_rest", "face_reading"]


def _levitated_steady(arrays: Mapping, cfg: Mapping, y_max_m: float = 0.012) -> np.ndarray:
    y, i, u = (np.asarray(arrays[c], float) for c in ("y", "i", "u"))
    vref = cfg["controller"]["v_ref_v"]
    m = (y > 0.002) & (y < y_max_m) & (i > cfg["levitation"]["min_current_a"]) & (u > 0.05) & (u < vref - 0.05)
    return m


def coil_time_constant(arrays: Mapping, cfg: Mapping) -> dict:
    """The coil's response to the command (module docstring): measured and model values."""
    y, i, u = (np.asarray(arrays[c], float) for c in ("y", "i", "u"))
    m = _levitated_steady(arrays, cfg)
    k = np.nonzero(m[:-1] & m[1:])[0]
    X = np.c_[i[k], u[k], np.ones(len(k))]
    (alpha, beta, gamma), *_ = np.linalg.lstsq(X, i[k + 1], rcond=None)
    ts = cfg["controller"]["ts_s"]
    r_tot = cfg["coil"]["r_ohm"] + cfg["coil"]["r_shunt_ohm"]
    ybar = float(np.mean(y[k]))
    ind = float(inductance_h(ybar, cfg["magnet"]["k0_h"], cfg["magnet"]["k_h"], cfg["magnet"]["a_m"]))
    gain = cfg["amplifier"]["v_max_v"] / cfg["controller"]["v_ref_v"]
    return {"samples": int(len(k)), "y_mean_m": ybar,
            "tau_s": float(-ts / np.log(alpha)), "tau_model_s": ind / r_tot,
            "r_over_gain_ohm": float((1 - alpha) / beta), "r_over_gain_model_ohm": r_tot / gain,
            "offset_v": float(-gamma / beta), "offset_model_v": 0.0,
            "inductance_h_if_r_nominal": float(-ts / np.log(alpha)) * r_tot, "inductance_model_h": ind}


def equilibrium_currents(arrays: Mapping, cfg: Mapping, window_s: float = 2.0) -> dict:
    """Mean (y, i) over settled windows of a constant reference, and the force law's current."""
    y, i, yd = (np.asarray(arrays[c], float) for c in ("y", "i", "yd"))
    ts = cfg["controller"]["ts_s"]
    w = int(round(window_s / ts))
    ok = _levitated_steady(arrays, cfg)
    rows = []
    for a in range(0, len(y) - w + 1, w):
        s = slice(a, a + w)
        if np.ptp(yd[s]) == 0 and ok[s].all() and abs(np.mean(y[s]) - yd[a]) < 2e-4:
            rows.append((float(np.mean(y[s])), float(np.mean(i[s])), float(yd[a])))
    out = {"plateaus": len(rows)}
    if not rows:
        return out
    ym, im, _ = (np.array(c) for c in zip(*rows))
    b, c = cfg["ball"], cfg["magnet"]
    pred = equilibrium_current_a(ym, b["mass_kg"], b["gravity_m_per_s2"], c["k_h"], c["a_m"])
    out.update({"y_m": ym.tolist(), "i_a": im.tolist(), "i_model_a": pred.tolist(),
                "ratio_mean": float(np.mean(im / pred))})
    if np.ptp(ym) > 5e-4:
        slope, icpt = np.polyfit(ym, im, 1)
        out["length_m"] = float(icpt / slope)            # i proportional to (a + y)
    return out


def noise_levels(arrays: Mapping, cfg: Mapping) -> dict:
    """Upper bounds of the sensors' noise before the ADCs (module docstring)."""
    y, i, u = (np.asarray(arrays[c], float) for c in ("y", "i", "u"))
    qy, qi = _ctl.position_lsb_m(cfg), _ctl.current_lsb_a(cfg)
    m = _levitated_steady(arrays, cfg)
    k = np.nonzero(m[:-1] & m[1:])[0]
    X = np.c_[i[k], u[k], np.ones(len(k))]
    sol, *_ = np.linalg.lstsq(X, i[k + 1], rcond=None)
    r = i[k + 1] - X @ sol
    s = 1.4826 * np.median(np.abs(r - np.median(r)))
    si = np.sqrt(max(s * s / (1 + sol[0] ** 2) - qi * qi / 12, 0.0))
    kk = np.nonzero(m[1:-1] & m[:-2] & m[2:])[0] + 1
    d2 = y[kk] - 0.5 * (y[kk - 1] + y[kk + 1])
    sy = np.sqrt(max(np.var(d2) / 1.5 - qy * qy / 12, 0.0))
    return {"current_a": float(si), "position_m": float(sy), "current_counts": float(si / qi),
            "position_counts": float(sy / qy)}


def loop_poles(cfg: Mapping, y0_m: float, knobs: Mapping | None = None) -> dict:
    """Poles of the linearised sampled loop at the position ``y0_m`` (module docstring).

    The plant's states are (y, dy/dt, i); its input the voltage, held over a sample;
    the controller's states the previous error and the two integrators (limits inactive).
    ``knobs`` may set ``sensor_gain`` (the reading's slope) and ``eddy_tau_s``-free models only.
    """
    kn = dict(knobs or {})
    b, mg_, co = cfg["ball"], cfg["magnet"], cfg["coil"]
    m, g = b["mass_kg"], b["gravity_m_per_s2"]
    k0, k, a = mg_["k0_h"], mg_["k_h"], mg_["a_m"]
    r = co["r_ohm"] + co["r_shunt_ohm"]
    gain = cfg["amplifier"]["v_max_v"] / cfg["controller"]["v_ref_v"]
    gam = float(kn.get("sensor_gain", 1.0))
    f_ext = float(kn.get("extra_force_n", 0.0))
    s = 1.0 + y0_m / a
    ind, dind = k0 + k / s, -k / (a * s * s)
    i0 = float(equilibrium_current_a(y0_m, m, g, k, a, f_ext))
    force = 0.5 * i0 * i0 * (-dind)
    dfdy = -2.0 * force / (a + y0_m)
    dfdi = 2.0 * force / i0
    damp = float(kn.get("damping_n_s_per_m", 0.0))
    ac = np.array([[0.0, 1.0, 0.0], [-dfdy / m, -damp / m, -dfdi / m], [0.0, -i0 * dind / ind, -r / ind]])
    bc = np.array([[0.0], [0.0], [gain / ind]])
    ts = cfg["controller"]["ts_s"]
    mm = np.zeros((4, 4))
    mm[:3, :3], mm[:3, 3:] = ac * ts, bc * ts
    e = sla.expm(mm)
    phi, gam_u = e[:3, :3], e[:3, 3:]
    c = cfg["controller"]
    kp, ki, kd, kpi, kii = c["kp_a_per_m"], c["ki_a_per_m_s"], c["kd_a_s_per_m"], c["kpi_v_per_a"], c["kii_v_per_a_s"]
    # loop state z = (y, v, i, e_prev, I, J); rows: the controller's quantities as functions of z
    err = np.array([-gam, 0, 0, 0, 0, 0.0])
    integ = np.array([0, 0, 0, 0, 1, 0.0]) + ki * ts * err
    idem = -(kp * err + integ + kd * (err - np.array([0, 0, 0, 1, 0, 0.0])) / ts)
    ei = idem - np.array([0, 0, 1, 0, 0, 0.0])
    intei = np.array([0, 0, 0, 0, 0, 1.0]) + kii * ts * ei
    u = kpi * ei + intei
    acl = np.zeros((6, 6))
    acl[:3, :3] = phi
    acl[:3] += gam_u @ u[None, :]
    acl[3], acl[4], acl[5] = err, integ, intei
    poles = np.linalg.eigvals(acl)
    osc = poles[((np.abs(poles.imag) > 1e-9) | (poles.real < 0)) & (np.abs(poles) > 0)]
    sp = np.log(osc.astype(complex)) / ts
    zeta = -sp.real / np.abs(sp) if len(sp) else np.array([1.0])
    j = int(np.argmin(zeta))
    return {"y0_m": float(y0_m), "i0_a": i0, "poles": poles, "spectral_radius": float(np.max(np.abs(poles))),
            "stable": bool(np.max(np.abs(poles)) < 1.0), "least_damping": float(zeta[j]),
            "least_damped_hz": float(abs(sp[j].imag) / (2 * np.pi)) if len(sp) else 0.0}


def start_estimate(arrays: Mapping, cfg: Mapping) -> dict:
    """Dotted config key -> value that the checks imply (module docstring); {} without data."""
    out = {}
    c = coil_time_constant(arrays, cfg)
    if c["samples"] < 50 or not (0 < c["tau_s"] < 1) or c["r_over_gain_ohm"] <= 0:
        return out
    r_tot = cfg["coil"]["r_ohm"] + cfg["coil"]["r_shunt_ohm"]
    gain = r_tot / c["r_over_gain_ohm"]
    out["amplifier.v_max_v"] = gain * cfg["controller"]["v_ref_v"]
    out["amplifier.drop_v"] = max(c["offset_v"] * gain, 0.0)
    mg_ = cfg["magnet"]
    k0 = c["tau_s"] * r_tot - mg_["k_h"] / (1.0 + c["y_mean_m"] / mg_["a_m"])
    if k0 > 0:
        out["magnet.k0_h"] = k0
    e = equilibrium_currents(arrays, cfg)
    b = cfg["ball"]
    c0 = np.sqrt(2 * b["mass_kg"] * b["gravity_m_per_s2"] / (mg_["k_h"] * mg_["a_m"]))
    gs = float(cfg["sensors"]["position_gain"])
    if e["plateaus"]:
        ym, im = np.array(e["y_m"]), np.array(e["i_a"])
        if "length_m" in e:
            slope = np.polyfit(ym, im, 1)[0]
            gs = c0 / slope
            out["sensors.position_gain"] = float(gs)
            out["sensors.position_offset_m"] = float(mg_["a_m"] * gs - e["length_m"])
        else:
            out["sensors.position_offset_m"] = float(np.mean(ym - gs * (im / c0 - mg_["a_m"])))
    else:
        o = mean_force_offset(arrays, cfg, gs)
        if o is not None:
            out["sensors.position_offset_m"] = o
    return {k: float(v) for k, v in face_anchored(out, cfg).items()}


def face_anchored(est: Mapping, cfg: Mapping) -> dict:
    r"""The same model with the sensor's zero where the magnet's face reads (``cfg``'s
    ``sensors.position_offset_m``) and the force law's length moved instead.

    In reading coordinates the law's equilibrium current :math:`(C/g_s)(a g_s - o_s + y_s)`,
    :math:`C = \sqrt{2 m g/(k a)}`, and the gap-dependent inductance :math:`k a g_s/(a g_s - o_s + y_s)`
    depend on :math:`(a, k, o_s)` only through :math:`a g_s - o_s` and :math:`k a`: the transformation
    :math:`a' = a - (o_s - o_{face})/g_s`, :math:`k' = k a/a'`, :math:`o_s' = o_{face}` leaves every replay
    of the levitated ball unchanged and moves only the face, the upper stop, to the reading the
    rig shows there. ``est`` without a sensor zero, or a length that would not stay positive, is
    returned as it is."""
    out = dict(est)
    if "sensors.position_offset_m" not in out:
        return out
    mg_, se = cfg["magnet"], cfg["sensors"]
    gs = float(out.get("sensors.position_gain", se["position_gain"]))
    k = float(out.get("magnet.k_h", mg_["k_h"]))
    a = float(out.get("magnet.a_m", mg_["a_m"]))
    a2 = a - (out["sensors.position_offset_m"] - float(se["position_offset_m"])) / gs
    if a2 < 0.1 * a:
        return out
    out.update({"magnet.a_m": a2, "magnet.k_h": k * a / a2,
                "sensors.position_offset_m": float(se["position_offset_m"])})
    return out


def mean_force_offset(arrays: Mapping, cfg: Mapping, gs: float) -> float | None:
    r"""The sensor's zero :math:`o_s` that makes the force law carry the weight on average over the
    levitated samples of a record without settled plateaus (a moving reference): the ball's mean
    acceleration over a long stretch is zero, so
    :math:`\overline{(i/(c_0 (a + (y_s - o_s)/g_s)))^2} = 1` with :math:`c_0 = \sqrt{2 m g/(k a)}`
    (published force law, scale ``gs``); None when no zero in the sensor's range satisfies it."""
    from scipy.optimize import brentq

    y, i = (np.asarray(arrays[c], float) for c in ("y", "i"))
    m = _levitated_steady(arrays, cfg)
    if m.sum() < 100:
        return None
    b, mg_ = cfg["ball"], cfg["magnet"]
    c0 = np.sqrt(2 * b["mass_kg"] * b["gravity_m_per_s2"] / (mg_["k_h"] * mg_["a_m"]))
    ym, im = y[m], i[m]

    def excess(o):
        gap = mg_["a_m"] + (ym - o) / gs
        return float(np.mean((im / (c0 * np.maximum(gap, 1e-4))) ** 2)) - 1.0

    lo, hi = -0.01, float(np.min(ym)) + gs * mg_["a_m"] * 0.9
    if not excess(lo) < 0.0 < excess(hi):
        return None
    return float(brentq(excess, lo, hi, xtol=1e-7))


def current_at_rest(arrays: Mapping, cfg: Mapping, rest_s: float = 0.2) -> dict:
    """The current reading after ``rest_s`` of zero command (module docstring): median and count."""
    i, u = np.asarray(arrays["i"], float), np.asarray(arrays["u"], float)
    n = int(round(rest_s / cfg["controller"]["ts_s"]))
    off = u <= 0.0
    run = np.zeros(len(u), int)
    for k in range(1, len(u)):
        run[k] = run[k - 1] + 1 if off[k] else 0
    sel = run >= n
    return {"samples": int(sel.sum()), "current_a": float(np.median(i[sel])) if sel.any() else None}


def face_reading(arrays: Mapping, cfg: Mapping, max_counts: int = 15, hold: int = 5) -> dict:
    """The position reading with the ball held at the magnet's face (module docstring)."""
    y, i = np.asarray(arrays["y"], float), np.asarray(arrays["i"], float)
    qy = _ctl.position_lsb_m(cfg)
    c = np.round(y / qy)
    k = np.arange(hold, len(y) - hold)
    win = np.lib.stride_tricks.sliding_window_view(c, 2 * hold)[: len(k)]
    sel = k[(c[k] <= max_counts) & (np.ptp(win, axis=1) <= 1) & (i[k] > cfg["levitation"]["min_current_a"] / 2)]
    return {"samples": int(len(sel)), "reading_m": float(np.median(y[sel])) if len(sel) else None,
            "clipped": bool(len(sel) and np.median(c[sel]) <= 0)}

