"""The report section "Close the loop with measured data": notebook cells that walk the chain.

:func:`section_cells` returns markdown and code cells (nbformat) for the HTML report built by
:mod:`ssamb.report`: replay, residual, signatures, fit, before/after. The code cells read
``closeloop.json`` and the figures of one analysis directory while the notebook runs (no
number is typed into the report).
"""
from __future__ import annotations

import textwrap
from pathlib import Path

__all__ = ["section_cells"]


def section_cells(closeloop_dir: str | Path, title: str = "Close the loop with measured data") -> list:
    """Cells of the report section for the analysis in ``closeloop_dir``."""
    from nbformat.v4 import new_code_cell, new_markdown_cell

    def md(t):
        return new_markdown_cell(textwrap.dedent(t).strip())

    def code(t):
        return new_code_cell(textwrap.dedent(t).strip())

    d = str(Path(closeloop_dir).resolve())
    return [
        md(f"""
        ## {title}

        The paper's conclusion is that an LTI uncertainty model cannot explain nonlinear
        behaviour. Here the residual between measured data and the nominal nonlinear model is
        explained with physics: replay the model with the recorded excitation, read the residual,
        rank the library effects by the signature each predicts, fit the leading ones by
        simulation, and keep those that lower the error on held-out data until the residual is
        noise. All errors below are on the held-out part of the record.
        """),
        code(f"""
        CL = Path({d!r})
        C = json.loads((CL / "closeloop.json").read_text())

        def fmt(x, spec=".3g"):
            return "-" if x is None else format(x, spec)

        v = C["validation"]
        display(Markdown(f"**Data**: `{{C['data']['source']}}`, {{C['data']['duration_s']:.2f}} s, excitation "
                         f"`{{C['data']['excitation'].get('kind')}}` on axes {{', '.join(C['data']['excited_axes'])}}; "
                         f"fitted on {{v['fit_s'][0]:.2f}}-{{v['fit_s'][1]:.2f}} s, held out {{v['holdout_s'][0]:.2f}}-{{v['holdout_s'][1]:.2f}} s. "
                         f"**Result**: {{C['summary']}}."))
        """),
        md("""
        ### 1-2. Replay and residual
        Residual (measured minus model) of every channel on the held-out part, with the nominal
        model and with the effects found, and its spectrum against the noise floor estimated from
        the frequencies the excitation does not touch.
        """),
        code("""
        display(Image(filename=str(CL / "residual_time.png")))
        display(Image(filename=str(CL / "residual_spectra.png")))
        """),
        md("""
        ### 3. Signatures: evidence before any fitting
        Each library effect predicts a signature (a phase lag linear in frequency, a flat gain
        ratio, current offsets without a position offset, a line in both axes in quadrature, a
        common-mode current shift, cross-axis coherence); the bars are the residual chi-square
        each signature accounts for.
        """),
        code("""
        display(Image(filename=str(CL / "evidence.png")))
        rows = [(n, fmt(e["score_chi2"]), fmt(e["log10_p"], ".1f"), "yes" if e["significant"] else "no", e["signature"])
                for n, e in C["evidence"].items()]
        display(HTML("<table><tr><th>effect</th><th>explained chi2</th><th>log10 p</th><th>candidate</th><th>signature</th></tr>"
                     + "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows) + "</table>"))
        if (CL / "sensor_ratio.png").exists():
            display(Image(filename=str(CL / "sensor_ratio.png")))
        """),
        md("""
        ### 4. Fit: candidates tried, kept or rejected
        Every candidate is fitted by simulation on the fitting part and judged on the held-out
        part (improvement test, BIC, share of the residual excess explained, no channel made
        worse, its own signature gone).
        """),
        code("""
        rows = []
        for r in C["rounds"]:
            for c in r["candidates"]:
                rows.append((r["round"], c["name"], ", ".join(f"{k} = {fmt(v, '.4g')}" for k, v in c["theta"].items()),
                             fmt(c["holdout_z"]), fmt(100 * c["explained"], ".0f") + " %", "kept" if c["passed"] else "; ".join(c["reasons"])))
        display(HTML("<table><tr><th>round</th><th>candidate</th><th>fit</th><th>held-out z</th><th>explained</th><th>verdict</th></tr>"
                     + "".join("<tr>" + "".join(f"<td>{x}</td>" for x in r) + "</tr>" for r in rows) + "</table>"))
        """),
        md("""
        ### 5. Effects found and the error before and after
        """),
        code("""
        rows = [(e["name"], ", ".join(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}" for k, v in e["params"].items()),
                 ", ".join(f"{k}: {fmt(v, '.2g')}" for k, v in e.get("uncertainty", {}).items()), fmt(100 * e["error_reduction"], ".0f") + " %")
                for e in C["effects"]]
        display(HTML("<table><tr><th>effect</th><th>parameters</th><th>standard error</th><th>share of the error removed</th></tr>"
                     + "".join("<tr>" + "".join(f"<td>{x}</td>" for x in r) + "</tr>" for r in rows) + "</table>"))
        chans = ["x_meas", "y_meas", "y_ss", "currents", "u_x", "u_y"]
        b, a = C["error_before"], C["error_after"]
        display(HTML("<table><tr><th>channel</th><th>rms before</th><th>rms after</th><th>noise rms</th><th>fit % before</th><th>fit % after</th></tr>"
                     + "".join(f"<tr><td>{c}</td><td>{fmt(b[c]['rms'])}</td><td>{fmt(a[c]['rms'])}</td><td>{fmt(b[c].get('noise_rms'))}</td>"
                               f"<td>{fmt(b[c]['fit_pct'], '.2f')}</td><td>{fmt(a[c]['fit_pct'], '.2f')}</td></tr>" for c in chans) + "</table>"))
        if C["unexplained"]:
            display(Markdown("**Unexplained residual** (no library effect accounts for it): "
                             + "; ".join(f"{t}: {len(v)} finding(s)" for t, v in C["remaining_signature"].items())))
        if C.get("notes"):
            display(Markdown("**Notes**: " + " ".join(f"({i + 1}) {n}." for i, n in enumerate(C["notes"]))))
        display(Image(filename=str(CL / "whiteness.png")))
        """),
    ]
