"""Assemble ``closeloop.json`` (its format is a stable interface, docs/formats.md; keys are only ever added).

Binding keys: ``effects`` (ordered by how much each explains, most first; each with ``name``,
``params``, ``error_reduction``, ``evidence``), ``unexplained``, ``error_before``,
``error_after`` (held-out errors of ``x_meas``, ``y_meas``, ``y_ss`` and ``currents``, each
``rms`` and ``fit_pct``), ``validation.fit_fraction``, ``parameters`` (calibrated nominal
parameters the data identify, keyed by dotted config key: ``value``, ``se``, ``nominal``,
``relative_change``, ``identifiable``) and ``not_identifiable`` (key -> reason). Added keys:
per-effect ``uncertainty``, ``fit`` and ``rivals`` (the effects the data cannot tell from it,
:func:`ssamb.closeloop.search.champion`); ``calibration`` (every calibratable parameter's
estimate, tolerance and verdict, the sensitivity matrix's rank, condition and identified
combinations, the error the calibration alone removes; with ``averaged_over``, the rejected
candidates whose fits widened the errors, each parameter's ``se_within_model`` beside them);
``remaining_signature`` (what is left
when the residual is not consistent with noise), ``evidence`` (the ranking before any fitting),
``rounds`` (every candidate tried and why it was accepted or rejected), ``noise``, ``data``,
``timing``, ``misfit`` (the final model's held-out chi-square per entry against the noise, per
view and in all; a note when it stays far above) and ``optimum`` (how the final model is known to
be a local optimum of the joint problem).

The errors are time-domain errors of the **predictions** (the mean of the replays:
:meth:`ssamb.closeloop.comparison.Comparison.prediction`), so a residual at the noise is the
rig's own noise plus a fraction ``1/replay_seeds`` of the model's.
"""
from __future__ import annotations

import numpy as np

from ..io import plain
from .calibration import findings
from .residual import channel_errors, channel_noise, compute_features

__all__ = ["build_report", "findings_text"]


def _error_reduction(meas_v, models_v, hold, sigma0, vn) -> list[float]:
    """Per step of a model sequence: the share of the first model's held-out residual excess removed.

    For every view clearly above the noise in the first model (mean square over twice the noise
    power), ``(ms_before - ms_after) / (ms_first - sigma^2)``, averaged over those views.
    """
    ms = [{v: float(np.mean((meas_v[v][hold] - m[v][hold]) ** 2)) for v in vn} for m in models_v]
    above = [v for v in vn if ms[0][v] > 2 * sigma0[v] ** 2]
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
    key = {"offset": lambda f: -abs(f["z"]), "residual_at_excited_lines": lambda f: f["p"],
           "line_not_excited": lambda f: -max(f["amplitude"].values())}
    return {test: sorted(lst, key=key.get(test, lambda f: 0))[:limit] for test, lst in by.items()}


def _calibration(search, sigma, meas_v, hold, nominal_v, dev) -> dict:
    """The ``calibration`` block and the binding ``parameters`` / ``not_identifiable``."""
    cal = search.calibration
    ident = search.joint.get("ident")
    specs = cal.specs
    if not specs:
        return {"parameters": [], "rank": 0}, {}, {}
    theta = search.joint.get("theta_cal", cal.theta)
    params, not_ident = findings(specs, theta, ident)
    per = []
    for s, t in zip(specs, theta):
        d = ident["per_parameter"][s.key]
        scale = abs(s.nominal) if s.relative else 1.0
        per.append({"key": s.key, "nominal": s.nominal, "value": s.value(float(t)), "se": d["se"] * scale,
                    "tolerance": s.prior_sd * scale, "relative": s.relative, "identified": d["identified"],
                    "z_from_nominal": float(t / s.prior_sd), "se_alone": d["se_alone"] * scale,
                    "partner": d["partner"], "correlation": d["correlation"], "reason": d["reason"],
                    "conflict": s.key in cal.conflicts})
        if "se_within_model" in d:       # widened over the candidates the data do not exclude
            per[-1]["se_within_model"] = d["se_within_model"] * scale
    red = _error_reduction(meas_v, [nominal_v, dev.views(search.calibrated)], hold, sigma, dev.view_names)[0]
    block = {"parameters": per, "rank": ident["rank"], "n_parameters": ident["n_parameters"],
             "condition": ident["condition"], "singular_values": ident["singular_values"],
             "combinations": ident["combinations"], "conflicts": cal.conflicts, "error_reduction": red,
             "simulations": cal.fit.evaluations if cal.fit else 0,
             "converged": bool(cal.fit.converged) if cal.fit else True,
             "stopped_short": bool(cal.fit.stopped_short) if cal.fit else False,
             "cost_over_noise_floor": float(cal.fit.floor_ratio) if cal.fit and cal.fit.floor > 0 else None,
             "infeasible_replays": int(cal.fit.infeasible) if cal.fit else 0}
    if cal.restarts:
        block["restarts"] = cal.restarts
    if ident.get("averaged_over"):
        block["averaged_over"] = ident["averaged_over"]
    return block, params, not_ident


