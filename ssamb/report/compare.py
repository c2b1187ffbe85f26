"""The paper-versus-reproduction table: one row per headline, the paper's value (quoted,
:mod:`ssamb.paper`), ours (default run), the paper's way (``summary['paper_way']``) and why
they differ -- each "why" computed: the paper's-way run, the critical amplitudes, the computed
cause of the μ peak, and the study variant that moves the number most (when the study ran)."""
from __future__ import annotations

from typing import Any, Mapping

from ..paper import PAPER

__all__ = ["comparison_rows", "HEADER"]

HEADER = ["quantity", "paper", "ours", "the paper's way", "why (computed)"]


def _f(v, d=4, unit=""):
    if v is None:
        return "none"
    if isinstance(v, float):
        return f"{v:.{d}g}{unit}"
    return f"{v}{unit}"


def _get(d: Mapping | None, *keys) -> Any:
    for k in keys:
        if not isinstance(d, Mapping):
            return None
        d = d.get(k)
    return d


def mover(study: Mapping | None, key: str, unit: str = "", d: int = 3) -> str:
    """'moved most by <variant> (baseline -> value)' for a headline quantity of the study, or
    a note that the study has not run."""
    if not study:
        return "Which assumption moves it: run `snakemake --cores 2 study`."
    var = study["variants"]
    base = var.get(study["baseline"], {}).get(key)
    cands = [(n, v[key]) for n, v in var.items() if n != study["baseline"] and v.get(key) is not None]
    if base is None or not cands:
        return "The study has no value for it."
    name, val = max(cands, key=lambda nv: abs(nv[1] - base))
    return f"Moved most by study variant `{name}` ({_f(base, d, unit)} -> {_f(val, d, unit)})."


def answer_text(study: Mapping, answer: str) -> str:
    """What a study answer asks of a variant, with the criteria of ``study.json``."""
    crit = study["criteria"]
    return {"delevitation": "make the nonlinear model delevitate in the sweep while the LTI models do not",
            "mu_peak_near_2hz": f"put the self-sensing μ peak within a factor {crit['mu_peak_factor']:g} of the "
                                f"paper's {PAPER['mu_peak_hz'][0]:g} Hz",
            "fit_y_near_paper": f"give a y fit within {crit['fit_y_points']:g} points of the paper's "
                                f"{PAPER['fit_y_pct'][0]:g} %"}[answer]


def _which(study: Mapping | None, answer: str) -> str:
    if not study:
        return ""
    names = study["answers"][answer]
    return f" Variants that {answer_text(study, answer)}: " + (", ".join(f"`{n}`" for n in names) or "none") + "."


def _fit_rows(S, P, study) -> list:
    fx, fy = S["fit_pct"]["x"], S["fit_pct"]["y"]
    px, py = _get(P, "fit_pct", "x"), _get(P, "fit_pct", "y")
    stable = _get(P, "stable")
    why_y = (f"With the paper's structure the assembled loop is {'stable' if stable else 'unstable'} "
             f"(spectral radius {_f(_get(P, 'spectral_radius'), 6)}) and y fits {_f(py, 4, ' %')}; ours "
             "(position-input "
             f"self-sensing, command-input amplifier) fits {_f(fy, 4, ' %')}. " + mover(study, "fit_y_pct", " %")
             + _which(study, "fit_y_near_paper"))
    return [("closed-loop LTI fit, x (Fig. 4)", f"{PAPER['fit_x_pct'][0]} %", _f(fx, 4, " %"), _f(px, 4, " %"),
             "The x loop reads the eddy-current sensor in both structures. " + mover(study, "fit_x_pct", " %")),
            ("closed-loop LTI fit, y (Fig. 4)", f"{PAPER['fit_y_pct'][0]} %", _f(fy, 4, " %"), _f(py, 4, " %"), why_y)]


def _order_rows(S, P) -> list:
    return [(f"{k} model order", str(PAPER['order_' + k][0]), _f(S["orders"].get(k)), _f(_get(P, "orders", k)),
             "Configured (identification.<subsystem>.order); the order scan in report section 2 is the evidence.")
            for k in ("plant", "amplifier", "selfsensing")]


