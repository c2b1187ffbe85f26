r"""Signatures: what residual each library effect predicts, and the evidence for it.

Each effect of the library states the signature it leaves in the residual of the nominal
model, and scores the evidence for that signature in the features of
:mod:`ssamb.closeloop.residual` **before any fitting**. Scores share one currency, the part of
the residual's :math:`\chi^2` (squared residual over its noise floor) that the signature
accounts for, so that candidates are comparable and ranked:

==================== ======================================================= ================================
effect               predicted signature                                      evidence (explained chi^2)
==================== ======================================================= ================================
sensor_delay         sensor-path ratio with a phase lag linear in frequency,   :math:`(\hat\tau/\sigma_\tau)^2`
                     :math:`\angle R = -2\pi f\tau`, gain flat at 1 (y: the    per axis
                     self-sensing estimate against the evaluation sensor)
sensor_gain          sensor-path ratio with a flat gain :math:`\ne 1`, no      :math:`(\hat\alpha/\sigma_\alpha)^2`
                     phase (the loop's integral action hides it from the      per axis
                     position offset; it shows in the excited response)
static_load          offsets of the differential coil currents and controller  :math:`z_{d_x}^2 + z_{d_y}^2`
                     outputs, :math:`\Delta i = -F/k_i`, none of the position
unbalance            a line at the spin frequency the excitation lacks, in     line :math:`\chi^2` in
                     both axes, in quadrature (y lagging x: a forward-         :math:`d_x, d_y`
                     rotating force :math:`m e\omega^2`)
amplifier_deadtime   a common-mode shift of all four coil currents, the same   :math:`z_{c_x}^2 + z_{c_y}^2`
                     in both axes (the current loop samples an asymmetric      plus the carrier lines'
                     ripple), and the ripple's shape at the carrier's aliased  chi-square excess
                     harmonics in both axes' common mode
cross_coupling       residual in one axis coherent with the other axis'        F-test of the cross term, plus
                     excitation beyond its own response, and an x current      the offsets it implies
                     offset from the gravity-loaded y fluxes
==================== ======================================================= ================================

An effect is a candidate when its feature is significant at ``alpha_evidence`` (Bonferroni
over the effects and, inside, over axes or views).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..io import plain
from .residual import Features

__all__ = ["Evidence", "SIGNATURES", "LIBRARY", "evidence_all", "rank", "claim_stat"]

#: the effect library the analysis can name (ARCHITECTURE.md; ``external_force`` is for tests)
LIBRARY = ("sensor_delay", "unbalance", "static_load", "sensor_gain", "amplifier_deadtime", "cross_coupling")

SIGNATURES = {
    "sensor_delay": "phase lag of the sensor path linear in frequency (slope -2 pi tau), gain flat at 1",
    "sensor_gain": "flat gain ratio of the sensor path (measured/model) different from 1, no phase",
    "static_load": "offsets of the differential coil currents and controller outputs, none of the position",
    "unbalance": "a line at a frequency the excitation lacks, in both axes, in quadrature (rotating force)",
    "amplifier_deadtime": "common-mode shift of all four coil currents (same in both axes) and ripple distortion",
    "cross_coupling": "residual in one axis coherent with the other axis' excitation; x current offset from gravity",
}


@dataclass
class Evidence:
    """Evidence for one effect.

    Attributes
    ----------
    name : str
    score : float
        Explained :math:`\\chi^2` (0 when the signature is absent).
    log10_p : float
        log10 of the (Bonferroni-corrected) p-value of the signature's feature.
    significant : bool
    hints : dict
        What the features say about the parameters (axes, delays, gains, spin speed, ...).
    details : dict
        The numbers behind the score.
    """

    name: str
    score: float
    log10_p: float
    significant: bool
    hints: dict = field(default_factory=dict)
    details: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"score_chi2": self.score, "log10_p": self.log10_p, "significant": self.significant,
                "signature": SIGNATURES[self.name], "hints": plain(self.hints), "details": plain(self.details)}


def _log10_norm2(z: float) -> float:
    """log10 of the two-sided normal p-value of ``z``."""
    return float(stats.norm.logsf(abs(z)) + math.log(2.0)) / math.log(10.0)


def _log10_norm1(z: float) -> float:
    """log10 of the one-sided (upper) normal p-value of ``z``."""
    return float(stats.norm.logsf(z)) / math.log(10.0)


def _ratio_path(ft: Features, axis: str, st) -> dict | None:
    """The ratio that isolates the sensor of an axis.

    y: the self-sensing estimate over the evaluation sensor (plant changes cancel), unless that
    path is much less precise than the estimate over the coil current (an excitation that moves
    the rotor little, like current pulses, leaves both position sensors near their noise).
    """
    if axis == "y":
        a, b = ft.ratios.get("y_sensor"), ft.ratios.get("y")
        if a is None or b is None:
            return a or b
        return a if (a["n_lines"] >= st.ratio_path_min_lines and a["se_tau_s"] <= st.ratio_path_se_factor * b["se_tau_s"]) else b
    return ft.ratios.get("x")


def _sensor(ft: Features, alpha: float, kind: str, st) -> Evidence:
    name = "sensor_delay" if kind == "tau" else "sensor_gain"
    axes, score, lp_min, det, hints = [], 0.0, 0.0, {}, {}
    n_tests = 2
    for ax in ("x", "y"):
        r = _ratio_path(ft, ax, st)
        if r is None:
            continue
        if kind == "tau":
            z = r["z_tau"]
            lp = _log10_norm1(z) + math.log10(n_tests)
            det[ax] = {"tau_s": r["tau_s"], "se_s": r["se_tau_s"], "z": z, "path": r["path"], "lines": r["n_lines"],
                       "chi2_per_dof_phase": r["chi2_phase"] / max(r["dof"], 1)}
            chi = r["chi2_tau"]
        else:
            z = r["z_alpha"]
            lp = _log10_norm2(z) + math.log10(n_tests)
            det[ax] = {"gain": r["gain"], "se_log_gain": r["se_alpha"], "z": z, "path": r["path"],
                       "lines": r["n_lines"], "chi2_per_dof_gain": r["chi2_gain"] / max(r["dof"], 1)}
            chi = r["chi2_alpha"]
        lp_min = min(lp_min, lp)
        if lp < math.log10(alpha):
            axes.append(ax)
            score += chi
            hints[("delay_" if kind == "tau" else "gain_") + ax] = r["tau_s"] if kind == "tau" else r["gain"]
    hints["axes"] = axes
    return Evidence(name, score, lp_min, bool(axes), hints, det)


def _static_load(ft: Features, alpha: float, st) -> Evidence:
    axes, score, lp_min, det, hints = [], 0.0, 0.0, {}, {}
    for ax in ("x", "y"):
        o = ft.offsets["d_" + ax]
        lp = _log10_norm2(o["z"]) + math.log10(2)
        det["d_" + ax] = {"offset_a": o["mean"], "z": o["z"]}
        lp_min = min(lp_min, lp)
        if lp < math.log10(alpha):
            axes.append(ax)
            score += o["z"] ** 2
            hints["offset_d_" + ax + "_a"] = o["mean"]
    for v in ("x_meas", "y_ss"):
        det[v] = {"offset_m": ft.offsets[v]["mean"], "z": ft.offsets[v]["z"]}
    hints["axes"] = axes
    return Evidence("static_load", score, lp_min, bool(axes), hints, det)


def _deadtime(ft: Features, alpha: float, st) -> Evidence:
    """A common-mode shift of both axes' coil currents, alike, and the ripple's shape changed at
    the carrier's own lines in both axes' common mode (the bias current shifts the first but
    not the second): either, the weaker axis deciding."""
    ox, oy = ft.offsets["c_x"], ft.offsets["c_y"]
    det = {"c_x": {"offset_a": ox["mean"], "z": ox["z"]}, "c_y": {"offset_a": oy["mean"], "z": oy["z"]}}
    same_sign = ox["z"] * oy["z"] > 0
    q = st.deadtime_ratio_max
    similar = same_sign and 1 / q <= abs(ox["mean"]) / max(abs(oy["mean"]), 1e-30) <= q
    zmin = min(abs(ox["z"]), abs(oy["z"]))
    lp_off = _log10_norm2(zmin) + math.log10(2) if similar else 0.0
    lp_dev = 0.0
    if ft.device:
        dx, dy = ft.device["c_x"], ft.device["c_y"]
        lp_dev = max(dx["logp"], dy["logp"]) / math.log(10.0) + math.log10(2)
        det["device_lines"] = {v: {"chi2": d["chi2"], "lines": d["k"]} for v, d in ft.device.items()}
    lp = min(lp_off, lp_dev) + math.log10(2)          # two features: Bonferroni
    sig = lp < math.log10(alpha)
    score = (ox["z"] ** 2 + oy["z"] ** 2 if similar else 0.0) + _device_excess(ft) if sig else 0.0
    det["same_sign_similar"] = bool(similar)
    return Evidence("amplifier_deadtime", score, lp, sig, {"common_mode_a": 0.5 * (ox["mean"] + oy["mean"])}, det)


def _device_excess(ft: Features) -> float:
    """The common-mode residual chi-square at the carrier's lines above its expectation."""
    return sum(max(ft.device[v]["chi2"] - ft.device[v]["k"], 0.0) for v in ("c_x", "c_y")) if ft.device else 0.0


