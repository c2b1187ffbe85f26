"""Report sections around the chain: overview, the paper-versus-reproduction table and the
paper's four figures (the first page), the nonlinear simulation, provenance, and the
configuration (an appendix, folded)."""
from __future__ import annotations

import csv

import numpy as np

from ...io import load_npz, read_json
from ...provenance import source_revision, versions
from ..compare import comparison_rows
from ..config_table import config_rows
from ..context import Context, experiment
from ..describe import excitation, khz
from ..elements import Figures, Image, Plot, Section, Table

__all__ = ["overview", "comparison", "figures", "parameters", "simulation", "provenance"]


def overview(ctx: Context) -> Section:
    """Title and what the reproduction does (figures from the config)."""
    t1, c = ctx.config["table1"], ctx.config
    return Section("ssamb: μ-analysis of a self-sensing AMB, reproduced", level=1).add(
        "Reproduction and extension of *\"μ-analysis applied to self-sensing active magnetic bearings\"*. "
        "A nonlinear simulation of a 2-DOF self-sensing AMB (direct current measurement, "
        f"{khz(t1['f_pwm_hz'])} two-state PWM amplifiers, reluctance-network magnetics with eddy currents, "
        "hysteresis and saturation, PID control, the paper's Table 1) generates data; SIPPY identifies "
        "discrete-time models of the plant, the power amplifier and the self-sensing at "
        f"{khz(c['controller']['fs_hz'])}; "
        "they are assembled into a closed-loop LTI model; the mismatch to the nonlinear system becomes an "
        f"additive uncertainty weight ({c['uncertainty']['tol_db']:g} dB fit); μ-analysis gives the stability "
        "margin; an augmented model is validated in a frequency sweep. Beyond the paper, measured rig data are "
        "explained with physics.")


def comparison(ctx: Context) -> Section:
    """The paper-versus-reproduction table (:func:`ssamb.report.compare.comparison_rows`)."""
    from ..compare import CHAINS, chain_views, failure_notes

    runs = {n: ctx.path("runs", n, "summary.json") for n in CHAINS if n != "default"}
    summaries = {n: read_json(p) for n, p in runs.items() if p.exists()}
    header, rows = comparison_rows(ctx.summary, ctx.study, ctx.ensemble, summaries)
    K = (ctx.ensemble or {}).get("K")
    spread = (f"Every number is a median [min–max] over K = {K} noise realisations (converter noise, excitation "
              "phases and calibration drawn anew; config `ensemble`; (k/K): only k realisations have it)."
              if K else "Every number is one noise realisation; `snakemake --cores 2 ensemble` gives median and "
              "range over the realisations, and the literal chain and the paper's rig.")
    notes = failure_notes(chain_views(ctx.summary, ctx.ensemble, summaries))
    return Section("Paper versus reproduction").add(
        "The paper's values are quotations (section and figure in `ssamb/paper.py`); ours, the paper's way (its "
        "model structures, config `scenarios.paper`), the literal chain (its identification from the raw data with "
        "no offset term, `scenarios.paper_literal`) and the paper's rig (the open assumptions under which the "
        "nonlinear model delevitates as the paper's did, `scenarios.paper_rig`) are read from the runs. " + spread
        + " The ceiling is the fit of one nonlinear run against the others: no model can exceed it. Each \"why\" "
        "is computed from these runs and, when it has run, the assumption study.",
        Table(header, rows), *notes)


#: the paper's figures and the stage PNGs that reproduce them (the first page of the report)
PAPER_FIGURES = (
    ("model/fig4.png", "Fig. 4: the nonlinear simulation and the closed-loop LTI model, one record"),
    ("uncertainty/selfsensing_fig7.png", "Fig. 7: the self-sensing mismatch ETFE and its uncertainty weight"),
    ("mu/selfsensing_fig8.png", "Fig. 8: μ over frequency, uncertainty in the self-sensing"),
    ("validation/fig9.png", "Fig. 9: the sweep through the nonlinear, nominal and augmented models"),
)


def figures(ctx: Context) -> Section:
    """The paper's Figs. 4, 7, 8 and 9 as this run made them, side by side."""
    return Section("The paper's figures, reproduced", level=3).add(
        Figures([Image(ctx.path(*p.split("/")), cap) for p, cap in PAPER_FIGURES]),
        "Sections 2-5 below show them with their numbers, and the other subsystems' weights and μ cases.")


