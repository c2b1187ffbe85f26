"""What the levitated ball's effect modules share: the error type, parameter checks, the
offset and ratio tests their evidence reads, and the report entry of a fitted effect."""
from __future__ import annotations

import math
import numbers

import numpy as np

from ...device import EffectModel, log10_p_two_sided, log10_p_upper
from ...errors import InputError

__all__ = ["EffectError", "number", "offset_evidence", "ratio_evidence", "force_like_evidence", "force_like_claim",
           "delay_evidence", "delay_model", "entries", "scalar_model", "TS_S", "calibrated", "reference_span_m",
           "MIN_SPAN_M"]

#: the reference's range over the compared samples below which a record shows one operating level
MIN_SPAN_M = 5e-4

#: the controller's period: delays are fractions of a sample
TS_S = 0.01


class EffectError(InputError):
    """An effect specification is invalid; the message names the effect and the parameter."""


def number(p: dict, key: str, where: str, lo: float = -math.inf, hi: float = math.inf,
           lo_open: bool = False, hi_open: bool = False) -> float:
    """``p[key]`` as a finite float within its range; :class:`EffectError` naming it otherwise."""
    v = p[key]
    if not isinstance(v, numbers.Real) or isinstance(v, bool) or not math.isfinite(float(v)):
        raise EffectError(f"{where}: parameter '{key}' must be a finite number (got {v!r})")
    v = float(v)
    if (v <= lo if lo_open else v < lo) or (v >= hi if hi_open else v > hi):
        raise EffectError(f"{where}: parameter '{key}' must be in {'(' if lo_open else '['}{lo:g}, {hi:g}"
                          f"{')' if hi_open else ']'} (got {v!r})")
    return v


def _z(ft, view: str) -> float:
    o = (getattr(ft, "offsets", None) or {}).get(view)
    return float(o["z"]) if o else 0.0


def offset_evidence(ft, alpha: float, shifted: tuple, clean: tuple, same_sign: bool = True) -> dict:
    r"""Evidence of an effect that shifts the residual's mean in the views ``shifted`` (the loop's
    integral action keeps the others, ``clean``, at zero).

    Score: :math:`\sum_{v \in shifted} z_v^2` when every shifted view's offset is significant
    (Bonferroni over the shifted views; with ``same_sign`` all of one sign) and no clean view's
    is; zero otherwise. ``log10_p``: of the weakest shifted view.
    """
    n = len(shifted) + len(clean)
    zs = {v: _z(ft, v) for v in shifted + clean}
    lp = {v: log10_p_two_sided(z) + math.log10(max(n, 1)) for v, z in zs.items()}
    weakest = max(lp[v] for v in shifted)
    signs = {np.sign(zs[v]) for v in shifted}
    ok = (weakest < math.log10(alpha) and all(lp[v] >= math.log10(alpha) for v in clean)
          and (not same_sign or len(signs) == 1))
    score = float(sum(zs[v] ** 2 for v in shifted)) if ok else 0.0
    det = {v: {"mean": float((ft.offsets.get(v) or {}).get("mean", 0.0)), "z": zs[v]} for v in zs}
    return {"score": score, "log10_p": float(weakest), "significant": bool(ok), "hints": {}, "details": det}


def ratio_evidence(ft, alpha: float, path: str, kind: str, sign: int = 0) -> dict:
    r"""Evidence read off the measured/model ratio of a path (:attr:`Maglev1D.features.paths`):
    ``kind`` ``tau`` (a delay, :math:`\angle R = -2\pi f\tau`) or ``alpha`` (a flat log gain);
    ``sign`` +1/-1: one-sided test of that sign, 0: two-sided."""
    r = (getattr(ft, "ratios", None) or {}).get(path)
    if not r:
        return {"score": 0.0, "log10_p": 0.0, "significant": False, "hints": {},
                "details": {"reason": f"no excited lines on the path {path}"}}
    z = float(r["z_tau"] if kind == "tau" else r["z_alpha"])
    if sign:
        lp = log10_p_upper(sign * z)
    else:
        lp = log10_p_two_sided(z)
    chi = float(r["chi2_tau"] if kind == "tau" else r["chi2_alpha"])
    sig = lp < math.log10(alpha)
    det = {"path": path, "z": z, "tau_s": float(r["tau_s"]), "se_tau_s": float(r["se_tau_s"]),
           "gain": float(r["gain"]), "se_log_gain": float(r["se_alpha"]), "lines": int(r["n_lines"])}
    return {"score": chi if sig else 0.0, "log10_p": float(lp), "significant": bool(sig), "hints": {}, "details": det}


