"""Assemble ``closeloop.json`` (ARCHITECTURE.md, binding; keys are only ever added).

Binding keys: ``effects`` (ordered by how much each explains, most first; each with ``name``,
``params``, ``error_reduction``, ``evidence``), ``unexplained``, ``error_before``,
``error_after`` (held-out errors of ``x_meas``, ``y_meas``, ``y_ss`` and ``currents``, each
``rms`` and ``fit_pct``) and ``validation.fit_fraction``. Added keys: per-effect
``uncertainty`` and ``fit``; ``remaining_signature`` (what is left when the residual is not
consistent with noise), ``evidence`` (the ranking before any fitting), ``rounds`` (every
candidate tried and why it was accepted or rejected), ``noise``, ``data``, ``timing``.
"""
from __future__ import annotations

import math

import numpy as np

from .data import VIEWS, views
from .residual import channel_errors

__all__ = ["build_report"]


def _clean(o):
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, np.ndarray):
        return _clean(o.tolist())
    if isinstance(o, np.generic):
        return _clean(o.item())
    if isinstance(o, complex):
        return {"abs": abs(o), "angle_rad": math.atan2(o.imag, o.real)}
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def _error_reduction(meas_v, models_v, hold, sigma0) -> list[float]:
    """Per accepted effect: the share of the nominal held-out residual excess it removed.

    For every view clearly above the noise in the nominal replay (mean square over twice the
    noise power), ``(ms_before - ms_after) / (ms_nominal - sigma^2)``, averaged over those views.
    """
    ms = [{v: float(np.mean((meas_v[v][hold] - m[v][hold]) ** 2)) for v in VIEWS} for m in models_v]
    above = [v for v in VIEWS if ms[0][v] > 2 * sigma0[v] ** 2]
    out = []
    for k in range(1, len(models_v)):
        if not above:
            out.append(0.0)
            continue
        red = float(np.mean([(ms[k - 1][v] - ms[k][v]) / (ms[0][v] - sigma0[v] ** 2) for v in above]))
        out.append(min(red, 1.0))        # at the noise the estimate scatters around 1
    return out


def _remaining(failures: list, limit: int = 12) -> dict:
    """Summary of the tests the final residual fails, strongest first per test."""
    by = {}
    for f in failures:
        by.setdefault(f["test"], []).append(f)
    out = {}
    for test, lst in by.items():
        key = {"offset": lambda f: -abs(f["z"]), "residual_at_excited_lines": lambda f: f["p"],
               "line_not_excited": lambda f: -max(f["amplitude"].values()), "ripple_distortion": lambda f: f["p"],
               "whiteness": lambda f: f["p"]}[test]
        out[test] = sorted(lst, key=key)[:limit]
    return out


def build_report(rec, split, nominal: dict, search, settings, source: str, timing: dict) -> dict:
    """The ``closeloop.json`` dictionary."""
    meas_v = views(rec.channels)
    hold = split.hold
    # noise levels from the final residual: effects inflate the floor of the nominal residual
    # (their intermodulation lines fill the off-grid bins), the final residual is the cleanest
    ft_n = search.final_features or search.nominal_features
    sig0 = ft_n.sigma if ft_n is not None else {v: 0.0 for v in VIEWS}
    sig_ch = ft_n.sigma_ch if ft_n is not None else {}
    models = [views(nominal)] + [views(a["model"]) for a in search.accepted]
    red = _error_reduction(meas_v, models, hold, sig0)
    effects = []
    for a, r in zip(search.accepted, red):
        fr = a["fit"]
        for e in a["entries"]:
            effects.append({
                "name": e["name"], "params": e["params"], "uncertainty": e.get("uncertainty", {}),
                "error_reduction": r,
                "evidence": a["evidence"].to_json(),
                "fit": {"parameters": dict(zip(fr.model.params, fr.theta.tolist())),
                        "standard_errors": dict(zip(fr.model.params, fr.se.tolist())),
                        "identifiable": dict(zip(fr.model.params, fr.identifiable.tolist())),
                        "fit_cost_ratio": fr.cost / fr.cost0 if fr.cost0 > 0 else 1.0,
                        "delta_bic": fr.delta_bic, "holdout_z": a["holdout"]["z"],
                        "explained_at_acceptance": a["holdout"]["explained"], "simulations": fr.sims,
                        "round": a["round"],
                        "without_signature": bool(search.rounds[a["round"]].get("fallback"))},
                **{k: v for k, v in e.items() if k not in ("name", "params", "uncertainty")},
            })
    effects.sort(key=lambda e: -e["error_reduction"])

    def errs(model):
        ce = channel_errors(rec.channels, model, hold, sig_ch or None)
        for c, d in ce.items():
            if "noise_rms" in d:
                d["above_noise"] = bool(d["rms"] > 2 * d["noise_rms"])
        return ce

    fs = rec.fs_hz
    rep = {
        "effects": effects,
        "unexplained": not search.consistent,
        "error_before": errs(nominal),
        "error_after": errs(search.final),
        "validation": {
            "fit_fraction": split.fit_fraction,
            "fit_s": [split.i0 / fs, split.i_fit / fs], "holdout_s": [split.i_fit / fs, split.i_end / fs],
            "discarded_s": split.i0 / fs, "whole_periods": split.n_period is not None,
            "period_s": None if split.n_period is None else split.n_period / fs,
            "errors_on": "held-out part",
        },
        "consistent_with_noise": search.consistent,
        "remaining_signature": _remaining(search.failures) if not search.consistent else {},
        "evidence": search.rounds[0]["evidence"] if search.rounds else {},
        "ranking": search.rounds[0]["ranking"] if search.rounds else [],
        "rounds": [{"round": r["round"], "ranking": r["ranking"], "candidates": r["candidates"],
                    "without_signature": bool(r.get("fallback"))} for r in search.rounds],
        "noise": {"views": sig0, "channels": sig_ch},
        "data": {"source": source, "duration_s": rec.duration_s, "fs_hz": fs, "excitation": rec.excitation,
                 "excited_axes": list(rec.excited_axes), "start": rec.start},
        "timing": timing,
        "settings": {k: getattr(settings, k) for k in settings.__dataclass_fields__},
    }
    notes = []
    for ax in ("x", "y"):
        if ax not in rec.excited_axes:
            notes.append(f"axis {ax} is not excited: a sensor gain or delay on it leaves no trace in these data")
    for e in effects:
        if e["fit"]["without_signature"]:
            notes.append(f"{e['name']}: no signature was significant before fitting (round {e['fit']['round']}); "
                         "it was found by fitting each library effect and rests on the held-out error alone")
        for p, ok in e["fit"]["identifiable"].items():
            if not ok:
                notes.append(f"{e['name']}: parameter {p} is not identifiable from these data (no sensitivity)")
    rep["notes"] = notes
    if rep["unexplained"] and not effects:
        rep["summary"] = "no library effect explains the residual; it is not consistent with noise (see remaining_signature)"
    elif rep["unexplained"]:
        rep["summary"] = (f"found {', '.join(e['name'] for e in effects)}; a residual that no library effect explains remains "
                          "(see remaining_signature)")
    elif effects:
        rep["summary"] = f"found {', '.join(e['name'] for e in effects)}; the held-out residual is consistent with noise"
    else:
        rep["summary"] = "no effect beyond noise: the nominal model explains the data"
    return _clean(rep)

