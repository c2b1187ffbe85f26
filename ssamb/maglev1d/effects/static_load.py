r"""``static_load``: a constant extra force on the ball.

Physics: :math:`f` (N, along :math:`+y`, i.e. downwards, adding to the weight) in
:math:`m\ddot y = m g + f - F` (knob ``extra_force_n``; forces of several effects add): a
magnetised neighbour, a cable, a ball heavier than documented.

Signature: the position loop's integral action holds the position; the current rises by
:math:`\Delta i = f\,i_0/(2 m g)` (:math:`\partial F/\partial i = 2F/i`) and the command with it.
Evidence: offsets of ``i`` and ``u`` of one sign, none of ``y`` (:math:`z_i^2 + z_u^2`).

Fit: :math:`f`, started at :math:`2 m g\,\Delta i / i_0`.

Identifiability: with the force constant, the sensor's scale and zero calibrated, not at all. The
load multiplies the force to carry by :math:`\lambda = 1 + f/(m g)`; in the reading's units the
linearised ball has the unstable pole :math:`p^2 = 2 \lambda g g_s/(A + y_s)` and the force's
gain :math:`b = 2 \lambda g g_s/i_0`, and holds at :math:`i_0 = \sqrt\lambda (A + y_s)/(g_s c)`
(:math:`A = a g_s - o_s`, :math:`c = \sqrt{k a/(2 m g)}`): exactly those of the rig without the
load with the scale :math:`\lambda g_s`, the force constant :math:`k/\lambda^3` and the zero that
keeps :math:`A`. Only the coil's motion term differs, by a fraction of a small term. A
recalibrated model without it reproduces a replay with it within the noise
(``tests/test_maglev1d_effects.py``).
"""
from __future__ import annotations

from ._common import (calibrated, entries, force_like_claim, force_like_evidence, number, operating_point,
                      scalar_model)

NAME = "static_load"
REQUIRED = ("fy_n",)
OPTIONAL = ()
SIGNATURE = "offsets of the coil current and the command of one sign, none of the position"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "extra_force_n"
#: the calibrated parameters that absorb it
CONFOUNDED = ("magnet.k_h", "sensors.position_gain", "sensors.position_offset_m")


def validate(p: dict, where: str) -> dict:
    return {"fy_n": number(p, "fy_n", where, -10.0, 10.0)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["fy_n"])


def evidence(ft, alpha: float, st) -> dict:
    return force_like_evidence(ft, alpha, 0)


claim = force_like_claim


def model(hints: dict, record, st):
    if calibrated(st, CONFOUNDED):
        return ("indistinguishable from the calibrated magnet.k_h, sensors.position_gain and "
                "sensors.position_offset_m: an extra force f makes the linearised ball that of a rig with the "
                "reading's scale 1 + f/mg times larger and the force constant (1 + f/mg)^3 times smaller (same "
                "unstable pole, force gain and current)")
    c = record.meta.get("constants", {})
    _, i0 = operating_point(record)
    f0 = 2.0 * c.get("weight_n", 0.18) * hints.get("offset_i_a", 0.0) / max(i0, 1e-3)
    return scalar_model(NAME, "fy_n", f0, 5e-3, -0.2, 0.2)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
