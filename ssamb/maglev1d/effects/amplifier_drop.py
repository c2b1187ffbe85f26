r"""``amplifier_drop``: the PWM stage loses a voltage.

Physics: the switch's on-state drop during the duty and the freewheeling diode's forward drop
during the rest, both :math:`V_d`, make the average coil voltage :math:`v = D V_{max} - V_d`
instead of :math:`D V_{max}` (knob ``drop_v``; drops add). With no current the diode does not
conduct and the voltage is not negative.

Signature: the current loop's integral action restores the current; the command rises by
:math:`V_d V_{ref}/V_{max}`, the current and the position are unchanged. Evidence: an offset of
``u`` alone (:math:`z_u^2`), none of ``i`` or ``y``.

Fit: :math:`V_d \ge 0`, started at :math:`\Delta u\,V_{max}/V_{ref}`.
"""
from __future__ import annotations

from ._common import entries, number, offset_claim, offset_evidence, scalar_model

NAME = "amplifier_drop"
REQUIRED = ("drop_v",)
OPTIONAL = ()
SIGNATURE = "an offset of the command alone, none of the coil current or the position"
SEARCHABLE = True
NEEDS_HINT = False
#: the calibrated parameter this effect is indistinguishable from
CALIBRATED_KEY = "amplifier.drop_v"
KNOB = "drop_v"


def validate(p: dict, where: str) -> dict:
    return {"drop_v": number(p, "drop_v", where, 0.0, 10.0)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["drop_v"])


def evidence(ft, alpha: float, st) -> dict:
    ev = offset_evidence(ft, alpha, ("u",), ("i", "y"))
    if ev["details"]["u"]["mean"] <= 0:
        ev.update(score=0.0, significant=False)
    ev["hints"]["offset_u_v"] = ev["details"]["u"]["mean"]
    return ev


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return offset_claim(ft, ("u",))


def model(hints: dict, record, st):
    if CALIBRATED_KEY in (getattr(st, "calibration", None) or {}):
        return f"indistinguishable from the calibrated {CALIBRATED_KEY}: the same stage"
    g = record.meta.get("constants", {}).get("v_gain", 1.0)
    return scalar_model(NAME, "drop_v", max(hints.get("offset_u_v", 0.0), 0.0) * g, 0.1, 0.0, 5.0)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
