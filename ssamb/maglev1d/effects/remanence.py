r"""``remanence``: the core keeps part of its magnetisation.

Physics: a soft-iron core pulled to saturation and closed by the ball (the ball stuck to the
magnet) keeps a remanent magnetisation, an MMF acting like a current :math:`i_r` in the coil:
:math:`F = \tfrac12 (i + i_r)^2 |dL/dy|`, and its flux linkage moves with the gap (knob
``remanence_a``; equivalent currents add). It is what holds a ball to the face with no current
and lets it go slowly.

Signature: the coil needs :math:`i_r` less current to hold the ball (at every level), so the
current and the command shift down together; the position is held; the force's gain
:math:`\partial F/\partial i = 2mg/(i + i_r)` drops with it (a flat gain below 1 of ``y/i``).
Evidence: negative offsets of ``i`` and ``u``, none of ``y``.

Fit: :math:`i_r`, started at minus the offset of ``i``.

Identifiability: with the sensor's zero, scale and the force constant calibrated, not at all: the
current drops by :math:`i_r` at every level, as it does when the sensor's zero moves by
:math:`i_r` over the equilibrium current's slope (linear in the reading), and the force's gain
:math:`2mg/(i + i_r)` against the measured :math:`i` is a change of the loop's gain the calibrated
constant and scale take up. A recalibrated model without it reproduces a replay with it within
the noise (``tests/test_maglev1d_effects.py``).
"""
from __future__ import annotations

from ._common import calibrated, entries, force_like_claim, force_like_evidence, number, scalar_model

NAME = "remanence"
REQUIRED = ("mmf_a",)
OPTIONAL = ()
SIGNATURE = "negative offsets of the coil current and the command, constant over levels, none of the position"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "remanence_a"
#: the calibrated parameters that absorb it
CONFOUNDED = ("sensors.position_offset_m", "sensors.position_gain", "magnet.k_h")


def validate(p: dict, where: str) -> dict:
    return {"mmf_a": number(p, "mmf_a", where, -1.0, 1.0)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["mmf_a"])


def evidence(ft, alpha: float, st) -> dict:
    return force_like_evidence(ft, alpha, -1)


claim = force_like_claim


def model(hints: dict, record, st):
    if calibrated(st, CONFOUNDED):
        return ("indistinguishable from the calibrated sensors.position_offset_m (with magnet.k_h and "
                "sensors.position_gain): a remanent MMF lowers the current at every level as a moved sensor zero does, "
                "and its change of the force's gain goes into the calibrated force constant and scale")
    return scalar_model(NAME, "mmf_a", -hints.get("offset_i_a", 0.0), 0.01, -0.3, 0.5)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
