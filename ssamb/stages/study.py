r"""Stage ``study_collect``: the assumption study's headline numbers, tornado charts and answers.

Every variant is a run of the chain (:mod:`ssamb.scenarios`); this stage reads their
``summary.json`` files and, per headline quantity, tabulates the variants against the study's
baseline run, draws a tornado chart per headline, and answers -- by computation over the
variants -- which assumptions reproduce each of the paper's three headline results.

The study against the noise
---------------------------
Each variant is one noise realisation. When the noise ensembles have run (``ensemble.json``),
the default chain's spread over its realisations becomes a *noise band* around the study's
baseline (:func:`noise_bands`): ``[b + (min - median), b + (max - median)]`` for a quantity on a
linear scale, ``[b min/median, b max/median]`` for the μ peak frequency and the weight scale
(log scale). A variant moves a headline only where its value lies outside that band
(``beyond_noise``); the tornado draws the band, and the answers widen each criterion by it (a
variant reproduces a headline when the paper's value is within the criterion of the variant's
own band).
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from ..io import read_json, write_json
from ..paper import PAPER
from ..scenarios import study_variants

__all__ = ["HEADLINES", "variant_quantities", "collect_study", "answers", "noise_bands", "NOISE_OF"]

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


#: study quantity -> the ensemble quantity whose spread is its noise band, and whether on a log scale
NOISE_OF = {"fit_y_pct": ("fit_y_pct", False), "fit_x_pct": ("fit_x_pct", False), "mu_peak_hz": ("mu_peak_hz", True),
            "mu_scale_for_unity": ("mu_scale_for_unity", True),
            "critical_nonlinear_um": ("critical_nonlinear_um", False),
            "critical_lti_um": ("critical_nominal_um", False),
            "delevitation_nonlinear_s": ("delevitation_nonlinear_s", False)}


def _band(value, spread: Mapping | None, log: bool):
    """``(lo, hi)`` of the noise band around ``value`` (module docstring), ``(value, value)`` without one."""
    if value is None:
        return None, None
    if not spread or not spread.get("K") or spread.get("K", 0) < 2:
        return value, value
    med, lo, hi = spread["median"], spread["min"], spread["max"]
    if log and med > 0 and lo > 0 and value > 0:
        return value * lo / med, value * hi / med
    return value + lo - med, value + hi - med


def noise_bands(baseline: Mapping, ensemble: Mapping | None) -> dict:
    """Per study quantity, the noise band around the baseline's value (``lo``, ``hi``, the
    ensemble's ``K``), from the default chain of ``ensemble.json``; empty without ensembles."""
    if not ensemble:
        return {}
    q = ensemble["chains"]["default"]["quantities"]
    out = {}
    for key, (ek, log) in NOISE_OF.items():
        lo, hi = _band(baseline.get(key), q.get(ek), log)
        if lo is not None and q.get(ek, {}).get("K", 0) >= 2:
            out[key] = {"lo": lo, "hi": hi, "K": q[ek]["K"], "log": log, "from": f"ensemble default chain, {ek}"}
    return out


