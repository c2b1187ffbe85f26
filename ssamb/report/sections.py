"""Cells of the report notebook, one list per section. Code cells read ``results/`` while the
notebook runs; markdown explains what the reader sees. Every number of ours comes from a file."""
from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Mapping

from nbformat.v4 import new_code_cell, new_markdown_cell

__all__ = ["all_sections"]


def _md(t):
    return new_markdown_cell(textwrap.dedent(t).strip())


def _code(t):
    return new_code_cell(textwrap.dedent(t).strip())


def _header(summary: Mapping):
    return [
        _md("""
        # ssamb: μ-analysis of a self-sensing AMB, reproduced

        Reproduction and extension of *"μ-analysis applied to self-sensing active magnetic bearings"*.
        A nonlinear simulation of a 2-DOF self-sensing AMB (direct current measurement, 30 kHz two-state
        PWM amplifiers, reluctance-network magnetics with eddy currents, hysteresis and saturation, PID
        control, the paper's Table 1) generates data; SIPPY identifies discrete-time models of the plant,
        the power amplifier and the self-sensing at 83.3 kHz; they are assembled into a closed-loop LTI
        model; the mismatch to the nonlinear system becomes an additive uncertainty weight (3 dB fit);
        μ-analysis gives the stability margin; an augmented model is validated in a frequency sweep.
        Beyond the paper, measured rig data are explained with physics (last section).

        ## Paper versus reproduction

        Our values are read from `results/summary.json`; the paper's are quotations (section and figure
        in `ssamb/report/paper.py`). Each difference is explained in one sentence.
        """),
        _code("""
        from ssamb.report.compare import comparison_rows
        display(HTML(T.table(comparison_rows(S), ["quantity", "paper", "reproduction", "why"])))
        """),
    ]


def _parameters(config_path: str):
    return [
        _md("""
        ## 1. Parameters

        Table 1 of the paper and every modelling assumption the paper leaves open, as used by this run
        (from `config.yaml`, with the one-line reason written beside each assumption).
        """),
        _code(f"""
        from ssamb.report.config_table import config_rows
        t1, assumptions = config_rows({config_path!r})
        display(Markdown("**Table 1 (the paper)**"))
        display(HTML(T.table(t1, ["key (unit in the name)", "value", "meaning"])))
        display(Markdown("**Modelling assumptions (ours, with reasons)**"))
        display(HTML(T.table(assumptions, ["key", "value", "reason"])))
        """),
    ]


def _simulation():
    return [
        _md("""
        ## 2. The nonlinear simulation

        Lift-off from the backup bearing (experiment `levitate`), and DCM self-sensing against the true
        position during the 100 µm multisine. The y loop is closed on the self-sensing estimate; the
        x loop on the eddy-current sensor.
        """),
        _code("""
        from ssamb.io import load_npz
        lev, lev_meta = load_npz(R / "sim" / "levitate.npz")
        fig, ax = plt.subplots(1, 2, figsize=(11, 3.4))
        ax[0].plot(lev["t"], lev["y_true"] * 1e6, label="y (true)")
        ax[0].plot(lev["t"], lev["y_ss"] * 1e6, "--", label="y (self-sensing)")
        ax[0].plot(lev["t"], lev["x_true"] * 1e6, label="x")
        ax[0].set_xlabel("time (s)"); ax[0].set_ylabel("position (um)"); ax[0].legend(); ax[0].set_title("lift-off from the backup bearing")
        ax[1].plot(lev["t"], lev["i_ypos"], lw=0.5, label="i_ypos")
        ax[1].plot(lev["t"], lev["i_yneg"], lw=0.5, label="i_yneg")
        ax[1].set_xlabel("time (s)"); ax[1].set_ylabel("coil current (A)"); ax[1].legend(); ax[1].set_title("coil currents (83.3 kHz samples, with ripple)")
        plt.tight_layout(); plt.show()
        ms, ms_meta = load_npz(R / "sim" / "multisine.npz")
        err = ms["y_ss"] - ms["y_meas"]
        fig, ax = plt.subplots(figsize=(11, 3.2))
        n = min(len(ms["t"]), int(0.5 * float(ms["fs_hz"])))
        ax.plot(ms["t"][:n], ms["y_meas"][:n] * 1e6, label="true y")
        ax.plot(ms["t"][:n], ms["y_ss"][:n] * 1e6, "--", label="DCM estimate")
        ax.set_xlabel("time (s)"); ax.set_ylabel("y (um)"); ax.legend(); ax.set_title("self-sensing during the 100 um multisine (first 0.5 s)")
        plt.show()
        cal = ms_meta["selfsensing_calibration"]
        display(HTML(T.table([
            ["self-sensing error, rms (multisine)", float(np.sqrt(np.mean(err**2))) * 1e6, "um"],
            ["self-sensing error, max (multisine)", float(np.max(np.abs(err))) * 1e6, "um"],
            ["calibration gain (eq. (2) to true y)", cal["gain"], "-"],
            ["calibration offset", cal["offset_m"] * 1e6, "um"],
            ["lift-off: rotor settled at (y)", float(lev["y_true"][-1]) * 1e6, "um"],
            ["levitation control current u_y", lev_meta["equilibrium"]["u_y"], "A"],
        ], ["quantity", "value", "unit"])))
        """),
    ]