def _effects(search, sigma, meas_v, hold, dev) -> list:
    models = [dev.views(search.calibrated)] + [dev.views(a["pred"]) for a in search.accepted]
    red = _error_reduction(meas_v, models, hold, sigma, dev.view_names)
    ident = search.joint.get("ident") or {"per_parameter": {}}
    out = []
    for a, r in zip(search.accepted, red):
        m = a["model"]
        idf = {p: ident["per_parameter"].get(f"{m.name}.{p}", {}).get("identified", True) for p in m.params}
        for e in a["entries"]:
            out.append({"name": e["name"], "params": e["params"], "uncertainty": e.get("uncertainty", {}),
                        "error_reduction": r, "evidence": a["evidence"].to_json(),
                        "fit": {"parameters": dict(zip(m.params, np.asarray(a["theta"]).tolist())),
                                "standard_errors": dict(zip(m.params, np.asarray(a["se"]).tolist())),
                                "identifiable": idf, "holdout_z": a["holdout"]["z"],
                                "explained_at_acceptance": a["holdout"]["explained"],
                                "delta_bic": a["holdout"]["delta_bic"], "round": a["round"],
                                "without_signature": a["without_signature"],
                                "aliases_plausible": a.get("alias_spread", {}).get("plausible", []),
                                **({"speed_refined": a["speed_refined"]} if a.get("speed_refined") else {})},
                        **({"rivals": list(a["rivals"])} if a.get("rivals") else {}),
                        **{k: v for k, v in e.items() if k not in ("name", "params", "uncertainty")}})
    out.sort(key=lambda e: -e["error_reduction"])
    return out


def _notes(rec, effects, cal_block, not_ident) -> list:
    notes = []
    for ax in rec.device.features.axis_views:
        if ax not in rec.excited_axes:
            notes.append(f"axis {ax} is not excited: a sensor gain or delay on it leaves no trace in these data")
    for e in effects:
        if e["fit"].get("aliases_plausible"):
            notes.append(f"{e['name']}: {len(e['fit']['aliases_plausible'])} point(s) of its comb (a delay whole "
                         "controller samples away) rejected by neither part of the record: its standard error holds "
                         "their spread")
        if e.get("rivals"):
            names = ", ".join(f"{r['name']} (z {r['z']:.2f})" for r in e["rivals"])
            notes.append(f"{e['name']}: the data cannot tell it apart from {names}: each passed every test alone in "
                         f"round {e['fit']['round']} and {e['name']} does not predict the held-out part significantly "
                         f"better (z of {e['name']} over each); {e['name']} is named first")
        if e["fit"]["without_signature"]:
            notes.append(f"{e['name']}: no signature was significant before fitting (round {e['fit']['round']}); "
                         "it was found by fitting each library effect and rests on the held-out error alone")
    if cal_block.get("stopped_short"):
        r = cal_block.get("cost_over_noise_floor")
        far = f"{r:.3g} times the noise floor" if r is not None else "far above the noise floor (its start infeasible)"
        notes.append(f"the calibration stopped short: it ended without converging while its cost was still {far} "
                     f"(a better calibration may exist; what follows rests on this one)")
    for p in cal_block.get("parameters", []):
        if p["identified"] and abs(p["z_from_nominal"]) > 3:
            notes.append(f"{p['key']}: {p['value']:.6g} lies {abs(p['z_from_nominal']):.1f} tolerances from its "
                         f"nominal value {p['nominal']:.6g}: outside the stated tolerance")
    return notes


