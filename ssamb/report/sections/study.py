"""Report section: the parameter study (config ``study``)."""
from __future__ import annotations

from ...io import read_json
from ..context import Context
from ..elements import Image, Section, Table

__all__ = ["study"]


def study(ctx: Context) -> Section:
    """The self-sensing μ margin and the critical sweep amplitudes over one parameter."""
    sec = Section("Parameter study").add(
        "The self-sensing μ margin and the sweep amplitude at which the nonlinear and the nominal LTI models "
        "delevitate, for other values of one parameter (config `study`; each value is its own workflow job).")
    path = ctx.path("study", "study.json")
    if not path.exists():
        return sec.add("No parameter study in this run.")
    st = read_json(path)
    rows = []
    for p in st["points"]:
        ca, fit = p.get("critical_amplitude_m") or {}, p.get("fit_pct") or {}
        rows.append([p["value"], p["stable"], fit.get("x"), fit.get("y"), p.get("mu_peak"), p.get("mu_peak_hz"),
                     p.get("mu_margin"), None if ca.get("nonlinear") is None else ca["nonlinear"] * 1e6,
                     None if ca.get("nominal_lti") is None else ca["nominal_lti"] * 1e6])
    sec.add(f"Parameter: `{st['parameter']}`",
            Table(["value", "LTI loop stable", "fit x (%)", "fit y (%)", "mu peak", "at (Hz)", "mu margin",
                   "critical amplitude, nonlinear (µm)", "critical amplitude, LTI (µm)"], rows))
    return sec.add(Image(ctx.path("study", "study.png")) if ctx.path("study", "study.png").exists() else None)
