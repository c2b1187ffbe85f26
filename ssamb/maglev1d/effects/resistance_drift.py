r"""``resistance_drift``: the coil warms, its resistance grows.

Physics: :math:`R(t) = R + \rho\,t` (:math:`t` from the record's start; knob
``r_rate_ohm_per_s``; rates add): copper's resistance grows by 0.39 %/K, and a coil carrying
half an ampere warms by kelvins per minute.

Signature: the current loop holds the current, so the command creeps,
:math:`\Delta u(t) = \rho\,t\,i_0 V_{ref}/V_{max}`; the current and the position do not. Evidence:
the slope of the residual's window means of ``u`` against time
(:math:`(\hat s/\sigma_s)^2`), with no slope in ``i``.

Fit: :math:`\rho`, started at :math:`\hat s\,(V_{max}/V_{ref})/i_0`.
"""
from __future__ import annotations

import math

import numpy as np

from ...device import log10_p_two_sided
from ._common import entries, number, operating_point, scalar_model

NAME = "resistance_drift"
REQUIRED = ("rate_ohm_per_s",)
OPTIONAL = ()
SIGNATURE = "the command's residual drifts linearly in time, the coil current's does not"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "r_rate_ohm_per_s"


def validate(p: dict, where: str) -> dict:
    return {"rate_ohm_per_s": number(p, "rate_ohm_per_s", where, -1.0, 1.0)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["rate_ohm_per_s"])


def _slope(win) -> tuple[float, float]:
    """Weighted least-squares slope of window means against time, and its standard error."""
    t, m, se = (np.asarray(win[k], float) for k in ("t_s", "mean", "se"))
    ok = np.isfinite(m) & np.isfinite(se) & (se > 0)
    if ok.sum() < 3:
        return 0.0, math.inf
    w = 1.0 / se[ok] ** 2
    tt = t[ok] - np.sum(w * t[ok]) / np.sum(w)
    s = float(np.sum(w * tt * m[ok]) / np.sum(w * tt * tt))
    return s, float(1.0 / math.sqrt(np.sum(w * tt * tt)))


def evidence(ft, alpha: float, st) -> dict:
    win = getattr(ft, "windows", None) or {}
    if "u" not in win or "i" not in win:
        return {"score": 0.0, "log10_p": 0.0, "significant": False, "hints": {},
                "details": {"reason": "no window means of the residual"}}
    su, eu = _slope(win["u"])
    si, ei = _slope(win["i"])
    zu, zi = su / eu, si / ei
    lp_u = log10_p_two_sided(zu) + math.log10(2)
    lp_i = log10_p_two_sided(zi) + math.log10(2)
    sig = lp_u < math.log10(alpha) and lp_i >= math.log10(alpha)
    return {"score": zu * zu if sig else 0.0, "log10_p": lp_u, "significant": bool(sig),
            "hints": {"slope_u_v_per_s": su},
            "details": {"u": {"slope_v_per_s": su, "z": zu}, "i": {"slope_a_per_s": si, "z": zi}}}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    win = getattr(ft, "windows", None) or {}
    if "u" not in win:
        return 0.0
    s, e = _slope(win["u"])
    return (s / e) ** 2 if math.isfinite(e) else 0.0


def model(hints: dict, record, st):
    g = record.meta.get("constants", {}).get("v_gain", 1.0)
    _, i0 = operating_point(record)
    return scalar_model(NAME, "rate_ohm_per_s", hints.get("slope_u_v_per_s", 0.0) * g / max(i0, 1e-3),
                        1e-3, -0.05, 0.05)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