def answers(variants: Mapping[str, Mapping], criteria: Mapping, ensemble: Mapping | None = None) -> dict:
    """Which variants reproduce each of the paper's headlines (computed from their numbers):
    the nonlinear model delevitates in the sweep while the nominal and augmented LTI models do
    not; the self-sensing μ peak within ``criteria["mu_peak_factor"]`` of the paper's ~2 Hz; the
    y fit within ``criteria["fit_y_points"]`` percentage points of the paper's (config
    ``study.criteria``). With ``ensemble`` each variant's value is widened by its noise band
    (the default chain's spread around it, :func:`_band`): the criterion is met when the band
    comes within it."""
    spread = ((ensemble or {}).get("chains") or {}).get("default", {}).get("quantities") or {}
    kf, ky = float(criteria["mu_peak_factor"]), float(criteria["fit_y_points"])
    f0, y0 = PAPER["mu_peak_hz"][0], PAPER["fit_y_pct"][0]
    out = {"delevitation": [], "mu_peak_near_2hz": [], "fit_y_near_paper": []}
    for name, q in variants.items():
        if (q["delevitation_nonlinear_s"] is not None and q["delevitation_nominal_lti_s"] is None
                and q["delevitation_augmented_lti_s"] is None):
            out["delevitation"].append(name)
        lo, hi = _band(q["mu_peak_hz"], spread.get("mu_peak_hz"), True)
        if lo is not None and lo <= f0 * kf and hi >= f0 / kf:
            out["mu_peak_near_2hz"].append(name)
        lo, hi = _band(q["fit_y_pct"], spread.get("fit_y_pct"), False)
        if lo is not None and lo - ky <= y0 <= hi + ky:
            out["fit_y_near_paper"].append(name)
    return out


def _tornado(quant: Mapping, assumptions: Mapping, baseline: Mapping, path: str | Path,
             noise: Mapping | None = None) -> None:
    """One panel per headline: per assumption, the span of the quantity over its values (bars
    from the baseline value), failed variants marked, and the noise band around the baseline
    (grey) when the ensembles have run."""
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
        nb = (noise or {}).get(key)
        if nb:
            ax.axvspan(nb["lo"], nb["hi"], color="0.85", zorder=0)
        ax.set_yticks(range(len(names)), names, fontsize=7)
        ax.set_title(f"{label} ({unit})", fontsize=8)
        if key in ("mu_peak_hz", "mu_scale_for_unity") and all(
                (quant[v][key] or 0) > 0 for a in names for v in assumptions[a]) and (b or 0) > 0:
            ax.set_xscale("log")
    fig.suptitle("Assumption study: each bar spans a headline over one assumption's values (line: baseline; "
                 "x: a variant without this number" + ("; grey: the noise band, the spread over the noise "
                                                        "realisations" if noise else "") + ")", fontsize=9)
    fig.tight_layout()
    save(fig, path)


def collect_study(study: Mapping, runs: Sequence[str], summaries: Sequence[str | Path], out_json: str | Path,
                  out_fig: str | Path | None = None, ensemble_json: str | Path | None = None) -> dict:
    """Read the variants' summaries (``runs`` are their prefixes ``runs/<name>/``, in the order of
    ``summaries``), write ``study.json`` (per variant: overrides and headline quantities; per
    assumption: its variants; the computed answers; with ``ensemble_json`` the noise bands and
    which variants move a headline beyond them) and the tornado charts."""
    names = [r.strip("/").split("/", 1)[1] for r in runs]
    quant = {n: variant_quantities(read_json(p)) for n, p in zip(names, summaries)}
    overrides = study_variants({"study": study})
    assumptions: dict[str, list] = {}
    for n in names:
        if n != "study-baseline" and "+" not in n:
            assumptions.setdefault(n[len("study-"):].split("=", 1)[0], []).append(n)
    baseline = quant.get("study-baseline", {})
    ens = read_json(ensemble_json) if ensemble_json is not None else None
    noise = noise_bands(baseline, ens)
    for q in quant.values():
        q["beyond_noise"] = {k: not nb["lo"] <= q[k] <= nb["hi"] for k, nb in noise.items() if q.get(k) is not None}
    res = {"variants": {n: {"overrides": overrides.get(n), **quant[n]} for n in names},
           "assumptions": assumptions, "pairs": [n for n in names if "+" in n], "baseline": "study-baseline",
           "criteria": dict(study["criteria"]), "answers": answers(quant, study["criteria"], ens), "noise": noise}
    res["sensitivity"] = {n: {k: quant[n][k] for k in (*HEADLINES, "fit_x_pct", "stable", "failed", "beyond_noise")}
                          for n in names}
    write_json(out_json, res)
    if out_fig is not None:
        _tornado(quant, assumptions, baseline, out_fig, noise)
    return res