def _identification():
    return [
        _md("""
        ## 3. Identification (paper section 3, Fig. 4)

        SIPPY subspace models at 83.3 kHz from closed-loop data (current pulses injected before the
        amplifiers), validated on an independent run; no detrending (every model carries its operating
        point through an affine input). Methods are compared and the best validation fit is used; the
        order scan is the evidence for the orders. Where our model structure departs from the paper's,
        the paper's variant is identified too and reported.
        """),
        _code("""
        rows = []
        for sub, d in S["details"]["identification"].items():
            for m in d["methods"]:
                rows.append([sub, m["method"], m["mean_fit"], m["spectral_radius"], m["time_s"], m["error"] or ""])
        display(HTML(T.table(rows, ["subsystem", "method", "mean validation fit (%)", "spectral radius", "time (s)", "error"])))
        rows = []
        for sub, d in S["details"]["identification"].items():
            pv = d["paper_variant"] or {}
            rows.append([sub, ", ".join(d["inputs"]) + " -> " + ", ".join(d["outputs"]), d["method"], S["orders"][sub],
                         d["mean_fit_pct"], ", ".join(pv.get("inputs", [])) or "(same)", 
                         None if not pv.get("fit_pct") else float(np.mean(pv["fit_pct"]))])
        display(Markdown("**Selected models, and the paper's structural variant**"))
        display(HTML(T.table(rows, ["subsystem", "inputs -> outputs", "method", "order", "mean fit (%)", "paper variant inputs", "its mean fit (%)"])))
        for sub in S["details"]["identification"]:
            display(Image(filename=str(R / "ident" / f"{sub}_orders.png")))
            display(Image(filename=str(R / "ident" / f"{sub}_validation.png")))
        """),
        _md("""
        ### Closed-loop LTI model and Fig. 4

        The three models and the two discrete PID controllers, connected by named signals
        (`control.interconnect`). The comparison starts both models at the same operating point.
        """),
        _code("""
        A = S["details"]["assembly"]
        rows = [["assembled loop (ours)", A["stable"], A["spectral_radius"], A["order"]]]
        for k, v in A["paper_structure"].items():
            rows.append([f"paper structure: {k}", v.get("stable"), v.get("spectral_radius"), ""])
        display(HTML(T.table(rows, ["model", "stable", "spectral radius", "order"])))
        display(Image(filename=str(R / "model" / "fig4.png")))
        display(HTML(T.table([[k, v] for k, v in A["fig4_fit_pct"].items()], ["channel", "fit (%)"])))
        d = A["d2c"] or {}
        display(Markdown("**Continuous-time equivalent (Tustin inverse).** The paper warns that d2c amplifies "
                         "estimation errors by about the sampling frequency."))
        display(HTML(T.table([
            ["largest magnitude difference below 1 kHz", d.get("max_mag_error_db_below_1khz"), "dB"],
            ["largest phase difference below 1 kHz", d.get("max_phase_error_deg_below_1khz"), "deg"],
            ["largest magnitude difference up to Nyquist (unwarped axis)", d.get("max_mag_error_db"), "dB"],
            ["frequency where the difference first exceeds 1 dB", d.get("f_1db_hz"), "Hz"],
            ["largest pole-error amplification |ds/dz|, relative to fs", d.get("pole_error_gain_over_fs_max"), "-"],
        ], ["quantity", "value", "unit"])))
        """),
    ]


