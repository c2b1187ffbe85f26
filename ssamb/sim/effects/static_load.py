r"""``static_load``: a constant external force on the rotor.

Physics: :math:`(F_x, F_y)` added to the rotor's equations of motion (a misaligned coupling, a
process load, the weight share of a tilted rotor).

Signature: the loop's integral action holds the position, so the force shows as offsets of the
differential coil currents (and controller outputs), :math:`\Delta i = -F/k_i`, and none of the
position. Evidence: :math:`z_{d_x}^2 + z_{d_y}^2` over the axes whose offset is significant.

Fit: :math:`(F_x, F_y)` on both axes, with or without evidence: the calibrated parameters can
take a load's offset on one axis (in y the rotor's weight: mass, airgap, the DCM calibration's
offset), so that the calibrated model's residual shows no offset there; fitted together with
them, their priors hold them at their tolerances and the load takes what they had absorbed.
"""
from __future__ import annotations

import math

import numpy as np

from ...device import EffectModel, log10_p_two_sided

NAME = "static_load"
REQUIRED = ("fx_n", "fy_n")
OPTIONAL = ()
SIGNATURE = "offsets of the differential coil currents and controller outputs, none of the position"
SEARCHABLE = True
NEEDS_HINT = False
ORDER = 3


def validate(p: dict, where: str) -> dict:
    return p


def apply(e: dict, ov: dict, f_x, f_y, t, base_dir) -> None:
    f_x += float(e["fx_n"])
    f_y += float(e["fy_n"])


def evidence(ft, alpha: float, st) -> dict:
    axes, score, lp_min, det, hints = [], 0.0, 0.0, {}, {}
    for ax in ("x", "y"):
        o = ft.offsets["d_" + ax]
        lp = log10_p_two_sided(o["z"]) + math.log10(2)
        det["d_" + ax] = {"offset_a": o["mean"], "z": o["z"]}
        lp_min = min(lp_min, lp)
        if lp < math.log10(alpha):
            axes.append(ax)
            score += o["z"] ** 2
            hints["offset_d_" + ax + "_a"] = o["mean"]
    for v in ("x_meas", "y_ss"):
        det[v] = {"offset_m": ft.offsets[v]["mean"], "z": ft.offsets[v]["z"]}
    hints["axes"] = axes
    return {"score": score, "log10_p": lp_min, "significant": bool(axes), "hints": hints, "details": det}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return ft.offsets["d_x"]["z"] ** 2 + ft.offsets["d_y"]["z"] ** 2


def model(hints: dict, record, st) -> EffectModel:
    axes = ("x", "y")

    def build(t, axes=axes):
        f = dict(zip(axes, (float(v) for v in t)))
        return [{"name": NAME, "fx_n": f.get("x", 0.0), "fy_n": f.get("y", 0.0)}]
    n = len(axes)
    return EffectModel(NAME, tuple(f"f{a}_n" for a in axes), np.zeros(n), np.full(n, 1.0), np.full(n, -1e3),
                       np.full(n, 1e3), build, {"axes": axes})


def report(m: EffectModel, theta, se, significant) -> list[dict]:
    f = dict(zip(m.fixed["axes"], zip(theta, se)))
    fx, sx = f.get("x", (0.0, 0.0))
    fy, sy = f.get("y", (0.0, 0.0))
    return [{"name": NAME, "params": {"fx_n": float(fx), "fy_n": float(fy)},
             "uncertainty": {"fx_n": float(sx), "fy_n": float(sy)}}]
