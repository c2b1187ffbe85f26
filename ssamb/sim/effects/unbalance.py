r"""``unbalance``: a spinning rotor's mass unbalance.

Physics: a rotating force of magnitude :math:`m e\,\omega^2`,
:math:`F_x = m e\omega^2\cos(\omega t + \varphi)`, :math:`F_y = m e\omega^2\sin(\omega t + \varphi)`
(forward whirl).

Signature: a line at the spin frequency that the excitation lacks, in both axes' coil currents,
in quadrature (y lagging x by about 90 degrees; the x probe loop and the y self-sensing loop
differ, more so at high frequency, hence a wide tolerance). Evidence: the line's chi-square in
:math:`d_x` and :math:`d_y`. A line above the noise in one axis only counts when the other
axis's phasor is within its noise of some whirl the tolerance allows (:func:`whirl_misfit`): an
axis the loop makes noisy (a clipped controller output beside the line, say) cannot show its
half of the whirl, but an axis that is quiet at the line rules the rotating force out.

Fit: :math:`(a, b) = m e\,(\cos\varphi, \sin\varphi)`, so that the force is linear in them, at
the spin speed the line itself measures, with the line's standard error. The replays are compared through
one phasor per line over the fitting part, in which a speed error and a phase error are nearly
one direction (only the phasor's small sinc loss tells them apart), so a speed fitted there
wanders along that valley by many times the line's own precision, and the held-out part, after
the fitting part, sees the phase drift it leaves. The line's least-squares frequency over the
same part (:func:`ssamb.closeloop.spectra.fit_line`, each view weighted by its noise near the
line, and tapered where the excitation is not periodic so that the model's misfit of it does
not pull the frequency) comes within 1.4 times the Cramer-Rao bound in white noise (1.7 tapered),
and its sandwich standard error says how far it can be trusted in coloured noise. Once the
model is final, the speed is estimated again along :func:`neighbours` (:mod:`ssamb.closeloop.speeds`:
the drift of the data's phase against the model's line, and the fitting part's whole cost with
the size solved at each speed tried), and the size's error includes the speed's.
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


def whirl_misfit(a_strong: complex, a_weak: complex, se_weak: float, strong_is_x: bool, st) -> float:
    r"""The weak axis's distance, in its noise, from the closest forward whirl the tolerances allow.

    With the ratio :math:`\rho = A_y / A_x` allowed in the sector :math:`-180^\circ + w \le
    \arg\rho \le -w`, :math:`1/r \le |\rho| \le r` (``whirl_phase_min_deg``,
    ``whirl_ratio_max``), the weak axis's phasor is predicted from the strong one's for every
    :math:`\rho` of the sector; returns :math:`\min_\rho |A_{weak} - \hat A_{weak}(\rho)|^2 /
    \sigma^2_{weak}`, a chi-square with 2 degrees of freedom when a rotating force made the line.

    Parameters
    ----------
    a_strong, a_weak : complex
        The line's phasors in the axis where it stands above the noise and in the other.
    se_weak : float
        The standard error of ``a_weak`` (per real and imaginary part).
    strong_is_x : bool
        Whether the strong axis is x (then :math:`\hat A_y = \rho A_x`, else :math:`\hat A_x =
        A_y / \rho`).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> st = SimpleNamespace(whirl_phase_min_deg=10.0, whirl_ratio_max=5.0)
    >>> round(whirl_misfit(1.0, -1j, 0.1, True, st), 6)       # y lags x by 90 deg: a whirl
    0.0
    >>> whirl_misfit(1.0, 0j, 0.01, True, st) > 100          # y quiet: no rotating force
    True
    """
    if abs(a_strong) == 0:
        return 0.0
    w = math.radians(float(st.whirl_phase_min_deg))
    r = float(st.whirl_ratio_max)
    # |A_weak - rho A_x| = |A_x| |q - rho|, q = A_y / A_x; |A_x - A_y / rho| = |A_y| |q - 1/rho|,
    # q = A_x / A_y, where 1/rho lies in the mirrored sector (angles w..180 - w)
    q = a_weak / a_strong
    lo, hi = (-math.pi + w, -w) if strong_is_x else (w, math.pi - w)
    d = _distance_to_sector(q, lo, hi, 1.0 / r, r)
    return float(abs(a_strong) ** 2 * d ** 2 / max(se_weak, 1e-300) ** 2)


def _distance_to_sector(q: complex, lo: float, hi: float, r_lo: float, r_hi: float) -> float:
    """Distance from ``q`` to the annular sector ``r_lo <= |z| <= r_hi``, ``lo <= arg z <= hi``
    (radians, ``-pi < lo < hi <= pi``): radial inside the angles, else to the nearer edge."""
    rq, th = abs(q), math.atan2(q.imag, q.real)
    if lo <= th <= hi:
        return max(r_lo - rq, rq - r_hi, 0.0)
    best = math.inf
    for phi in (lo, hi):
        u = complex(math.cos(phi), math.sin(phi))
        t = min(max((q * u.conjugate()).real, r_lo), r_hi)
        best = min(best, abs(q - t * u))
    return best


def _line_evidence(ln: dict, crit: float, st) -> tuple[dict, float | None]:
    """One line's entry in the details and its strength as a rotating force (None: not one).

    Both axes above the noise: the forward quadrature within the tolerances, the strength the
    weaker axis's chi-square. One axis above it: the other within its noise of a whirl
    (:func:`whirl_misfit` at most ``crit``), the strength the strong axis's chi-square."""
    ax, ay = ln["phasor"].get("d_x", 0j), ln["phasor"].get("d_y", 0j)
    cx, cy = ln["chi2"].get("d_x", 0.0), ln["chi2"].get("d_y", 0.0)
    rho = ay / ax if abs(ax) > 0 else 0j
    ang = math.degrees(math.atan2(rho.imag, rho.real)) if rho != 0 else 0.0
    ratio = abs(rho)
    w = st.whirl_phase_min_deg
    quad = -180.0 + w <= ang <= -w and 1.0 / st.whirl_ratio_max <= ratio <= st.whirl_ratio_max
    both = cx > crit and cy > crit
    entry = {"f_hz": ln["f_hz"], "chi2_d_x": cx, "chi2_d_y": cy, "y_over_x_deg": ang, "y_over_x_abs": ratio,
             "both_axes": both, "quadrature_forward": quad}
    if both:
        return entry, (min(cx, cy) if quad else None)
    if max(cx, cy) <= crit:
        return entry, None
    strong_is_x = cx > cy
    weak, a_weak = ("d_y", ay) if strong_is_x else ("d_x", ax)
    se = ln.get("se", {}).get(weak)
    if se is None:
        c = cy if strong_is_x else cx
        se = abs(a_weak) / math.sqrt(c) if c > 0 else math.inf
    mis = whirl_misfit(ax if strong_is_x else ay, a_weak, se, strong_is_x, st) if math.isfinite(se) else 0.0
    entry.update(one_axis="x" if strong_is_x else "y", whirl_misfit_chi2=mis)
    return entry, (max(cx, cy) if mis <= crit else None)


