r"""``unbalance``: a spinning rotor's mass unbalance.

Physics: a rotating force of magnitude :math:`m e\,\omega^2`,
:math:`F_x = m e\omega^2\cos(\omega t + \varphi)`, :math:`F_y = m e\omega^2\sin(\omega t + \varphi)`
(forward whirl).

Signature: a line at the spin frequency that the excitation lacks, in both axes' coil currents,
in quadrature (y lagging x by about 90 degrees; the x probe loop and the y self-sensing loop
differ, more so at high frequency, hence a wide tolerance). Evidence: the line's chi-square in
:math:`d_x` and :math:`d_y`.

Fit: :math:`(a, b) = m e\,(\cos\varphi, \sin\varphi)`, so that the force is linear in them, and
the spin speed, started at the line's frequency (its sensitivity is zero until the force is
nonzero, so it joins the fit after the first step).
"""
from __future__ import annotations

import math

import numpy as np

from ...device import EffectModel
from ._common import EffectError

NAME = "unbalance"
REQUIRED = ("speed_hz", "mass_ecc_kgm")
OPTIONAL = ("phase_rad",)
SIGNATURE = "a line at a frequency the excitation lacks, in both axes, in quadrature (rotating force)"
SEARCHABLE = True
NEEDS_HINT = True
ORDER = 2


def validate(p: dict, where: str) -> dict:
    if float(p["speed_hz"]) < 0 or float(p["mass_ecc_kgm"]) < 0:
        raise EffectError(f"{where}: speed_hz and mass_ecc_kgm must be >= 0")
    return p


def apply(e: dict, ov: dict, f_x, f_y, t, base_dir) -> None:
    w = 2 * math.pi * float(e["speed_hz"])
    amp = float(e["mass_ecc_kgm"]) * w * w
    ph = float(e.get("phase_rad", 0.0))
    f_x += amp * np.cos(w * t + ph)
    f_y += amp * np.sin(w * t + ph)


def evidence(ft, alpha: float, st) -> dict:
    from scipy import stats  # imported where needed: scipy.stats costs every job and workflow start ~0.7 CPU s

    best = None
    det = {"lines": []}
    for ln in ft.lines:
        ax, ay = ln["phasor"].get("d_x", 0j), ln["phasor"].get("d_y", 0j)
        cx, cy = ln["chi2"].get("d_x", 0.0), ln["chi2"].get("d_y", 0.0)
        # both axes above the noise at this line (chi2 with 2 dof, Bonferroni over lines)
        crit = float(stats.chi2.isf(alpha / max(len(ft.lines), 1) / 2, 2))
        both = cx > crit and cy > crit
        rho = ay / ax if abs(ax) > 0 else 0j
        ang = math.degrees(math.atan2(rho.imag, rho.real)) if rho != 0 else 0.0
        ratio = abs(rho)
        w = st.whirl_phase_min_deg
        quad = -180.0 + w <= ang <= -w and 1.0 / st.whirl_ratio_max <= ratio <= st.whirl_ratio_max
        entry = {"f_hz": ln["f_hz"], "chi2_d_x": cx, "chi2_d_y": cy, "y_over_x_deg": ang, "y_over_x_abs": ratio,
                 "both_axes": both, "quadrature_forward": quad}
        det["lines"].append(entry)
        if both and quad:
            sc = cx + cy
            if best is None or sc > best[0]:
                best = (sc, ln, min(cx, cy))
    if best is None:
        return {"score": 0.0, "log10_p": 0.0, "significant": False, "hints": {}, "details": det}
    sc, ln, cmin = best
    lp = -0.5 * cmin / math.log(10.0) + math.log10(max(len(ft.lines), 1))    # chi2(2): sf = exp(-x/2)
    # the speed's finite-difference step: a tenth of the frequency resolution (a phase drift of
    # 0.6 rad over the segment)
    return {"score": sc, "log10_p": lp, "significant": lp < math.log10(alpha),
            "hints": {"speed_hz": ln["f_hz"], "speed_step_hz": 0.1 * ft.frame.df_hz}, "details": det}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    """The line chi-square at the fitted speed in both axes (in any phase relation), so that a
    fit that leaves the line, or creates one in the other axis, fails."""
    f0 = hints.get("speed_hz")
    tot = 0.0
    for ln in ft.lines:
        if f0 is not None and abs(ln["f_hz"] - f0) <= 2 * df_hz:
            tot += ln["chi2"].get("d_x", 0.0) + ln["chi2"].get("d_y", 0.0)
    return tot


def model(hints: dict, record, st) -> EffectModel | str:
    if "speed_hz" not in hints:
        return "no line to start the spin speed from"
    f_hz = float(hints["speed_hz"])
    w = 2 * math.pi * f_hz

    def build(t):
        me = float(math.hypot(t[0], t[1]))
        return [{"name": NAME, "speed_hz": float(t[2]), "mass_ecc_kgm": me, "phase_rad": float(math.atan2(t[1], t[0]))}]
    s = 1.0 / (w * w)     # 1 N of force
    df = float(hints.get("speed_step_hz", 0.01))
    return EffectModel(NAME, ("me_cos_kgm", "me_sin_kgm", "speed_hz"), np.array([0.0, 0.0, f_hz]),
                       np.array([s, s, df]), np.array([-1.0, -1.0, max(f_hz - 5 * df, 0.0)]),
                       np.array([1.0, 1.0, f_hz + 5 * df]), build, {"speed_hz": f_hz},
                       size_params=("me_cos_kgm", "me_sin_kgm"))


def report(m: EffectModel, theta, se, significant) -> list[dict]:
    a, b, f_hz = theta
    me = math.hypot(a, b)
    w = 2 * math.pi * f_hz
    se_me = float(math.sqrt(0.5 * (se[0] ** 2 + se[1] ** 2)))
    return [{"name": NAME, "params": {"speed_hz": float(f_hz), "mass_ecc_kgm": float(me),
                                      "phase_rad": float(math.atan2(b, a))},
             "uncertainty": {"speed_hz": float(se[2]), "mass_ecc_kgm": se_me,
                             "phase_rad": float(se_me / max(me, 1e-300))},
             "force_n": float(me * w * w)}]
