r"""``sensor_gain``: a scale error of the position measurement.

Physics: the sensor reads :math:`g\,y` (knob ``sensor_gain``; gains of several effects
multiply): an optical sensor's sensitivity depends on its LED, its alignment and the ball.

Signature: the position over the current (``y/i``) has a flat gain :math:`g \ne 1` and no phase;
held at the reference reading, the ball floats at :math:`y_d/g`, so the current shifts too.
Evidence: :math:`(\hat\alpha/\sigma_\alpha)^2` of ``y/i``, two-sided (:math:`\alpha = \ln g`).

Fit: :math:`g - 1`, started at the path's gain.
"""
from __future__ import annotations

import numpy as np

from ...device import EffectModel
from ._common import number, ratio_claim, ratio_evidence

NAME = "sensor_gain"
REQUIRED = ("gain",)
OPTIONAL = ()
SIGNATURE = "flat gain of the position over the coil current different from 1, no phase"
SEARCHABLE = True
NEEDS_HINT = False
#: the calibrated parameter this effect is indistinguishable from
CALIBRATED_KEY = "sensors.position_gain"
KNOB = "sensor_gain"


def validate(p: dict, where: str) -> dict:
    return {"gain": number(p, "gain", where, 0.2, 5.0)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] *= float(e["gain"])


def evidence(ft, alpha: float, st) -> dict:
    ev = ratio_evidence(ft, alpha, "y/i", "alpha", 0)
    if ev["significant"]:
        ev["hints"]["gain"] = ev["details"]["gain"]
    return ev


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return ratio_claim(ft, "y/i", "alpha")


def model(hints: dict, record, st):
    if CALIBRATED_KEY in (getattr(st, "calibration", None) or {}):
        return f"indistinguishable from the calibrated {CALIBRATED_KEY}: the same reading of the same ball"
    th = float(np.clip(hints.get("gain", 1.0) - 1.0, -0.5, 1.0))
    return EffectModel(NAME, ("gain_minus_1",), np.array([th]), np.array([0.02]), np.array([-0.5]), np.array([1.0]),
                       lambda t: [{"name": NAME, "gain": float(1.0 + t[0])}], {})


def report(m, theta, se, significant) -> list[dict]:
    return [{"name": NAME, "params": {"gain": float(1.0 + theta[0])}, "uncertainty": {"gain": float(se[0])}}]
