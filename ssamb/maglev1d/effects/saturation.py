r"""``saturation``: the core saturates, the force grows slower than :math:`i^2`.

Physics: :math:`F = F_{law}(y, i)/(1 + c\,i^2)` (knob ``saturation_per_a2``; coefficients add):
the iron's permeability falls as the flux density rises, so the force at a current is lower
than the reluctance law's, the more so the higher the current.

Signature: to hold the ball the current rises by :math:`\Delta i \approx c\,i_0^3/2` (and the
command with it), growing steeply with the operating current; the position is held. Evidence:
positive offsets of ``i`` and ``u``, none of ``y``.

Fit: :math:`c \ge 0`, started at :math:`2\Delta i/i_0^3`.

Identifiability: only across operating levels. At one level a saturating core needs more current,
as a smaller force constant does, and its lower force gain :math:`\partial F/\partial i` is a change
the calibrated constant and scale take up; the two differ in how the extra current grows with the
level (:math:`c\,i^2`), which a record whose reference stays at one level (range below
:data:`~ssamb.maglev1d.effects._common.MIN_SPAN_M`) does not show.
"""
from __future__ import annotations

from ._common import (MIN_SPAN_M, calibrated, entries, force_like_claim, force_like_evidence, number,
                      operating_point, reference_span_m, scalar_model)

NAME = "saturation"
REQUIRED = ("coefficient_per_a2",)
OPTIONAL = ()
SIGNATURE = "positive offsets of the coil current and the command growing with the current cubed, none of the position"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "saturation_per_a2"


def validate(p: dict, where: str) -> dict:
    return {"coefficient_per_a2": number(p, "coefficient_per_a2", where, 0.0, 10.0)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] += float(e["coefficient_per_a2"])


def evidence(ft, alpha: float, st) -> dict:
    return force_like_evidence(ft, alpha, 1)


claim = force_like_claim


def model(hints: dict, record, st):
    if calibrated(st, ("magnet.k_h",)) and reference_span_m(record) < MIN_SPAN_M:
        return (f"the reference stays at one level ({1e3 * reference_span_m(record):.2g} mm range): there a saturating "
                f"core is a smaller calibrated magnet.k_h; the two differ only in how the current grows across levels")
    _, i0 = operating_point(record)
    c0 = 2.0 * max(hints.get("offset_i_a", 0.0), 0.0) / max(i0, 1e-3) ** 3
    return scalar_model(NAME, "coefficient_per_a2", c0, 0.05, 0.0, 3.0)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
