r"""``current_offset``: the current reading is offset.

Physics: the ADC reads :math:`i + o` (knob ``current_offset_a``; offsets add): the shunt
amplifier's or the ADC's offset (the rig's logs read 7-10 counts with no current flowing).

Signature: the current loop makes the reading follow the demand, so the true current, which the
force balance fixes, is :math:`o` lower than the reading: the reading is offset by :math:`o`, the
command (set by the true current) and the position are not. Evidence: an offset of ``i``
alone, none of ``u`` or ``y``.

Fit: :math:`o`, started at the offset of ``i``.

Identifiability: with the stage's drop and the sensor's zero calibrated, not at all. The true
current is :math:`o` below the reading, so the command's offset moves by :math:`R o V_{ref}/V_{max}`
-- what a different drop does -- and the reading at every level by :math:`o` -- what a moved sensor
zero does (the equilibrium current is linear in the reading); what remains, the force's gain
:math:`2mg/i` off by :math:`o/i`, the calibrated force constant and scale take up. A recalibrated
model without it reproduces a replay with it within the noise
(``tests/test_maglev1d_effects.py``).
"""
from __future__ import annotations

from ._common import calibrated, entries, number, offset_claim, offset_evidence, scalar_model

NAME = "current_offset"
REQUIRED = ("offset_a",)
OPTIONAL = ()
SIGNATURE = "an offset of the coil current alone, none of the command or the position"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "current_offset_a"
#: the calibrated parameters that absorb it
CONFOUNDED = ("amplifier.drop_v", "sensors.position_offset_m")


def validate(p: dict, where: str) -> dict:
    return {"offset_a": number(p, "offset_a", where, -1.0, 1.0)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["offset_a"])


def evidence(ft, alpha: float, st) -> dict:
    ev = offset_evidence(ft, alpha, ("i",), ("u", "y"))
    ev["hints"]["offset_a"] = ev["details"]["i"]["mean"]
    return ev


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return offset_claim(ft, ("i",))


def model(hints: dict, record, st):
    if calibrated(st, CONFOUNDED):
        return ("indistinguishable from the calibrated amplifier.drop_v and sensors.position_offset_m: a current "
                "reading offset moves the command as the stage's drop does and the current at every level as the "
                "sensor's zero does; the force's gain, a few per cent off, goes into the calibrated force constant "
                "and scale")
    return scalar_model(NAME, "offset_a", hints.get("offset_a", 0.0), 2e-3, -0.1, 0.1)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