def parameters(ctx: Context) -> Section:
    """Appendix (folded): Table 1 and every modelling assumption with the reason written beside
    it in the config."""
    t1, assumptions = config_rows(ctx.config_path)
    sec = Section("Appendix: configuration", collapsed=True)
    return sec.add(
        f"Table 1 of the paper and every modelling assumption the paper leaves open, as used by this run "
        f"(`{ctx.config_path.name}`, with the one-line reason written beside each assumption).",
        Table(["key (unit in the name)", "value", "meaning"], t1, caption="Table 1 (the paper)"),
        Table(["key", "value", "reason"], assumptions, caption="Modelling assumptions (ours, with reasons)"))


def _liftoff_plot(lev: dict):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 3.4))
    ax[0].plot(lev["t"], lev["y_true"] * 1e6, label="y (true)")
    ax[0].plot(lev["t"], lev["y_ss"] * 1e6, "--", label="y (self-sensing)")
    ax[0].plot(lev["t"], lev["x_true"] * 1e6, label="x")
    ax[0].set(xlabel="time (s)", ylabel="position (µm)", title="lift-off from the backup bearing")
    ax[0].legend()
    ax[1].plot(lev["t"], lev["i_ypos"], lw=0.5, label="i_ypos")
    ax[1].plot(lev["t"], lev["i_yneg"], lw=0.5, label="i_yneg")
    ax[1].set(xlabel="time (s)", ylabel="coil current (A)", title="coil currents (controller-rate samples)")
    ax[1].legend()
    fig.tight_layout()
    return fig


def _selfsensing_plot(ms: dict, what: str):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 3.2))
    n = min(len(ms["t"]), int(0.5 * float(ms["fs_hz"])))
    ax.plot(ms["t"][:n], ms["y_meas"][:n] * 1e6, label="true y")
    ax.plot(ms["t"][:n], ms["y_ss"][:n] * 1e6, "--", label="DCM estimate")
    ax.set(xlabel="time (s)", ylabel="y (µm)", title=f"self-sensing during the {what} (first 0.5 s)")
    ax.legend()
    return fig


def simulation(ctx: Context) -> Section:
    """Lift-off and self-sensing against the true position in the uncertainty experiment."""
    name = ctx.config["uncertainty"]["experiment"]
    lev, lev_meta = load_npz(ctx.path("sim", "levitate.npz"))
    ms, ms_meta = load_npz(ctx.path("sim", f"{name}.npz"))
    err = ms["y_ss"] - ms["y_meas"]
    cal = ms_meta.get("selfsensing_calibration") or {}
    what = excitation(experiment(ctx, "uncertainty.experiment"))
    rows = [["self-sensing error, rms", float(np.sqrt(np.mean(err ** 2))) * 1e6, "µm"],
            ["self-sensing error, max", float(np.max(np.abs(err))) * 1e6, "µm"],
            ["calibration gain (eq. (2) to true y)", cal.get("gain"), "-"],
            ["calibration offset", None if cal.get("offset_m") is None else cal["offset_m"] * 1e6, "µm"],
            ["lift-off: rotor settled at (y)", float(lev["y_true"][-1]) * 1e6, "µm"],
            ["levitation control current u_y", lev_meta["equilibrium"]["u_y"], "A"]]
    return Section("1. The nonlinear simulation").add(
        f"Lift-off from the backup bearing (experiment `levitate`), and DCM self-sensing against the true "
        f"position during the {what} (experiment `{name}`). The y loop is closed on the self-sensing estimate; "
        "the x loop on the eddy-current sensor.",
        Plot(_liftoff_plot(lev)), Plot(_selfsensing_plot(ms, what)),
        Table(["quantity", "value", "unit"], rows, caption=f"Self-sensing in `{name}` and lift-off"))


def provenance(ctx: Context) -> Section:
    """The code (git commit, or the sources' hash), the config hashes, every package's version and
    the run time of every rule."""
    sims = ctx.summary.get("details", {}).get("simulations", {})
    hashes = sorted({v.get("config_hash") for v in sims.values() if v.get("config_hash")})
    rows = []
    for f in sorted(ctx.path("benchmarks").rglob("*.tsv")):
        with open(f) as fh:
            rec = list(csv.DictReader(fh, delimiter="\t"))
        if rec:
            rows.append([str(f.relative_to(ctx.path("benchmarks"))).replace(".tsv", ""), float(rec[0]["s"]),
                         float(rec[0]["max_rss"])])
    info = [["ssamb code", source_revision()], ["config hash (simulations)", ", ".join(hashes) or "none"]]
    return Section("Provenance").add(
        "The code that made this report, the configuration hash, the version of every package ssamb depends "
        "on, and the run time of every rule (Snakemake benchmarks).",
        Table(["item", "value"], info + [[k, v] for k, v in versions().items()]),
        Table(["rule / wildcard", "wall time (s)", "max RSS (MB)"], rows),
        f"Sum of rule run times: {sum(r[1] for r in rows):.1f} s." if rows else None)
