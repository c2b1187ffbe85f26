r"""``cross_coupling``: extra flux coupling between adjacent electromagnets.

Physics: a fraction :math:`c` of each electromagnet's flux links its neighbours (on top of what
the stator's reluctance network already couples; kernel parameter ``XCOUP``): one axis' currents
produce force in the other.

Signature: residual in one axis coherent with the other axis' excitation beyond its own response
(an F-test of the cross term), and an x current offset from the gravity-loaded y fluxes.

Fit: the coefficient :math:`c`, either sign, from a coarse grid over 5-20 % (the response is
nearly linear; the grid saves iterations from zero).
"""
from __future__ import annotations

import math

import numpy as np

from ...device import EffectModel

NAME = "cross_coupling"
REQUIRED = ("coefficient",)
OPTIONAL = ()
SIGNATURE = "residual in one axis coherent with the other axis' excitation; x current offset from gravity"
# at rest the coupled forces' means are a constant (F_x, F_y) that a static load gives alike in
# every channel's mean (tests/test_device.py); the y loop's noise coupled into x raises the x
# noise spectrum too, which the AMB's features do not compare
ALIASES = ("static_load",)
SEARCHABLE = True
NEEDS_HINT = False
ORDER = 6


def validate(p: dict, where: str) -> dict:
    return p


def apply(e: dict, ov: dict, f_x, f_y, t, base_dir) -> None:
    ov["XCOUP"] = ov.get("XCOUP", 0.0) + float(e["coefficient"])


def evidence(ft, alpha: float, st) -> dict:
    det, score, lp_min, dirs = {}, 0.0, 0.0, []
    for key, c in ft.cross.items():
        lp = c["logp"] / math.log(10.0) + math.log10(2 * c.get("n_views", 1))
        det[key] = {"view": c["view"], "test": c["kind"], "stat": c["stat"], "log10_p": lp}
        lp_min = min(lp_min, lp)
        if lp < math.log10(alpha):
            dirs.append(key)
            score += c.get("delta_chi2", 0.0)
    sig = bool(dirs)
    if sig:
        # the coupling of the gravity-loaded y fluxes into x shows as current offsets
        score += ft.offsets["d_x"]["z"] ** 2 + ft.offsets["d_y"]["z"] ** 2
    return {"score": score, "log10_p": lp_min, "significant": sig, "hints": {"directions": dirs}, "details": det}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return sum(c.get("delta_chi2", 0.0) for c in ft.cross.values())


def model(hints: dict, record, st) -> EffectModel:
    return EffectModel(NAME, ("coefficient",), np.zeros(1), np.full(1, 0.03), np.full(1, -0.5), np.full(1, 0.5),
                       lambda t: [{"name": NAME, "coefficient": float(t[0])}], {},
                       tuple(np.array([v]) for v in (-0.2, -0.1, -0.05, 0.05, 0.1, 0.2)))


def report(m: EffectModel, theta, se, significant) -> list[dict]:
    return [{"name": NAME, "params": {"coefficient": float(theta[0])}, "uncertainty": {"coefficient": float(se[0])}}]
