"""Report sections beyond the default run: the paper's way (scenario ``paper``) and the
assumption study (``snakemake --cores 2 study``)."""
from __future__ import annotations

from ..context import Context
from ..compare import answer_text
from ..elements import Image, Section, Table
from ..failures import failure_lines

__all__ = ["paper_way", "sensitivity"]


def paper_way(ctx: Context) -> Section:
    """The chain with the paper's structures (run ``runs/paper/``): stability, selection, μ cause."""
    P = ctx.summary.get("paper_way")
    sec = Section("The paper's way").add(
        "The whole chain again with the paper's model structures wherever the paper is explicit (config "
        "`scenarios.paper`: self-sensing from the coil current i_ypos, the 4-input amplifier, the plant on all "
        "four currents); results in `results/runs/paper/`.")
    if not P:
        return sec.add("No paper's-way run in this configuration (config `scenarios.paper`).")
    rows = [["assembled loop stable", P.get("stable")], ["spectral radius", P.get("spectral_radius")],
            ["fit x / y (%)", f"{P['fit_pct']['x']} / {P['fit_pct']['y']}" if P.get("fit_pct") else None],
            ["self-sensing μ peak", (P.get("mu") or {}).get("selfsensing", {}) and P["mu"]["selfsensing"]["peak"]],
            ["its cause (computed)", (P.get("mu_peak_cause") or {}).get("sentence")]]
    rows += [["failed", line] for line in failure_lines(P.get("failed"))]
    S = P.get("selection") or {}
    if S:
        rows += [["selection by the assembled loop", S.get("rule")],
                 ["stable combinations", f"{S.get('n_stable')} of {S.get('n_combinations')}"],
                 ["selected candidates", ", ".join(f"{k}: {v}" for k, v in (S.get("selected") or {}).items())]]
    sel = [[k, v.get("method"), ", ".join(v.get("inputs", [])), v.get("mean_fit_pct"), v.get("spectral_radius")]
           for k, v in (P.get("identification") or {}).items()]
    return sec.add(Table(["quantity", "value"], rows),
                   Table(["subsystem", "method", "inputs", "mean validation fit (%)", "spectral radius"], sel,
                         caption="The paper's structures identified per subsystem (before the selection)"))


def sensitivity(ctx: Context) -> Section:
    """The assumption study: per variant the headline numbers, the tornado charts and the
    computed answers (which assumptions reproduce which of the paper's headlines)."""
    sec = Section("Assumption study").add(
        "Every open modelling choice varied one at a time over its plausible values (config `study`), each "
        "variant a run of the whole chain; numbers relative to the study's baseline run (the config's own "
        "values with the study's common overrides).")
    st = ctx.study
    if st is None:
        return sec.add("Not in this report: `snakemake --cores 2 study` runs the study; every report built "
                       "after it holds it.")
    keys = ("fit_y_pct", "mu_peak_hz", "mu_scale_for_unity", "critical_nonlinear_um", "critical_lti_um",
            "delevitation_nonlinear_s")
    noise = st.get("noise") or {}
    rows = [[n, v.get("stable"), *[v.get(k) for k in keys],
             ", ".join(k for k, b in (v.get("beyond_noise") or {}).items() if b) or ("none" if noise else "—"),
             "; ".join(failure_lines(v["failed"]))]
            for n, v in st["variants"].items()]
    ans = st["answers"]
    band = (("Each variant is one noise realisation: a variant moves a headline only where its value leaves the "
             "noise band around the baseline (the spread of the default chain over "
             f"{max(b['K'] for b in noise.values())} noise realisations, grey in the tornado), and the answers "
             "below widen each criterion by that band.") if noise else
            "Each variant is one noise realisation; after `snakemake --cores 2 ensemble` the study (rerun) marks "
            "which variants move a headline beyond the noise.")
    return sec.add(
        band,
        Table(["variant", "LTI loop stable", "fit y (%)", "μ peak (Hz)", "μ weight scale", "critical amplitude, "
               "nonlinear (µm)", "critical amplitude, LTI (µm)", "delevitation (s)", "beyond the noise",
               "failed stages"], rows),
        Image(ctx.path("study", "tornado.png")),
        "**Which assumptions reproduce the paper's headlines (computed over the variants):** " + " ".join(
            f"Variants that {answer_text(st, k)}: {', '.join(f'`{n}`' for n in ans[k]) or 'none'}." for k in ans))
