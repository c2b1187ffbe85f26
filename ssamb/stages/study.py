r"""Stage ``study_collect``: the assumption study's headline numbers, tornado charts and answers.

Every variant is a run of the chain (:mod:`ssamb.scenarios`); this stage reads their
``summary.json`` files and, per headline quantity, tabulates the variants against the study's
baseline run, draws a tornado chart per headline, and answers -- by computation over the
variants -- which assumptions reproduce each of the paper's three headline results.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from ..io import read_json, write_json
from ..paper import PAPER
from ..scenarios import study_variants

__all__ = ["HEADLINES", "variant_quantities", "collect_study", "answers"]

#: headline quantity -> (label, unit)
HEADLINES = {
    "fit_y_pct": ("closed-loop LTI fit, y (Fig. 4)", "%"),
    "mu_peak_hz": ("self-sensing μ peak frequency", "Hz"),
    "mu_scale_for_unity": ("weight scale for a μ peak of 1 (self-sensing)", "-"),
    "critical_nonlinear_um": ("sweep amplitude that delevitates the nonlinear model", "µm"),
    "critical_lti_um": ("sweep amplitude that delevitates the nominal LTI model", "µm"),
    "delevitation_nonlinear_s": ("delevitation time of the nonlinear model in the sweep", "s"),
}


def _critical_um(val: Mapping | None, model: str):
    for o in (val or {}).get("outcomes", []):
        if o["model"] == model and o.get("critical_amplitude_m") is not None:
            return o["critical_amplitude_m"] * 1e6
    return None


def variant_quantities(s: Mapping) -> dict:
    """The headline quantities of one run's summary (None where missing or failed)."""
    det = s.get("details") or {}
    mu = (s.get("mu") or {}).get("selfsensing") or {}
    val = det.get("validation")
    dl = s.get("delevitation_s") or {}
    return {"fit_y_pct": (s.get("fit_pct") or {}).get("y"), "fit_x_pct": (s.get("fit_pct") or {}).get("x"),
            "stable": (det.get("assembly") or {}).get("stable"), "mu_peak": mu.get("peak"),
            "mu_peak_hz": mu.get("peak_hz"), "mu_scale_for_unity": mu.get("scale_for_unity"),
            "critical_nonlinear_um": _critical_um(val, "nonlinear"),
            "critical_lti_um": _critical_um(val, "nominal LTI"),
            "delevitation_nonlinear_s": dl.get("nonlinear"), "delevitation_nominal_lti_s": dl.get("nominal_lti"),
            "delevitation_augmented_lti_s": dl.get("augmented_lti"), "failed": s.get("failed") or {}}


def _near(v, target: float, factor: float) -> bool:
    return v is not None and target / factor <= v <= target * factor


def answers(variants: Mapping[str, Mapping], criteria: Mapping) -> dict:
    """Which variants reproduce each of the paper's headlines (computed from their numbers):
    the nonlinear model delevitates in the sweep while the nominal and augmented LTI models do
    not; the self-sensing μ peak within ``criteria["mu_peak_factor"]`` of the paper's ~2 Hz; the
    y fit within ``criteria["fit_y_points"]`` percentage points of the paper's (config
    ``study.criteria``)."""
    out = {"delevitation": [], "mu_peak_near_2hz": [], "fit_y_near_paper": []}
    for name, q in variants.items():
        if (q["delevitation_nonlinear_s"] is not None and q["delevitation_nominal_lti_s"] is None
                and q["delevitation_augmented_lti_s"] is None):
            out["delevitation"].append(name)
        if _near(q["mu_peak_hz"], PAPER["mu_peak_hz"][0], float(criteria["mu_peak_factor"])):
            out["mu_peak_near_2hz"].append(name)
        fit_y = q["fit_y_pct"]
        if fit_y is not None and abs(fit_y - PAPER["fit_y_pct"][0]) <= float(criteria["fit_y_points"]):
            out["fit_y_near_paper"].append(name)
    return out


def _tornado(quant: Mapping, assumptions: Mapping, baseline: Mapping, path: str | Path) -> None:
    """One panel per headline: per assumption, the span of the quantity over its values (bars
    from the baseline value), failed variants marked."""
    import matplotlib.pyplot as plt

    from ..figures import save

    names = list(assumptions)
    fig, axs = plt.subplots(2, 3, figsize=(13, 1.2 + 0.32 * max(4, len(names)) * 2), squeeze=False)
    for ax, (key, (label, unit)) in zip(axs.ravel(), HEADLINES.items()):
        b = baseline.get(key)
        for i, a in enumerate(names):
            vals = [quant[v][key] for v in assumptions[a] if quant[v][key] is not None]
            for v in vals:
                ax.plot([b if b is not None else v, v], [i, i], color="C0", lw=6, alpha=0.5, solid_capstyle="butt")
            if len(vals) < len(assumptions[a]):
                ax.plot([b if b is not None else 0], [i], "x", color="C3")
        if b is not None:
            ax.axvline(b, color="k", lw=0.8)
        ax.set_yticks(range(len(names)), names, fontsize=7)
        ax.set_title(f"{label} ({unit})", fontsize=8)
        if key in ("mu_peak_hz", "mu_scale_for_unity") and all(
                (quant[v][key] or 0) > 0 for a in names for v in assumptions[a]) and (b or 0) > 0:
            ax.set_xscale("log")
    fig.suptitle("Assumption study: each bar spans a headline over one assumption's values (line: baseline; "
                 "x: a variant without this number)", fontsize=9)
    fig.tight_layout()
    save(fig, path)


def collect_study(study: Mapping, runs: Sequence[str], summaries: Sequence[str | Path], out_json: str | Path,
                  out_fig: str | Path | None = None) -> dict:
    """Read the variants' summaries (``runs`` are their prefixes ``runs/<name>/``, in the order of
    ``summaries``), write ``study.json`` (per variant: overrides and headline quantities; per
    assumption: its variants; the computed answers) and the tornado charts."""
    names = [r.strip("/").split("/", 1)[1] for r in runs]
    quant = {n: variant_quantities(read_json(p)) for n, p in zip(names, summaries)}
    overrides = study_variants({"study": study})
    assumptions: dict[str, list] = {}
    for n in names:
        if n != "study-baseline" and "+" not in n:
            assumptions.setdefault(n[len("study-"):].split("=", 1)[0], []).append(n)
    baseline = quant.get("study-baseline", {})
    res = {"variants": {n: {"overrides": overrides.get(n), **quant[n]} for n in names},
           "assumptions": assumptions, "pairs": [n for n in names if "+" in n], "baseline": "study-baseline",
           "criteria": dict(study["criteria"]), "answers": answers(quant, study["criteria"])}
    res["sensitivity"] = {n: {k: quant[n][k] for k in (*HEADLINES, "fit_x_pct", "stable", "failed")} for n in names}
    write_json(out_json, res)
    if out_fig is not None:
        _tornado(quant, assumptions, baseline, out_fig)
    return res