def evidence(ft, alpha: float, st) -> dict:
    from scipy import stats  # imported where needed: scipy.stats costs every job and workflow start ~0.7 CPU s

    best = None
    det = {"lines": []}
    # a line above the noise (chi2 with 2 dof, Bonferroni over lines)
    crit = float(stats.chi2.isf(alpha / max(len(ft.lines), 1) / 2, 2))
    for ln in ft.lines:
        entry, strength = _line_evidence(ln, crit, st)
        det["lines"].append(entry)
        if strength is not None:
            sc = entry["chi2_d_x"] + entry["chi2_d_y"]
            if best is None or sc > best[0]:
                best = (sc, ln, strength)
    if best is None:
        return {"score": 0.0, "log10_p": 0.0, "significant": False, "hints": {}, "details": det}
    sc, ln, cmin = best
    lp = -0.5 * cmin / math.log(10.0) + math.log10(max(len(ft.lines), 1))    # chi2(2): sf = exp(-x/2)
    return {"score": sc, "log10_p": lp, "significant": lp < math.log10(alpha),
            "hints": {"speed_hz": ln["f_hz"], "speed_se_hz": float(ln["f_se_hz"])},
            "details": det}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    """The line chi-square at the spin speed in both axes (in any phase relation), so that a
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
        return [{"name": NAME, "speed_hz": f_hz, "mass_ecc_kgm": me, "phase_rad": float(math.atan2(t[1], t[0]))}]
    s = 1.0 / (w * w)     # 1 N of force
    return EffectModel(NAME, ("me_cos_kgm", "me_sin_kgm"), np.array([0.0, 0.0]), np.array([s, s]),
                       np.array([-1.0, -1.0]), np.array([1.0, 1.0]), build,
                       {"speed_hz": f_hz, "speed_se_hz": float(hints.get("speed_se_hz", 0.0))},
                       size_params=("me_cos_kgm", "me_sin_kgm"))


def neighbours(m: EffectModel, theta, t_centre_s: float, steps: float | list) -> list:
    """The same unbalance at spin speeds ``steps`` (in units of the line's standard error) from
    the fitted one, its force's phase kept where the fitting part pins it (at ``t_centre_s``, the
    part's centre): ``[(model, theta)]``. The fitting part sees a speed error only through the
    phase it drifts by within the part, so the speed is searched along this family (the search's
    ``_refine_speeds``) rather than fitted beside the phasor.
    """
    f0, se = float(m.fixed["speed_hz"]), float(m.fixed.get("speed_se_hz", 0.0))
    if se <= 0:
        return []
    me, ph = math.hypot(theta[0], theta[1]), math.atan2(theta[1], theta[0])
    out = []
    for k in np.atleast_1d(steps):
        f = f0 + float(k) * se
        if f <= 0:
            continue
        m2 = model({"speed_hz": f, "speed_se_hz": se}, None, None)
        p2 = ph - 2 * math.pi * (f - f0) * t_centre_s
        out.append((m2, np.array([me * math.cos(p2), me * math.sin(p2)])))
    return out


def report(m: EffectModel, theta, se, significant) -> list[dict]:
    r"""The unbalance in the library's terms, with standard errors. The phase is the force's at
    the record's start, :math:`t = 0`, while the data pin it at ``fixed["phase_t_s"]`` (the
    fitting part's centre, where the search's speed refinement holds it): a speed error
    :math:`\sigma_f` moves it by :math:`2\pi t\,\sigma_f` there, which its error includes."""
    a, b = theta[:2]
    f_hz = float(m.fixed["speed_hz"])
    me = math.hypot(a, b)
    w = 2 * math.pi * f_hz
    se_at_speed = float(math.sqrt(0.5 * (se[0] ** 2 + se[1] ** 2)))
    se_me = float(math.hypot(se_at_speed, float(m.fixed.get("size_se_speed", 0.0))))
    se_f = float(m.fixed.get("speed_se_hz", 0.0))
    se_ph = math.hypot(se_at_speed / max(me, 1e-300), 2 * math.pi * float(m.fixed.get("phase_t_s", 0.0)) * se_f)
    return [{"name": NAME, "params": {"speed_hz": float(f_hz), "mass_ecc_kgm": float(me),
                                      "phase_rad": float(math.atan2(b, a))},
             "uncertainty": {"speed_hz": se_f, "mass_ecc_kgm": se_me, "phase_rad": float(se_ph)},
             "force_n": float(me * w * w)}]