def force_like_evidence(ft, alpha: float, sign: int = 0) -> dict:
    """Evidence of an effect that changes the force balance: offsets of ``i`` and ``u`` of one
    sign (``sign`` +1/-1: only that one), none of ``y``; the offset of ``i`` as a hint."""
    ev = offset_evidence(ft, alpha, ("i", "u"), ("y",))
    if sign and sign * ev["details"]["i"]["mean"] <= 0:
        ev.update(score=0.0, significant=False)
    ev["hints"]["offset_i_a"] = ev["details"]["i"]["mean"]
    return ev


def force_like_claim(ft, hints: dict, df_hz: float, st) -> float:
    return offset_claim(ft, ("i", "u"))


def delay_evidence(ft, alpha: float, path: str) -> dict:
    """Evidence of a delay on ``path`` (one-sided lag), its slope as the hint ``delay_s``."""
    ev = ratio_evidence(ft, alpha, path, "tau", +1)
    if ev["significant"]:
        ev["hints"]["delay_s"] = ev["details"]["tau_s"]
    return ev


def delay_model(name: str, hints: dict):
    """A delay of less than a sample, started at the hint or a coarse grid."""
    return scalar_model(name, "delay_s", hints.get("delay_s", 0.0), 1e-3, 0.0, 0.99 * TS_S, grid=(2e-3, 5e-3))


def ratio_claim(ft, path: str, kind: str) -> float:
    r = (getattr(ft, "ratios", None) or {}).get(path)
    return float(r["chi2_tau" if kind == "tau" else "chi2_alpha"]) if r else 0.0


def offset_claim(ft, views: tuple) -> float:
    return float(sum(_z(ft, v) ** 2 for v in views))


def scalar_model(name: str, key: str, theta0: float, step: float, lo: float, hi: float,
                 grid: tuple = ()) -> EffectModel:
    """An effect with one parameter ``key``, fitted in its own unit."""
    th0 = float(np.clip(theta0, lo, hi))
    return EffectModel(name, (key,), np.array([th0]), np.array([step]), np.array([lo]), np.array([hi]),
                       lambda t: [{"name": name, key: float(t[0])}], {}, tuple(np.array([g]) for g in grid))


def entries(m: EffectModel, theta, se) -> list[dict]:
    """The ``closeloop.json`` entry of a fitted effect (every parameter with its standard error)."""
    return [{"name": m.name, "params": {k: float(v) for k, v in zip(m.params, theta)},
             "uncertainty": {k: float(s) for k, s in zip(m.params, se)}}]


def operating_point(record) -> tuple[float, float]:
    """Mean measured position (m) and current (A) over the record's usable part."""
    y, i = record.channels["y"], record.channels["i"]
    idx = np.concatenate([np.arange(a, b) for a, b in record.usable]) if record.usable else np.arange(len(y))
    return float(np.mean(y[idx])), float(np.mean(i[idx]))


def calibrated(st, keys) -> bool:
    """Whether every one of the dotted config ``keys`` is calibrated in the settings ``st``."""
    cal = getattr(st, "calibration", None) or {}
    return all(k in cal for k in keys)


def reference_span_m(record) -> float:
    """The range of the position reference over the record's compared samples (m)."""
    yd = record.inputs["yd"]
    idx = np.concatenate([np.arange(a, b) for a, b in record.usable]) if record.usable else np.arange(len(yd))
    return float(np.ptp(yd[idx])) if len(idx) else 0.0