def _dropped_note(d: dict) -> str:
    """The note of an effect the joint refit left at zero (:attr:`SearchResult.dropped`)."""
    values = ", ".join(f"{k} {v:.3g} +- {d['se'][k]:.2g}" for k, v in d["theta"].items())
    beyond = ""
    if d.get("beyond_z") is not None:
        beyond = f", and the held-out part does not need it (z {d['beyond_z']:.2f} over the same model with it at zero"
        if d.get("refit_z") is not None:
            beyond += f"; z {d['refit_z']:.2f} over the joint refit without it"
        beyond += ")"
    return (f"{d['name']}: accepted in round {d['round']}, but in the joint refit its size is consistent with zero "
            f"({values}; Wald chi2 {d['size_chi2']:.3g} on {d['k']}){beyond}: not a finding, left out of the final "
            f"model")


def _misfit_notes(mis: dict, opt: dict, far: float = 2.0) -> list:
    """Notes when the final model's held-out misfit stays far above the noise (``far`` times the
    chi-square per entry the noise gives, in a view or in all) and when the joint refit did not
    converge."""
    out = []
    if mis and mis.get("ratio", 0.0) > far:
        worst = sorted(mis["views"].items(), key=lambda kv: -kv[1]["ratio"])
        views = ", ".join(f"{v} {d['ratio']:.3g}" for v, d in worst if d["ratio"] > far)
        out.append(f"the final model's held-out misfit stays {mis['ratio']:.3g} times the noise (chi-square per entry; "
                   f"1 at the noise; per view: {views})")
    elif mis:
        views = [f"{v} {d['ratio']:.3g}" for v, d in mis["views"].items() if d["ratio"] > far]
        if views:
            out.append(f"the final model's held-out misfit stays far above the noise in {', '.join(views)} "
                       "(chi-square per entry; 1 at the noise)")
    if opt and not opt.get("converged", True):
        out.append(opt["how"])
    return out


def _summary(effects, unexplained, params) -> str:
    cal = (f"calibrated {len(params)} nominal parameter{'s' if len(params) != 1 else ''}"
           if params else "no nominal parameter identified")
    if unexplained and not effects:
        return (f"{cal}; no library effect explains the residual; it is not consistent with noise "
                "(see remaining_signature)")
    if unexplained:
        return (f"{cal}; found {', '.join(e['name'] for e in effects)}; a residual that no library effect explains "
                "remains (see remaining_signature)")
    if effects:
        return f"{cal}; found {', '.join(e['name'] for e in effects)}; the held-out residual is consistent with noise"
    return f"{cal}; no effect beyond noise: the calibrated model explains the data"


