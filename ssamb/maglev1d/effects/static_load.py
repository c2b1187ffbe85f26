r"""``static_load``: a constant extra force on the ball.

Physics: :math:`f` (N, along :math:`+y`, i.e. downwards, adding to the weight) in
:math:`m\ddot y = m g + f - F` (knob ``extra_force_n``; forces of several effects add): a
magnetised neighbour, a cable, a ball heavier than documented.

Signature: the position loop's integral action holds the position; the current rises by
:math:`\Delta i = f\,i_0/(2 m g)` (:math:`\partial F/\partial i = 2F/i`) and the command with it.
Evidence: offsets of ``i`` and ``u`` of one sign, none of ``y`` (:math:`z_i^2 + z_u^2`).

Fit: :math:`f`, started at :math:`2 m g\,\Delta i / i_0`.
"""
from __future__ import annotations

from ._common import entries, force_like_claim, force_like_evidence, number, operating_point, scalar_model

NAME = "static_load"
REQUIRED = ("fy_n",)
OPTIONAL = ()
SIGNATURE = "offsets of the coil current and the command of one sign, none of the position"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "extra_force_n"


def validate(p: dict, where: str) -> dict:
    return {"fy_n": number(p, "fy_n", where, -10.0, 10.0)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["fy_n"])


def evidence(ft, alpha: float, st) -> dict:
    return force_like_evidence(ft, alpha, 0)


claim = force_like_claim


def model(hints: dict, record, st):
    c = record.meta.get("constants", {})
    _, i0 = operating_point(record)
    f0 = 2.0 * c.get("weight_n", 0.18) * hints.get("offset_i_a", 0.0) / max(i0, 1e-3)
    return scalar_model(NAME, "fy_n", f0, 5e-3, -0.2, 0.2)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
