r"""``amplifier_deadtime``: a dead time in every PWM switching transition.

Physics: every turn-on of the two-state bridge is delayed by :math:`t_d` (kernel parameter
``DEADTIME``): the mean coil voltage drops, and the ripple's shape changes.

Signature: a common-mode shift of all four coil currents, the same in both axes (the current loop
samples an asymmetric ripple), and the ripple's shape at the carrier's aliased harmonics in both
axes' common mode (the bias current shifts the first but not the second): either, the weaker
axis deciding.

Fit: :math:`t_d \ge 0`, from the best of a coarse grid an octave apart (a dead time of 1.5 us
moves the currents by orders of magnitude more than a finite-difference step: the response is
far from linear over the range).
"""
from __future__ import annotations

import math

import numpy as np

from ...device import EffectModel, log10_p_two_sided
from ._common import EffectError

NAME = "amplifier_deadtime"
REQUIRED = ("deadtime_s",)
OPTIONAL = ()
SIGNATURE = "common-mode shift of all four coil currents (same in both axes) and ripple distortion"
SEARCHABLE = True
NEEDS_HINT = False
ORDER = 5


def validate(p: dict, where: str) -> dict:
    if not 0 <= float(p["deadtime_s"]) < 1e-5:
        raise EffectError(f"{where}: deadtime_s must be in [0, 10 us) (got {p['deadtime_s']})")
    return p


def apply(e: dict, ov: dict, f_x, f_y, t, base_dir) -> None:
    ov["DEADTIME"] = ov.get("DEADTIME", 0.0) + float(e["deadtime_s"])


def _device_excess(ft) -> float:
    """The common-mode residual chi-square at the carrier's lines above its expectation."""
    return sum(max(ft.device[v]["chi2"] - ft.device[v]["k"], 0.0) for v in ("c_x", "c_y")) if ft.device else 0.0


def evidence(ft, alpha: float, st) -> dict:
    ox, oy = ft.offsets["c_x"], ft.offsets["c_y"]
    det = {"c_x": {"offset_a": ox["mean"], "z": ox["z"]}, "c_y": {"offset_a": oy["mean"], "z": oy["z"]}}
    same_sign = ox["z"] * oy["z"] > 0
    q = st.deadtime_ratio_max
    similar = same_sign and 1 / q <= abs(ox["mean"]) / max(abs(oy["mean"]), 1e-30) <= q
    zmin = min(abs(ox["z"]), abs(oy["z"]))
    lp_off = log10_p_two_sided(zmin) + math.log10(2) if similar else 0.0
    lp_dev = 0.0
    if ft.device:
        dx, dy = ft.device["c_x"], ft.device["c_y"]
        lp_dev = max(dx["logp"], dy["logp"]) / math.log(10.0) + math.log10(2)
        det["device_lines"] = {v: {"chi2": d["chi2"], "lines": d["k"]} for v, d in ft.device.items()}
    lp = min(lp_off, lp_dev) + math.log10(2)          # two features: Bonferroni
    sig = lp < math.log10(alpha)
    score = (ox["z"] ** 2 + oy["z"] ** 2 if similar else 0.0) + _device_excess(ft) if sig else 0.0
    det["same_sign_similar"] = bool(similar)
    return {"score": score, "log10_p": lp, "significant": sig,
            "hints": {"common_mode_a": 0.5 * (ox["mean"] + oy["mean"])}, "details": det}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return ft.offsets["c_x"]["z"] ** 2 + ft.offsets["c_y"]["z"] ** 2 + _device_excess(ft)


def model(hints: dict, record, st) -> EffectModel:
    # dead times of PWM bridges: 0.1-2 us (a grid an octave apart)
    return EffectModel(NAME, ("deadtime_s",), np.zeros(1), np.full(1, 2.5e-7), np.zeros(1), np.full(1, 9.9e-6),
                       lambda t: [{"name": NAME, "deadtime_s": float(t[0])}], {},
                       tuple(np.array([v]) for v in (0.25e-6, 0.5e-6, 1e-6, 2e-6, 4e-6)))


def report(m: EffectModel, theta, se, significant) -> list[dict]:
    return [{"name": NAME, "params": {"deadtime_s": float(theta[0])}, "uncertainty": {"deadtime_s": float(se[0])}}]