def _cross(ft: Features, alpha: float, st) -> Evidence:
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
    return Evidence("cross_coupling", score, lp_min, sig, {"directions": dirs}, det)


def _unbalance(ft: Features, alpha: float, st) -> Evidence:
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
        # forward whirl: y lags x by 90 deg for equal loops; the x (probe) and y (self-sensing)
        # loops differ, more so at high frequency, hence the wide tolerance
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
        return Evidence("unbalance", 0.0, 0.0, False, {}, det)
    sc, ln, cmin = best
    lp = -0.5 * cmin / math.log(10.0) + math.log10(max(len(ft.lines), 1))    # chi2(2): sf = exp(-x/2)
    # the speed's finite-difference step: a tenth of the frequency resolution (a phase drift of
    # 0.6 rad over the segment)
    return Evidence("unbalance", sc, lp, lp < math.log10(alpha),
                    {"speed_hz": ln["f_hz"], "speed_step_hz": 0.1 * ft.frame.df_hz}, det)


_FUNCS = {"sensor_delay": lambda ft, a, st: _sensor(ft, a, "tau", st),
          "sensor_gain": lambda ft, a, st: _sensor(ft, a, "alpha", st),
          "static_load": _static_load, "unbalance": _unbalance, "amplifier_deadtime": _deadtime,
          "cross_coupling": _cross}