def build_report(rec, split, search, settings, source: str, timing: dict) -> dict:
    """The ``closeloop.json`` dictionary."""
    dev = rec.device
    meas_v = dev.views(rec.channels)
    hold = split.hold
    frame = _hold_frame(rec, split)
    sigma = compute_features(rec, frame, meas_v, dev.views(search.final), settings, lines=False).sigma
    sig_ch = channel_noise(frame, rec.channels, search.final, settings, dev)
    cal_block, params, not_ident = _calibration(search, sigma, meas_v, hold, dev.views(search.nominal), dev)
    effects = _effects(search, sigma, meas_v, hold, dev)

    def errs(model):
        ce = channel_errors(rec.channels, model, hold, dev, sig_ch or None)
        for d in ce.values():
            if "noise_rms" in d:
                d["above_noise"] = bool(d["rms"] > 2 * d["noise_rms"])
        return ce

    fs = rec.fs_hz
    rep = {
        "effects": effects, "unexplained": not search.consistent,
        "error_before": errs(search.nominal), "error_after": errs(search.final),
        "error_calibrated": errs(search.calibrated),
        "parameters": params, "not_identifiable": not_ident, "calibration": cal_block,
        "validation": {"fit_fraction": split.fit_fraction, "fit_s": [split.i0 / fs, split.i_fit / fs],
                       "holdout_s": [split.i_fit / fs, split.i_end / fs], "discarded_s": split.i0 / fs,
                       "usable_s": [[a / fs, b / fs] for a, b in (rec.usable or ((0, rec.n),))],
                       "usable_reason": rec.usable_reason,
                       "whole_periods": split.n_period is not None,
                       "period_s": None if split.n_period is None else split.n_period / fs,
                       "errors_on": "held-out part"},
        "consistent_with_noise": search.consistent,
        "remaining_signature": _remaining(search.failures) if not search.consistent else {},
        "evidence": search.rounds[0]["evidence"] if search.rounds else {},
        "ranking": search.rounds[0]["ranking"] if search.rounds else [],
        "rounds": [{"round": r["round"], "ranking": r["ranking"], "candidates": r["candidates"],
                    "without_signature": bool(r.get("fallback"))} for r in search.rounds],
        "final_model": {"overrides": search.overrides, "effects": search.effects},
        "noise": {"views": sigma, "channels": sig_ch},
        "data": {"source": source, "device": dev.name, "duration_s": rec.duration_s, "fs_hz": fs,
                 "excitation": rec.excitation,
                 "excited_axes": list(rec.excited_axes), "start": rec.start, "acquisition": rec.acquisition},
        "timing": timing,
        "settings": {k: getattr(settings, k) for k in settings.__dataclass_fields__},
    }
    rep["misfit"] = search.misfit
    rep["optimum"] = search.optimum
    rep["notes"] = (_notes(rec, effects, cal_block, not_ident) + [_dropped_note(d) for d in search.dropped]
                    + _misfit_notes(search.misfit, search.optimum))
    rep["summary"] = _summary(effects, rep["unexplained"], params)
    return plain(rep)


def _hold_frame(rec, split):
    from .spectra import make_frame

    return make_frame(rec.fs_hz, split.i_fit, split.i_end - split.i_fit, rec.signal, split.n_period, rec.lines_hz)



_UNITS = (("_s_per_m", "S/m"), ("_ohm", "ohm"), ("_kg", "kg"), ("_hz", "Hz"), ("_m", "m"), ("_a", "A"), ("_v", "V"),
          ("_s", "s"))


def _unit(key: str) -> str:
    leaf = key.split(".")[-1]
    return next((u for suf, u in _UNITS if leaf.endswith(suf)), "")


def findings_text(rep: dict) -> list[str]:
    """The findings of a ``closeloop.json``, one line each (the command line prints them).

    ``table1.mass_kg = 4.05 +- 0.01 kg (model 3.86 kg, +4.9 %)``; the parameters the data cannot
    identify, with the reason; the effects with their parameters; the held-out error before
    and after.
    """
    out = [f"summary: {rep['summary']}"] if "summary" in rep else []
    for key, p in rep.get("parameters", {}).items():
        u = _unit(key)
        rel = f", {100 * p['relative_change']:+.2f} %" if p.get("relative_change") is not None else ""
        out.append(f"parameter {key} = {p['value']:.6g} +- {p['se']:.2g} {u} (model {p['nominal']:.6g} {u}{rel})")
    for key, why in rep.get("not_identifiable", {}).items():
        out.append(f"not identifiable {key}: {why}")
    for e in rep.get("effects", []):
        unc = e.get("uncertainty", {})
        par = ", ".join(f"{k} = {v:.4g}" + (f" +- {unc[k]:.2g}" if isinstance(unc.get(k), float) else "")
                        if isinstance(v, float) else f"{k} = {v}" for k, v in e["params"].items())
        why = (f"removes {100 * e['error_reduction']:.0f} % of the residual excess"
               if e.get("error_reduction") is not None else f"held-out z {e.get('holdout_z', float('nan')):.1f}")
        out.append(f"effect {e['name']}: {par} ({why})")
    for c in rep["error_before"]:
        grouped = any(c in g.get("per_coil", {}) for g in rep["error_before"].values())
        if "per_coil" not in rep["error_before"][c] and grouped:
            continue            # a channel of a group: the group's line stands for it
        b, a = rep["error_before"][c], rep["error_after"][c]
        noise = a.get("noise_rms", float("nan"))
        out.append(f"held-out rms error {c}: {b['rms']:.3g} -> {a['rms']:.3g} (noise {noise:.3g})")
    return out
