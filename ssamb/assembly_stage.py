r"""The ``assemble`` stage: closed-loop LTI model, its continuous equivalent and Fig. 4.

:func:`run_assemble` interconnects the three identified subsystem models with the discrete
PID controllers (:func:`ssamb.loop.assemble_closed_loop`), reports the stability of the
result and of the paper's structural variant, converts the loop to continuous time (Tustin
inverse; the error of the conversion is quantified on the frequency response), and compares
the LTI model with the nonlinear simulation on the Fig. 4 experiment.

Initial state for the comparison: the nonlinear run starts from its settled operating point
with no injection (the pre-roll), so the LTI model starts at its equilibrium for the
references at t = 0 and zero injection -- not for the first input sample, which would put a
pulse's DC response into the initial state.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import control
import numpy as np

from .ident import load_model, nrmse_fit
from .io import load_npz, save_npz, write_json
from .loop import (assemble_closed_loop, d2c_error, d2c_pole_sensitivity, equilibrium,
                   simulate_closed_loop, stability, to_continuous)

__all__ = ["run_assemble", "save_statespace", "load_statespace", "lti_initial_state"]

FIG4_CHANNELS = ("x_meas", "y_meas", "y_ss", "i_ypos", "i_yneg", "i_xpos", "i_xneg", "u_x", "u_y")


def save_statespace(path: str | Path, sys: control.StateSpace, meta: Mapping | None = None) -> None:
    """Write a named state-space system (NPZ arrays + JSON sidecar with names and dt)."""
    info = {"inputs": list(sys.input_labels), "outputs": list(sys.output_labels),
            "dt": 0.0 if not sys.dt else float(sys.dt), "name": sys.name, **(meta or {})}
    save_npz(path, {"A": np.asarray(sys.A), "B": np.asarray(sys.B), "C": np.asarray(sys.C),
                    "D": np.asarray(sys.D)}, info)


def load_statespace(path: str | Path) -> control.StateSpace:
    arrays, meta = load_npz(path)
    dt = meta.get("dt", 0.0) or 0
    return control.ss(arrays["A"], arrays["B"], arrays["C"], arrays["D"], dt,
                      inputs=meta["inputs"], outputs=meta["outputs"], name=meta.get("name", "sys"))


def lti_initial_state(cl: control.StateSpace, r_x0: float = 0.0, r_y0: float = 0.0) -> np.ndarray:
    """Equilibrium of the closed loop for constant references and no injection."""
    w0 = np.array([{"r_x": r_x0, "r_y": r_y0, "one": 1.0}.get(n, 0.0) for n in cl.input_labels])
    return equilibrium(cl, w0)


def run_assemble(models: Mapping[str, str | Path], paper_models: Mapping[str, str | Path],
                 fig4_npz: str | Path, pid_params: Mapping, out_discrete: str | Path,
                 out_continuous: str | Path, out_json: str | Path, out_fig: str | Path | None = None,
                 continuous_method: str = "tustin") -> dict:
    """Assemble the closed loop, convert it, compare it on Fig. 4; write the files.

    Parameters
    ----------
    models : mapping
        ``plant``, ``amplifier``, ``selfsensing`` -> selected model files (``identify``).
    paper_models : mapping
        The same for the paper's structural variants (evidence).
    fig4_npz : path
        The nonlinear simulation of the Fig. 4 experiment.
    pid_params : mapping
        The config sections the PID needs (``table1``, ``controller``).
    """
    from .sim.controller import pid_discrete

    pid = pid_discrete(pid_params)
    m = {k: load_model(v) for k, v in models.items()}
    cl = assemble_closed_loop(m["plant"], m["amplifier"], m["selfsensing"], pid, pid)
    rep = stability(cl)
    # the paper's structure, subsystem by subsystem and all together (evidence)
    variants = {}
    for k, path in paper_models.items():
        mm = dict(m)
        mm[k] = load_model(path)
        try:
            v = assemble_closed_loop(mm["plant"], mm["amplifier"], mm["selfsensing"], pid, pid)
            variants[k] = {"spectral_radius": stability(v).spectral_radius, "stable": stability(v).stable,
                           "inputs": list(mm[k].input_names)}
        except ValueError as exc:
            variants[k] = {"error": str(exc)}
    if paper_models:
        mm = {k: load_model(paper_models[k]) if k in paper_models else m[k] for k in m}
        try:
            v = assemble_closed_loop(mm["plant"], mm["amplifier"], mm["selfsensing"], pid, pid)
            variants["all"] = {"spectral_radius": stability(v).spectral_radius, "stable": stability(v).stable}
        except ValueError as exc:
            variants["all"] = {"error": str(exc)}
    info = {
        "stable": rep.stable,
        "spectral_radius": rep.spectral_radius,
        "order": int(np.asarray(cl.A).shape[0]),
        "inputs": list(cl.input_labels),
        "outputs": list(cl.output_labels),
        "subsystem_orders": {k: v.order for k, v in m.items()},
        "subsystem_inputs": {k: list(v.input_names) for k, v in m.items()},
        "paper_structure": variants,
        "continuous_method": continuous_method,
    }
    save_statespace(out_discrete, cl, {"stable": rep.stable})
    if rep.stable:
        clc = to_continuous(cl, continuous_method)
        freqs = np.logspace(-1, np.log10(0.45 / float(cl.dt)), 300)
        err = d2c_error(cl, clc, freqs, warp=False)
        sens = d2c_pole_sensitivity(cl, continuous_method)
        info["d2c"] = {"max_mag_error_db_below_1khz": _max_below(err, 1e3, "mag_db"),
                       "max_phase_error_deg_below_1khz": _max_below(err, 1e3, "phase_deg"),
                       "max_mag_error_db": err["max_abs_mag_db"],
                       "max_phase_error_deg": err["max_abs_phase_deg"],
                       "f_1db_hz": err["f_1db_hz"],
                       "pole_error_gain_max": float(np.max(np.abs(sens["gain"]))),
                       "pole_error_gain_over_fs_max": float(np.max(np.abs(sens["gain_over_fs"])))}
    else:
        clc = cl
        info["d2c"] = None
    save_statespace(out_continuous, clc, {"stable": rep.stable, "method": continuous_method})
    # Fig. 4
    nl, _ = load_npz(fig4_npz)
    fits = {}
    if rep.stable:
        x0 = lti_initial_state(cl, float(nl["r_x"][0]), float(nl["r_y"][0]))
        out = simulate_closed_loop(cl, nl["t"], nl["r_x"], nl["r_y"], nl.get("inj_x"), nl.get("inj_y"), x0=x0)
        fits = {c: float(nrmse_fit(nl[c], out[c])) for c in FIG4_CHANNELS}
        if out_fig is not None:
            from .figures import fig4

            fig4(nl, out, fits, out_fig)
    elif out_fig is not None:
        from .figures import fig4

        fig4(nl, {k: np.full_like(np.asarray(nl["t"], float), np.nan) for k in ("x_meas", "y_meas")},
             {"x_meas": float("nan"), "y_meas": float("nan")}, out_fig)
    info["fig4_fit_pct"] = fits
    info["fit_pct"] = {"x": fits.get("x_meas"), "y": fits.get("y_meas")}
    write_json(out_json, info)
    return info


def _max_below(err: Mapping, f_max: float, key: str):
    if key not in err or "freqs_hz" not in err:
        return None
    f = np.asarray(err["freqs_hz"])
    v = np.asarray(err[key])
    sel = f <= f_max
    return float(np.nanmax(np.abs(v[sel]))) if sel.any() else None
