r"""``sensor_offset``: the position sensor's zero is not at the magnet's face.

Physics: the sensor reads :math:`y + o` (knob ``sensor_offset_m``; offsets add): the beam's
alignment, the ball's size, ambient light on an optical sensor.

Signature: held at the reference reading, the ball floats at :math:`y_d - o`; the force law
wants :math:`\Delta i = -o\, i_0/(a + y_0)` (:math:`i_{eq} \propto a + y`) and the command follows;
the position itself is held. Evidence: offsets of ``i`` and ``u`` of one sign, none of ``y``.
At a single operating point this is the signature of ``static_load`` as well; across levels of
the reference the two differ (:math:`\Delta i` constant here, proportional to :math:`i_0` there).

Fit: :math:`o`, started at :math:`-\Delta i\,(a + y_0)/i_0`.
"""
from __future__ import annotations

from ._common import entries, force_like_claim, force_like_evidence, number, operating_point, scalar_model

NAME = "sensor_offset"
REQUIRED = ("offset_m",)
OPTIONAL = ()
SIGNATURE = "offsets of the coil current and the command of one sign, none of the position (constant over levels)"
SEARCHABLE = True
NEEDS_HINT = False
#: the calibrated parameter this effect is indistinguishable from
CALIBRATED_KEY = "sensors.position_offset_m"
KNOB = "sensor_offset_m"


def validate(p: dict, where: str) -> dict:
    return {"offset_m": number(p, "offset_m", where, -0.01, 0.01)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["offset_m"])


def evidence(ft, alpha: float, st) -> dict:
    return force_like_evidence(ft, alpha, 0)


claim = force_like_claim


def model(hints: dict, record, st):
    if CALIBRATED_KEY in (getattr(st, "calibration", None) or {}):
        return f"indistinguishable from the calibrated {CALIBRATED_KEY}: the same reading of the same ball"
    c = record.meta.get("constants", {})
    y0, i0 = operating_point(record)
    o0 = -hints.get("offset_i_a", 0.0) * (c.get("a_m", 0.005) + y0) / max(i0, 1e-3)
    return scalar_model(NAME, "offset_m", o0, 1e-4, -3e-3, 3e-3)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
