"""Report section "Close the loop with measured data" (beyond the paper): the chain on the
default rig data set, read from its ``closeloop.json`` and figures."""
from __future__ import annotations

from ...io import read_json
from ..context import Context
from ..elements import Image, Section, Table

__all__ = ["closeloop"]


def _fmt(x, spec=".3g"):
    return "-" if x is None else format(x, spec)


def _candidates(C) -> Table:
    rows = [(r["round"], c["name"], ", ".join(f"{k} = {_fmt(v, '.4g')}" for k, v in c["theta"].items()),
             c["holdout_z"], f"{100 * c['explained']:.0f} %", "kept" if c["passed"] else "; ".join(c["reasons"]))
            for r in C["rounds"] for c in r["candidates"]]
    return Table(["round", "candidate", "fit", "held-out z", "explained", "verdict"], rows,
                 caption="Candidates tried, kept or rejected")


def _effects(C) -> list:
    eff = [(e["name"], ", ".join(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}"
                                 for k, v in e["params"].items()),
            ", ".join(f"{k}: {_fmt(v, '.2g')}" for k, v in e.get("uncertainty", {}).items()),
            f"{100 * e['error_reduction']:.0f} %") for e in C["effects"]]
    b, a = C["error_before"], C["error_after"]
    m = C.get("error_calibrated", b)
    errs = [(c, b[c]["rms"], m[c]["rms"], a[c]["rms"], a[c].get("noise_rms"), b[c]["fit_pct"], a[c]["fit_pct"])
            for c in ("x_meas", "y_meas", "y_ss", "currents", "u_x", "u_y") if c in b]
    return [Table(["effect", "parameters", "standard error", "share of the error removed"], eff),
            Table(["channel", "rms nominal", "rms calibrated", "rms final", "noise rms", "fit % nominal",
                   "fit % final"], errs, caption="Held-out error of the nominal, calibrated and final model (SI "
                                                 "units)")]


def _calibration(C) -> list:
    cal = C.get("calibration", {})
    rows = [(p["key"], p["nominal"], p["value"], p["se"] if p["identified"] else None, p["tolerance"],
             f"{p['z_from_nominal']:+.2f}", "identified" if p["identified"] else p["reason"])
            for p in cal.get("parameters", [])]
    if not rows:
        return []
    combos = "; ".join(" + ".join(f"{w:+.2f} {k}" for k, w in c["weights"].items()) +
                       f" (known to {100 * c['known_to_fraction_of_tolerance']:.2g} % of the tolerance)"
                       for c in cal.get("combinations", [])[:4])
    return [Table(["parameter (config key, SI)", "nominal", "estimate", "standard error", "tolerance",
                   "change (tolerances)", "verdict"], rows,
                  caption="Nominal parameters calibrated from the data (MAP with the tolerances as priors; "
                          "standard errors from the Jacobian at the optimum and the replays' own spread)"),
            f"Sensitivity matrix: rank {cal.get('rank')} of {cal.get('n_parameters')} (singular values of the "
            "information per tolerance at least 3), condition "
            f"{_fmt(cal['condition']) if cal.get('condition') is not None else 'unbounded (numerically singular)'}. "
            "Identified combinations: "
            f"{combos or 'none'}. The calibration alone removes {100 * cal.get('error_reduction', 0.0):.0f} % of the "
            "nominal model's held-out residual excess."]


def closeloop(ctx: Context) -> Section | None:
    """Replay, residual, signatures, fit, before/after for the default data set (None if none)."""
    if ctx.closeloop_dir is None:
        return None
    d = ctx.closeloop_dir
    C = read_json(d / "closeloop.json")
    v, data = C["validation"], C["data"]
    ev = [(n, e["score_chi2"], e["log10_p"], e["significant"], e["signature"]) for n, e in C["evidence"].items()]
    sec = Section("6. Close the loop with measured data (beyond the paper)").add(
        "The paper's conclusion is that an LTI uncertainty model cannot explain nonlinear behaviour. Here the "
        "residual between measured data and the nominal nonlinear model is explained with physics: replay the "
        "model with the recorded excitation, calibrate the nominal parameters a rig never matches exactly, "
        "rank the library effects by the signature each predicts in the calibrated model's residual, fit the "
        "leading ones by simulation, keep those that lower the error on held-out data until the residual is "
        "noise, and refit everything jointly. All errors below are on the held-out part of the record; the "
        "noise is estimated from the data and from replays with other noise seeds.",
        f"**Data**: `{data['source']}`, {data['duration_s']:.2f} s, excitation `{data['excitation'].get('kind')}` "
        f"on axes {', '.join(data['excited_axes'])}; fitted on {v['fit_s'][0]:.2f}-{v['fit_s'][1]:.2f} s, held "
        f"out {v['holdout_s'][0]:.2f}-{v['holdout_s'][1]:.2f} s. **Result**: {C['summary']}.",
        "### Calibration of the nominal parameters", *_calibration(C), Image(d / "calibration.png"),
        "### Replay and residual", Image(d / "features.png"), Image(d / "residual_time.png"),
        Image(d / "residual_spectra.png"),
        "### Signatures: evidence before any fitting", Image(d / "evidence.png"),
        Table(["effect", "explained chi2", "log10 p", "candidate", "signature"], ev),
        Image(d / "sensor_ratio.png") if (d / "sensor_ratio.png").exists() else None,
        "### Fit, and the effects found", _candidates(C), *_effects(C))
    if C["unexplained"]:
        sec.add("**Unexplained residual** (no library effect accounts for it): "
                + "; ".join(f"{t}: {len(x)} finding(s)" for t, x in C["remaining_signature"].items()))
    if C.get("notes"):
        sec.add("**Notes**: " + " ".join(f"({i + 1}) {n}." for i, n in enumerate(C["notes"])))
    return sec