def evidence_all(ft: Features, settings) -> dict:
    """Evidence for every library effect (``settings.alpha_evidence`` is shared by the effects:
    Bonferroni; the signature thresholds are the settings' own)."""
    a = settings.alpha_evidence / len(LIBRARY)
    return {name: _FUNCS[name](ft, a, settings) for name in LIBRARY}


def rank(ev: dict) -> list[str]:
    """Effects with significant evidence, strongest first."""
    return [e.name for e in sorted(ev.values(), key=lambda e: -e.score) if e.significant]


def claim_stat(name: str, ft: Features, hints: dict, df_hz: float, settings) -> float:
    """The explained chi^2 of an effect's own feature in ``ft`` (used before and after its fit).

    For the unbalance it is the line chi^2 at the fitted speed in both axes (in any phase
    relation), so that a fit that leaves the line, or creates one in the other axis, fails.
    """
    if name == "unbalance":
        f0 = hints.get("speed_hz")
        tot = 0.0
        for ln in ft.lines:
            if f0 is not None and abs(ln["f_hz"] - f0) <= 2 * df_hz:
                tot += ln["chi2"].get("d_x", 0.0) + ln["chi2"].get("d_y", 0.0)
        return tot
    if name in ("sensor_delay", "sensor_gain"):
        tot = 0.0
        for ax in ("x", "y"):
            r = _ratio_path(ft, ax, settings)
            if r is not None:
                tot += r["chi2_tau"] if name == "sensor_delay" else r["chi2_alpha"]
        return tot
    if name == "static_load":
        return ft.offsets["d_x"]["z"] ** 2 + ft.offsets["d_y"]["z"] ** 2
    if name == "amplifier_deadtime":
        return ft.offsets["c_x"]["z"] ** 2 + ft.offsets["c_y"]["z"] ** 2 + _device_excess(ft)
    if name == "cross_coupling":
        return sum(c.get("delta_chi2", 0.0) for c in ft.cross.values())
    raise KeyError(name)
