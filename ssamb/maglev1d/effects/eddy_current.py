r"""``eddy_current``: the flux, and with it the force, lags the coil current.

Physics: eddy currents in the solid core and the ball act like a core-loss resistance
:math:`R_c = L/\tau_e` in parallel with the coil's inductance. The force-producing current
:math:`i_m` obeys :math:`L\,\dot i_m = L (v - R i_m)/(L + R\tau_e) - i_m \dot y\, dL/dy`, the
terminal current is :math:`i = i_m + \tau_e (v - R i_m)/(L + R\tau_e)` (knob ``eddy_tau_s``;
:mod:`ssamb.maglev1d.physics`).

Signature: the position over the measured current (``y/i``) lags (the force lags the current
the sensor reads) while the current over the command (``i/u``) leads (the terminal current
jumps with the voltage). Evidence: both one-sided slopes significant,
:math:`z_{y/i}^2 + z_{i/u}^2`.

Fit: :math:`\tau_e \ge 0`, started at the ``y/i`` slope (or a coarse grid).
"""
from __future__ import annotations

import math

from ._common import entries, number, ratio_claim, ratio_evidence, scalar_model

NAME = "eddy_current"
REQUIRED = ("tau_s",)
OPTIONAL = ()
SIGNATURE = "position over current lags and current over command leads (force behind the measured current)"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "eddy_tau_s"


def validate(p: dict, where: str) -> dict:
    return {"tau_s": number(p, "tau_s", where, 0.0, 0.05)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["tau_s"])


def evidence(ft, alpha: float, st) -> dict:
    a = ratio_evidence(ft, alpha / 2, "y/i", "tau", +1)
    b = ratio_evidence(ft, alpha / 2, "i/u", "tau", -1)
    sig = a["significant"] and b["significant"]
    lp = max(a["log10_p"], b["log10_p"]) + math.log10(2)
    out = {"score": (a["score"] + b["score"]) if sig else 0.0, "log10_p": lp, "significant": bool(sig),
           "hints": {}, "details": {"y/i": a["details"], "i/u": b["details"]}}
    if sig:
        out["hints"]["tau_s"] = a["details"]["tau_s"]
    return out


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return ratio_claim(ft, "y/i", "tau") + ratio_claim(ft, "i/u", "tau")


def model(hints: dict, record, st):
    return scalar_model(NAME, "tau_s", hints.get("tau_s", 0.0), 1e-3, 0.0, 0.03, grid=(2e-3, 6e-3))


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