def _uncertainty():
    return [
        _md("""
        ## 4. Uncertainty weights (paper section 5, Fig. 7)

        The same 100 µm random-phase multisine (5–26 Hz) drives the nonlinear simulation and the LTI
        model; the ETFE of the additive mismatch (eq. (6)) is read on the excited lines of each
        subsystem's channel, an envelope is drawn through its peaks, and a strictly proper weight is
        fitted within 3 dB of it and never below the ETFE.
        """),
        _code("""
        rows = [[k, f"{v['channel']['input']} -> {v['channel']['output']}", v["unit"], v["order"], v["max_dev_db"], v["bound_holds"], v["within_tol"]]
                for k, v in S["details"]["weights"].items()]
        display(HTML(T.table(rows, ["subsystem", "channel", "unit", "weight order", "max deviation (dB)", "W >= ETFE on every line", "within 3 dB"])))
        for k in S["details"]["weights"]:
            display(Image(filename=str(R / "uncertainty" / f"{k}_fig7.png")))
        """),
    ]


def _mu():
    return [
        _md("""
        ## 5. μ-analysis (paper sections 4 and 6.2, Fig. 8)

        The generalized plant of Fig. 6 with additive uncertainty W·Δ on one subsystem (or all three,
        block-diagonal), closed with the controller (lower LFT); μ of N11 over frequency with our engine
        (`ssamb.mu.mussv`, upper and lower bounds). The margin is 1/peak: the loop tolerates every
        ‖Δ‖∞ < 1/peak; it is also the factor the weights may be scaled by before the peak reaches 1
        (the paper needed 0.0012).
        """),
        _code("""
        rows = [[k, v["peak"], v.get("peak_lower"), v["peak_hz"], v["margin"], v["scale_for_unity"], v.get("robustly_stable")]
                for k, v in S["details"]["mu"].items()]
        display(HTML(T.table(rows, ["case", "mu peak (upper)", "mu peak (lower)", "peak frequency (Hz)", "margin 1/peak", "weight scale for peak 1", "robustly stable"])))
        for k in S["details"]["mu"]:
            display(Image(filename=str(R / "mu" / f"{k}_fig8.png")))
        """),
        _md("""
        ### The baseline the paper argues against: ISO 14839-3 sensitivity and classical margins

        From the same closed-loop model, each axis's loop broken at its controller input.
        """),
        _code("""
        B = S["details"]["baseline"]
        rows = [[ax, b["peak_sensitivity"], b["peak_sensitivity_db"], b["peak_hz"], b["iso14839_zone"],
                 b["gain_margin_upper_db"], b["gain_margin_lower_db"], b["phase_margin_deg"], b["phase_margin_hz"]]
                for ax, b in B.items()]
        display(HTML(T.table(rows, ["axis", "peak |S|", "peak |S| (dB)", "at (Hz)", "ISO 14839-3 zone", "gain margin, upper (dB)",
                                    "gain margin, lower (dB)", "phase margin (deg)", "at (Hz)"])))
        """),
    ]