def _mu_rows(S, P, study) -> list:
    ss, pss = S["mu"].get("selfsensing") or {}, _get(P, "mu", "selfsensing") or {}
    cause = (ss.get("cause") or {}).get("sentence") or "cause not computed"
    pcause = (_get(P, "mu_peak_cause") or {}).get("sentence") or "cause not computed"
    return [("weight fit, largest deviation from the envelope", f"<= {PAPER['weight_fit_max_db'][0]} dB",
             _f(S["weight_fit_max_db"], 3, " dB"), _f(_get(P, "weight_fit_max_db"), 3, " dB"),
             "Both fits are held to the same tolerance (config uncertainty.tol_db)."),
            ("weight scale factor for a μ peak of 1 (self-sensing)", _f(PAPER["mu_scale_for_unity"][0]),
             _f(ss.get("scale_for_unity"), 3), _f(pss.get("scale_for_unity"), 3),
             "The scale is 1/peak of μ for the measured weight. " + mover(study, "mu_scale_for_unity")),
            ("μ peak frequency (self-sensing)", f"~{PAPER['mu_peak_hz'][0]:g} Hz", _f(ss.get("peak_hz"), 3, " Hz"),
             _f(pss.get("peak_hz"), 3, " Hz"), f"Ours: {cause}. The paper's way: {pcause}. "
             + mover(study, "mu_peak_hz", " Hz") + _which(study, "mu_peak_near_2hz"))]


def _event(o: Mapping | None) -> str:
    if o is None:
        return "none"
    if o.get("delevitates"):
        return f"{o['time_s']:.3g} s at {o['sweep_hz']:.3g} Hz"
    ca = o.get("critical_amplitude_m")
    return "none" + (f" (delevitates from {ca * 1e6:.0f} µm)" if ca else "")


def _sweep_rows(S, P, study) -> list:
    outs = {o["model"]: o for o in (_get(S, "details", "validation", "outcomes") or [])}
    aug = [(m.split("Delta=")[-1], o) for m, o in outs.items() if m.startswith("augmented")]
    dl, pdl = S["delevitation_s"], _get(P, "delevitation_s") or {}
    sw = _get(S, "details", "validation", "sweep") or {}
    band = PAPER["sweep_band_hz"][0]
    ours = (f"{sw['amplitude_m'] * 1e6:.3g} µm, {sw['f_start_hz']:g}-{sw['f_stop_hz']:g} Hz in "
            f"{sw['sweep_duration_s']:g} s "
            f"({sw.get('law', 'linear')})") if sw else "none"
    return [("sweep signal (section 6)", f"{PAPER['sweep_amplitude_m'][0] * 1e6:.3g} µm, {band[0]:g}-{band[1]:g} Hz, "
             "duration not stated", ours, ours, "The paper gives amplitude and band, not the rate; the study varies "
             "the duration and the law (config study.assumptions)."),
            ("delevitation in the sweep, nonlinear", f"just after {PAPER['delevitation_nonlinear_s'][0]} s",
             _event(outs.get("nonlinear")), _f(pdl.get("nonlinear"), 3, " s"),
             "The critical sweep amplitudes (report section 5) say how far from delevitation each model is. "
             + mover(study, "critical_nonlinear_um", " µm")
             + _which(study, "delevitation")),
            ("delevitation, nominal LTI model", "none", _event(outs.get("nominal LTI")),
             _f(pdl.get("nominal_lti"), 3, " s"),
             "An LTI model delevitates only above its exact critical amplitude. "
             + mover(study, "critical_lti_um", " µm")),
            ("delevitation, augmented LTI model", "none",
             "; ".join(f"Delta={k}: {_event(o)}" for k, o in aug) if aug else _f(dl["augmented_lti"]),
             _f(pdl.get("augmented_lti"), 3, " s"), "Δ = +1, −1 and an all-pass, each with the measured weight.")]


def comparison_rows(S: Mapping, study: Mapping | None = None) -> list[tuple]:
    """Rows ``(quantity, paper, ours, the paper's way, why)`` from a default-run summary and,
    when it has run, the assumption study (``study.json``)."""
    P = S.get("paper_way")
    iso = S["iso14839_peak_sensitivity"]
    return (_fit_rows(S, P, study) + _order_rows(S, P) + _mu_rows(S, P, study) + _sweep_rows(S, P, study)
            + [("ISO 14839-3 peak sensitivity x / y", "not reported", f"{_f(iso['x'], 3)} / {_f(iso['y'], 3)}",
                " / ".join(_f(v, 3) for v in (_get(P, "iso14839_peak_sensitivity") or {}).values()) or "none",
                "The baseline the paper argues against, from the same closed-loop model.")])
