r"""The ``uncertainty`` and ``mu`` stages (paper sections 4-5, Figs. 7-8).

:func:`run_uncertainty` -- the same random-phase multisine reference drives the nonlinear
simulation and the closed-loop LTI model; for one subsystem the ETFE of the additive mismatch
(eq. (6)) is measured on the excited lines of its channel pair, an envelope is drawn through
the peaks and a strictly proper weight W(s) is fitted within ``tol_db`` of it and never below
the ETFE on a line.

Channel pairs (input -> output of each subsystem's SISO view along the excited direction):
self-sensing: its model input -> ``y_ss``; amplifier: ``u_y_cmd`` -> ``i_ypos``; plant:
``i_ypos`` -> ``y_meas`` (the multisine drives the y reference, so the y channels carry it).

:func:`run_mu` -- the generalized plant of Fig. 6 (:mod:`ssamb.uncertainty_loop`) for a case
(self-sensing, amplifier, plant, or all three block-diagonally), N11 over a log grid refined
around the peak, the structured singular value bounds (:func:`ssamb.mu.mussv`), the peak, its
frequency, the margin and the factor the weights must be scaled by to bring the peak to 1
(the paper needed 0.0012). The baseline the paper argues against -- the ISO 14839-3 peak
sensitivity of each axis and the classical margins -- comes from the same closed loop.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import control
import numpy as np

from .assembly_stage import load_statespace, lti_initial_state
from .ident import load_model
from .io import load_npz, save_npz, write_json

__all__ = ["channel_pair", "run_uncertainty", "load_weight", "run_mu", "run_baseline"]


def channel_pair(subsystem: str, ss_input: str = "y_meas") -> tuple[str, str]:
    if subsystem == "selfsensing":
        return ss_input, "y_ss"
    if subsystem == "amplifier":
        return "u_y_cmd", "i_ypos"
    if subsystem == "plant":
        return "i_ypos", "y_meas"
    raise ValueError(f"subsystem '{subsystem}': must be selfsensing, amplifier or plant")


def _signal(d: Mapping, name: str) -> np.ndarray:
    if name == "u_y_cmd":
        return np.asarray(d["u_y"], float) + np.asarray(d.get("inj_y", 0.0), float)
    if name == "u_x_cmd":
        return np.asarray(d["u_x"], float) + np.asarray(d.get("inj_x", 0.0), float)
    return np.asarray(d[name], float)


def run_uncertainty(multisine_npz: str | Path, closed_loop_npz: str | Path, selfsensing_model: str | Path,
                    subsystem: str, params: Mapping, out_npz: str | Path, out_json: str | Path,
                    out_fig: str | Path | None = None) -> dict:
    """Measure the additive mismatch of one subsystem and fit its weight (Fig. 7).

    ``params``: ``tol_db``, ``max_order``, ``n_transient_periods``, ``k_sigma`` (the envelope is
    drawn through the ETFE magnitude plus ``k_sigma`` standard deviations of its period-to-period
    spread, so that noise cannot push a line above the weight), ``max_curvature_db_per_decade2``.
    """
    from .loop import simulate_closed_loop
    from .uncertainty import additive_mismatch, fit_weight, peak_envelope

    nl, meta = load_npz(multisine_npz)
    exc = meta.get("excitation", {})
    if "lines_hz" not in exc:
        raise ValueError(f"{multisine_npz}: not a multisine experiment (no lines in its meta)")
    fs = float(nl["fs_hz"])
    spp = int(exc["samples_per_period"])
    lines_hz = np.asarray(exc["lines_hz"], float)
    bins = np.rint(lines_hz * spp / fs).astype(int)
    cl = load_statespace(closed_loop_npz)
    x0 = lti_initial_state(cl, float(nl["r_x"][0]), float(nl["r_y"][0]))
    lti = simulate_closed_loop(cl, nl["t"], nl["r_x"], nl["r_y"], x0=x0)
    ss_in = list(load_model(selfsensing_model).input_names)[0]
    u_name, y_name = channel_pair(subsystem, ss_in)
    n_per = len(nl["t"]) // spp
    mm = additive_mismatch(_signal(nl, u_name)[: n_per * spp], _signal(nl, y_name)[: n_per * spp],
                           _signal(lti, u_name)[: n_per * spp], _signal(lti, y_name)[: n_per * spp],
                           fs_hz=fs, samples_per_period=spp, lines_bins=bins,
                           n_transient_periods=int(params["n_transient_periods"]))
    k_sigma = float(params["k_sigma"])
    target = mm.upper(k_sigma) if k_sigma > 0 else mm.mag
    env = peak_envelope(mm.freqs_hz, target,
                        max_curvature_db_per_decade2=float(params["max_curvature_db_per_decade2"]))
    fit = fit_weight(mm.freqs_hz, env, target, tol_db=float(params["tol_db"]),
                     max_order=int(params["max_order"]))
    w_at = fit.mag(mm.freqs_hz)
    info = {
        "subsystem": subsystem,
        "channel": {"input": u_name, "output": y_name},
        "lines_hz": mm.freqs_hz.tolist(),
        "etfe_mag": np.asarray(mm.mag).tolist(),
        "etfe_std": np.asarray(mm.std).tolist(),
        "envelope_target_mag": np.asarray(target).tolist(),
        "weight": {"gain": float(fit.gain), "zeros_hz": list(map(float, fit.zeros_hz)),
                   "poles_hz": list(map(float, fit.poles_hz)), "order": int(fit.order)},
        "weight_mag_at_lines": np.asarray(w_at).tolist(),
        "max_dev_db": float(fit.max_dev_db),
        "within_tol": bool(fit.within_tol),
        "bound_holds": bool(fit.bound_holds),
        "min_margin_db": float(fit.min_margin_db),
        "gain_raise_db": float(fit.gain_raise_db),
        "tol_db": float(params["tol_db"]),
        "k_sigma": k_sigma,
        "unit": _unit(u_name, y_name),
        "model_etfe_mag": np.abs(mm.model.g).tolist(),
        "real_etfe_mag": np.abs(mm.real.g).tolist(),
    }
    save_npz(out_npz, {"gain": np.asarray(fit.gain), "zeros_hz": np.asarray(fit.zeros_hz, float),
                       "poles_hz": np.asarray(fit.poles_hz, float)}, {"subsystem": subsystem, **info["weight"]})
    write_json(out_json, info)
    if out_fig is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from .figures import save
        from .uncertainty import plot_weight

        fig, ax = plt.subplots(figsize=(8.5, 4.0))
        plot_weight(ax, fit, mm.freqs_hz, mm.mag, unit=info["unit"],
                    title=f"Fig. 7 equivalent: additive uncertainty weight, {subsystem} ({u_name} -> {y_name})")
        save(fig, out_fig)
    return info


def _unit(u: str, y: str) -> str:
    uu = "m" if u in ("y_meas", "x_meas") else "A"
    yu = "m" if y in ("y_meas", "x_meas", "y_ss") else "A"
    return f"{yu}/{uu}"


def load_weight(path: str | Path) -> control.TransferFunction:
    r"""Rebuild :math:`W(s) = K \prod(1 + s/\omega_z)/\prod(1 + s/\omega_p)` from a weight file."""
    arrays, _ = load_npz(path)
    s = control.tf("s")
    w = control.tf([float(arrays["gain"])], [1.0])
    for fz in np.atleast_1d(arrays["zeros_hz"]):
        w = w * (1 + s / (2 * np.pi * float(fz)))
    for fp in np.atleast_1d(arrays["poles_hz"]):
        w = w / (1 + s / (2 * np.pi * float(fp)))
    return w


def _loop_from_files(models: Mapping[str, str | Path], pid_params: Mapping):
    from .sim.controller import pid_discrete
    from .uncertainty_loop import uncertainty_loop

    pid = pid_discrete(pid_params)
    m = {k: load_model(v) for k, v in models.items()}
    return uncertainty_loop(m["plant"], m["amplifier"], m["selfsensing"], pid, pid)


def run_mu(models: Mapping[str, str | Path], weights: Mapping[str, str | Path], case: str,
           pid_params: Mapping, params: Mapping, out_json: str | Path, out_npz: str | Path,
           out_fig: str | Path | None = None) -> dict:
    """μ over frequency for one uncertainty case (Fig. 8) and its margins.

    ``params``: ``f_min_hz``, ``f_max_hz``, ``n_points`` (log grid), ``refine`` (bool).
    """
    from .robust import mu_frequency_response
    from .uncertainty_loop import case_structure, n11_function

    loop = _loop_from_files(models, pid_params)
    w = {k: load_weight(v) for k, v in weights.items()}
    blk = case_structure(case)
    f = n11_function(loop, w, case)
    freqs = np.logspace(np.log10(float(params["f_min_hz"])), np.log10(float(params["f_max_hz"])),
                        int(params["n_points"]))
    sweep = mu_frequency_response(f, freqs, blk, refine=bool(params["refine"]))
    d = sweep.as_dict()
    info = {"case": case, "blk": blk, "peak": float(sweep.peak), "peak_hz": float(sweep.peak_hz),
            "peak_lower": float(sweep.peak_lower), "margin": float(sweep.margin),
            "margin_difference": float(sweep.margin_difference),
            "scale_for_unity": float(sweep.scale_for_unity),
            "robustly_stable": bool(sweep.peak < 1.0),
            "weights": sorted(w)}
    info.update({k: v for k, v in d.items() if k not in info and not isinstance(v, (list, np.ndarray))})
    save_npz(out_npz, {"freqs_hz": np.asarray(sweep.freqs_hz), "upper": np.asarray(sweep.upper),
                       "lower": np.asarray(sweep.lower)}, {"case": case})
    write_json(out_json, info)
    if out_fig is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from .figures import save

        fig, ax = plt.subplots(figsize=(8.5, 3.8))
        ax.loglog(sweep.freqs_hz, sweep.upper, label="upper bound")
        ax.loglog(sweep.freqs_hz, sweep.lower, "--", label="lower bound")
        ax.axhline(1.0, color="k", lw=0.8)
        ax.plot([sweep.peak_hz], [sweep.peak], "rv", label=f"peak {sweep.peak:.3g} at {sweep.peak_hz:.3g} Hz")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("mu (-)")
        ax.set_title(f"Fig. 8 equivalent: mu for additive uncertainty, case '{case}'")
        ax.legend(fontsize=8)
        save(fig, out_fig)
    return info


def run_baseline(closed_loop_npz: str | Path, models: Mapping[str, str | Path], pid_params: Mapping,
                 params: Mapping, out_json: str | Path) -> dict:
    """ISO 14839-3 peak sensitivity per axis and the classical margins (the paper's baseline).

    The sensitivity of each axis is measured where its sensor signal enters the controller
    (x: ``x_meas``, y: ``y_ss``), with the other axis closed: :math:`S = 1/(1 + L)` of the loop
    broken at the controller input.
    """
    from .robust import sensitivity_peak
    from .sim.controller import pid_discrete

    pid = pid_discrete(pid_params)
    m = {k: load_model(v) for k, v in models.items()}
    freqs = np.logspace(np.log10(float(params["f_min_hz"])), np.log10(float(params["f_max_hz"])),
                        int(params["n_points"]))
    out = {}
    for axis in ("x", "y"):
        L = _loop_transfer(m, pid, axis)
        sp = sensitivity_peak(L, freqs, kind="L")
        mg = loop_margins(L, np.logspace(-1, np.log10(0.45 / float(L.dt)), 20000))
        out[axis] = {"peak_sensitivity": float(sp.peak), "peak_sensitivity_db": float(sp.peak_db),
                     "peak_hz": float(sp.peak_hz), "iso14839_zone": sp.zone, **mg}
    write_json(out_json, out)
    return out


def loop_margins(L: control.LTI, freqs_hz: np.ndarray) -> dict:
    r"""Classical margins of a SISO loop that may be open-loop unstable (conditionally stable).

    On a dense grid: every gain crossover (:math:`|L| = 1`) gives a phase margin
    :math:`180° + \angle L` (wrapped), and every phase crossover (:math:`\angle L = \pm 180°`,
    i.e. L real negative) gives a gain factor :math:`1/|L|`. For an open-loop unstable plant
    the loop has an *upper* gain margin (factor > 1 before instability) and a *lower* one
    (reduction factor < 1): both are reported, with the smallest phase margin. (A margin
    computed for a stable open loop, such as ``control.stability_margins``, does not apply.)
    """
    f = np.asarray(freqs_hz, float)
    w = 2 * np.pi * f
    arg = np.exp(1j * w * L.dt) if L.dt else 1j * w
    Lw = np.asarray(L(arg)).reshape(-1)
    mag = np.abs(Lw)
    ph = np.degrees(np.angle(Lw))
    pm, f_pm = [], []
    for i in np.flatnonzero(np.diff(np.sign(mag - 1.0)) != 0):
        a = (1.0 - mag[i]) / (mag[i + 1] - mag[i])
        p = ph[i] + a * (((ph[i + 1] - ph[i]) + 180) % 360 - 180)
        pm.append(((180.0 + p) + 180) % 360 - 180)
        f_pm.append(f[i] + a * (f[i + 1] - f[i]))
    up, low, f_up, f_low = [], [], [], []
    im = Lw.imag
    for i in np.flatnonzero(np.diff(np.sign(im)) != 0):
        a = im[i] / (im[i] - im[i + 1])
        re = Lw.real[i] + a * (Lw.real[i + 1] - Lw.real[i])
        if re >= 0:
            continue
        k = 1.0 / abs(re)
        fc = f[i] + a * (f[i + 1] - f[i])
        (up if k > 1 else low).append(k)
        (f_up if k > 1 else f_low).append(fc)
    res = {"phase_margin_deg": None, "phase_margin_hz": None, "gain_margin_upper_db": None,
           "gain_margin_upper_hz": None, "gain_margin_lower_db": None, "gain_margin_lower_hz": None,
           "gain_crossovers_hz": [float(x) for x in f_pm]}
    if pm:
        j = int(np.argmin(np.abs(pm)))
        res["phase_margin_deg"], res["phase_margin_hz"] = float(abs(pm[j])), float(f_pm[j])
    if up:
        j = int(np.argmin(up))
        res["gain_margin_upper_db"], res["gain_margin_upper_hz"] = float(20 * np.log10(up[j])), float(f_up[j])
    if low:
        j = int(np.argmax(low))
        res["gain_margin_lower_db"], res["gain_margin_lower_hz"] = float(20 * np.log10(low[j])), float(f_low[j])
    return res


def _f(v):
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def _loop_transfer(m, pid, axis: str) -> control.StateSpace:
    """Loop transfer L of one axis broken at the controller input (other axis closed)."""
    import warnings

    from .loop import as_statespace

    P = as_statespace(m["plant"], name="plant")
    G = as_statespace(m["amplifier"], name="amplifier")
    S = as_statespace(m["selfsensing"], name="selfsensing")
    dt = float(P.dt)
    Cx = control.ss(pid.A, pid.B, pid.C, pid.D, dt, inputs=["e_x"], outputs=["u_x"], name="pid_x")
    Cy = control.ss(pid.A, pid.B, pid.C, pid.D, dt, inputs=["e_y"], outputs=["u_y"], name="pid_y")
    meas = "x_meas" if axis == "x" else "y_ss"
    blocks = [P, G, S, Cx, Cy,
              control.summing_junction(inputs=["u_x"], output="u_x_cmd", dt=dt, name="sx"),
              control.summing_junction(inputs=["u_y"], output="u_y_cmd", dt=dt, name="sy")]
    if axis == "x":
        blocks.append(control.summing_junction(inputs=["-y_ss"], output="e_y", dt=dt, name="ey"))
        blocks.append(control.summing_junction(inputs=["e_in"], output="e_x", dt=dt, name="ex"))
    else:
        blocks.append(control.summing_junction(inputs=["-x_meas"], output="e_x", dt=dt, name="ex"))
        blocks.append(control.summing_junction(inputs=["e_in"], output="e_y", dt=dt, name="ey"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # break the loop at the controller input: e_in enters the controller, the measurement
        # comes back; with e = r - meas closing it, L = meas/e_in and S = 1/(1 + L)
        sys = control.interconnect(blocks, inplist=["e_in"], inputs=["e_in"], outlist=[meas], outputs=[meas])
    return control.ss(sys.A, sys.B, sys.C, sys.D, dt)