def _validation():
    return [
        _md("""
        ## 6. Sweep validation (paper section 6, Fig. 9)

        The sweep reference drives the nonlinear simulation, the nominal LTI model and the augmented
        models (self-sensing model + W·Δ with Δ = +1, −1 and a first-order all-pass). Delevitation is
        the rotor reaching the backup-bearing clearance. Because an LTI model responds linearly, the
        sweep amplitude at which it would delevitate is exact; the nonlinear model's is bisected over
        simulations. Comparing them validates the uncertainty model quantitatively.
        """),
        _code("""
        V = S["details"]["validation"]
        sw = V["sweep"]
        display(Markdown(f"Sweep: {sw['amplitude_m']*1e6:.4g} um on {sw['axis']}, {sw['f_start_hz']:g} to {sw['f_stop_hz']:g} Hz in {sw['sweep_duration_s']:g} s ({sw['law']}); clearance {V['clearance_m']*1e6:.4g} um."))
        rows = [[o["model"], o["delevitates"], o["time_s"], o["sweep_hz"], o["max_radial_m"] * 1e6 if o["max_radial_m"] == o["max_radial_m"] else None,
                 None if o.get("critical_amplitude_m") is None else o["critical_amplitude_m"] * 1e6] for o in V["outcomes"]]
        display(HTML(T.table(rows, ["model", "delevitates", "time (s)", "sweep frequency then (Hz)", "max radial (um)", "critical sweep amplitude (um)"])))
        display(Image(filename=str(R / "validation" / "fig9.png")))
        """),
    ]


def _study():
    return [
        _md("""
        ## Parameter study

        The self-sensing μ margin and the sweep amplitude at which the nonlinear and the nominal LTI
        models delevitate, for other values of one parameter (config `study`; each value is its own
        workflow job, so the study spreads over a cluster).
        """),
        _code("""
        st_path = R / "study" / "study.json"
        if st_path.exists():
            st = json.loads(st_path.read_text())
            rows = []
            for p in st["points"]:
                ca = p.get("critical_amplitude_m") or {}
                rows.append([p["value"], p["stable"], (p.get("fit_pct") or {}).get("x"), (p.get("fit_pct") or {}).get("y"),
                             p.get("mu_peak"), p.get("mu_peak_hz"), p.get("mu_margin"),
                             None if ca.get("nonlinear") is None else ca["nonlinear"] * 1e6,
                             None if ca.get("nominal_lti") is None else ca["nominal_lti"] * 1e6])
            display(Markdown(f"Parameter: `{st['parameter']}`"))
            display(HTML(T.table(rows, ["value", "LTI loop stable", "fit x (%)", "fit y (%)", "mu peak", "at (Hz)", "mu margin", "critical amplitude, nonlinear (um)", "critical amplitude, LTI (um)"])))
            if (R / "study" / "study.png").exists():
                display(Image(filename=str(R / "study" / "study.png")))
        else:
            display(Markdown("No parameter study in this run."))
        """),
    ]


def _provenance():
    return [
        _md("""
        ## Provenance

        Configuration hash, package versions, the git commit of the code, and the run time of every
        rule (Snakemake benchmarks).
        """),
        _code("""
        import subprocess, csv
        from ssamb.io import versions
        try:
            commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=R.parent).stdout.strip() or "unknown"
        except Exception:
            commit = "unknown"
        sims = S["details"]["simulations"]
        hashes = sorted({v.get("config_hash") for v in sims.values() if v.get("config_hash")})
        display(HTML(T.table([["git commit", commit], ["config hash (simulations)", ", ".join(hashes)]] + [[k, v] for k, v in versions().items()], ["item", "value"])))
        rows = []
        for f in sorted((R / "benchmarks").rglob("*.tsv")):
            rec = list(csv.DictReader(open(f), delimiter="\\t"))
            if rec:
                rows.append([str(f.relative_to(R / "benchmarks")).replace(".tsv", ""), float(rec[0]["s"]), float(rec[0]["max_rss"])])
        display(HTML(T.table(rows, ["rule / wildcard", "wall time (s)", "max RSS (MB)"])))
        display(Markdown(f"Sum of rule run times: {sum(r[1] for r in rows):.1f} s."))
        """),
    ]


def all_sections(results_dir: Path, summary: Mapping, config_path: str | None = None,
                 closeloop_dir: str | None = None) -> list:
    from ..closeloop.section import section_cells

    secs = [_header(summary), _parameters(config_path or "config.yaml"), _simulation(), _identification(),
            _uncertainty(), _mu(), _validation()]
    if closeloop_dir is not None:
        secs.append([_md("## 7. Close the loop with measured data (beyond the paper)")]
                    + section_cells(closeloop_dir, title="The chain on the default rig data set"))
    secs.append(_study())
    secs.append(_provenance())
    return secs
