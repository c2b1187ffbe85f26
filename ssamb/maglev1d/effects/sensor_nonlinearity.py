r"""``sensor_nonlinearity``: the position sensor's reading is not linear in the ball's position.

Physics: an optical sensor reads the light the ball takes out of a beam of finite width; the
shadow of a sphere grows with its chord across the beam, not in proportion to its travel, and the
photodiode's response is not linear either. About the centre reading :math:`c`
(``sensors.position_centre_m``) the reading is :math:`y_s = \ell + q (\ell - c)^2` with the linear
reading :math:`\ell = g_s y + o_s` (knob ``sensor_curvature_per_m``; curvatures add): the scale
:math:`dy_s/dy = g_s (1 + 2 q (\ell - c))` changes by :math:`2q` per metre of reading, and the
reading at :math:`c` and the scale there stay those of the linear sensor.

Signature: held at a reference :math:`r \ne c`, the ball floats :math:`q (r - c)^2` (in reading
units) nearer the magnet than the linear sensor puts it, and the current drops by the equilibrium
current's slope times that; the loop's gain grows with the level (:math:`g_s` times the local
scale). Both show only across levels of the reference or in swings of a millimetre or more; the
residual features carry no level, so its evidence is its held-out improvement alone (fitted when
no signature is significant and the residual is not noise).

Identifiability: a record whose reference stays at one level (range below
:data:`~ssamb.maglev1d.effects._common.MIN_SPAN_M`) has one local scale and zero, those of the
calibrated sensor: no curvature to see.

Fit: :math:`q` (1/m), from 0, a coarse grid of both signs, within the range where the reading stays
monotonic over the sensor's 0-20 mm.
"""
from __future__ import annotations

from ._common import MIN_SPAN_M, entries, number, reference_span_m, scalar_model

NAME = "sensor_nonlinearity"
REQUIRED = ("curvature_per_m",)
OPTIONAL = ()
SIGNATURE = "the current's and the loop's dependence on the level differ from the linear sensor's (across levels only)"
SEARCHABLE = True
NEEDS_HINT = False
ORDER = 110
KNOB = "sensor_curvature_per_m"
#: the curvature's range (1/m): the reading stays monotonic over 0-20 mm about a 5 mm centre
LOWER, UPPER = -30.0, 90.0


def validate(p: dict, where: str) -> dict:
    return {"curvature_per_m": number(p, "curvature_per_m", where, LOWER, UPPER)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["curvature_per_m"])


def evidence(ft, alpha: float, st) -> dict:
    return {"score": 0.0, "log10_p": 0.0, "significant": False, "hints": {},
            "details": {"reason": "the residual features carry no level: judged by its held-out improvement"}}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return 0.0


def model(hints: dict, record, st):
    span = reference_span_m(record)
    if span < MIN_SPAN_M:
        return (f"the reference stays at one level ({1e3 * span:.2g} mm range): the reading's local scale and zero "
                f"there are the calibrated sensor's, its curvature shows only across levels")
    return scalar_model(NAME, "curvature_per_m", 0.0, 5.0, LOWER, UPPER, grid=(-15.0, 30.0))


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
