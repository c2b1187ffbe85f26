r"""Stage ``uncertainty``: the additive mismatch of one subsystem and its weight (section 5, Fig. 7).

The same random-phase multisine reference drives the nonlinear simulation (its recorded run)
and the closed-loop LTI model; for one subsystem the ETFE of the additive mismatch (eq. (6)) is
measured on the excited lines of its channel pair (:func:`ssamb.channels.etfe_pair`), an
envelope is drawn through the peaks and a strictly proper weight W(s) is fitted within
``tol_db`` of it and never below the ETFE on a line (:func:`ssamb.uncertainty.measure_weight`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ..channels import ONE, etfe_pair, signal
from ..closed_loop import lti_initial_state, simulate_closed_loop, stability
from ..io import DataError, write_json
from ..model_io import load_model, load_record, load_statespace, save_weight
from ..uncertainty import measure_weight

__all__ = ["run_uncertainty"]

_METRES = ("x_meas", "y_meas", "y_ss")


def _unit(u: str, y: str) -> str:
    return f"{'m' if y in _METRES else 'A'}/{'m' if u in _METRES else 'A'}"


def run_uncertainty(multisine_npz: str | Path, closed_loop_npz: str | Path, selfsensing_model: str | Path,
                    subsystem: str, params: Mapping, out_npz: str | Path, out_json: str | Path,
                    out_fig: str | Path | None = None) -> dict:
    """Measure the additive mismatch of one subsystem and fit its weight (Fig. 7).

    ``params`` is the config section ``uncertainty``: ``tol_db``, ``max_order``,
    ``n_transient_periods``, ``k_sigma``, ``max_curvature_db_per_decade2``.
    """
    nl, meta = load_record(multisine_npz)
    exc = meta.get("excitation", {})
    if "lines_hz" not in exc:
        raise DataError(f"{multisine_npz}: not a multisine experiment (no lines in its meta)")
    fs, spp = float(nl["fs_hz"]), int(exc["samples_per_period"])
    bins = np.rint(np.asarray(exc["lines_hz"], float) * spp / fs).astype(int)
    cl = load_statespace(closed_loop_npz)
    rep = stability(cl)
    if not rep.stable:
        raise ValueError(f"{closed_loop_npz}: the assembled closed loop is unstable ({rep}): it has no response "
                         "to compare with the nonlinear one")
    lti = simulate_closed_loop(cl, nl["t"], nl["r_x"], nl["r_y"],
                               x0=lti_initial_state(cl, float(nl["r_x"][0]), float(nl["r_y"][0])))
    ss_in = [c for c in load_model(selfsensing_model).input_names if c != ONE][0]
    u_name, y_name = etfe_pair(subsystem, ss_in)
    n = len(nl["t"]) // spp * spp
    mm, target, fit = measure_weight(
        signal(nl, u_name)[:n], signal(nl, y_name)[:n], signal(lti, u_name)[:n], signal(lti, y_name)[:n],
        fs_hz=fs, samples_per_period=spp, lines_bins=bins,
        **{k: params[k] for k in ("n_transient_periods", "k_sigma", "max_curvature_db_per_decade2",
                                  "tol_db", "max_order")})
    weight = {"gain": float(fit.gain), "zeros_hz": list(map(float, fit.zeros_hz)),
              "poles_hz": list(map(float, fit.poles_hz)), "order": int(fit.order)}
    info = {
        "subsystem": subsystem, "channel": {"input": u_name, "output": y_name},
        "lines_hz": mm.freqs_hz.tolist(), "etfe_mag": np.asarray(mm.mag).tolist(),
        "etfe_std": np.asarray(mm.std).tolist(), "envelope_target_mag": np.asarray(target).tolist(),
        "weight": weight, "weight_mag_at_lines": np.asarray(fit.mag(mm.freqs_hz)).tolist(),
        "max_dev_db": float(fit.max_dev_db), "within_tol": bool(fit.within_tol),
        "bound_holds": bool(fit.bound_holds), "min_margin_db": float(fit.min_margin_db),
        "gain_raise_db": float(fit.gain_raise_db), "tol_db": float(params["tol_db"]),
        "k_sigma": float(params["k_sigma"]), "unit": _unit(u_name, y_name),
        "model_etfe_mag": np.abs(mm.model.g).tolist(), "real_etfe_mag": np.abs(mm.real.g).tolist(),
    }
    save_weight(out_npz, fit.gain, fit.zeros_hz, fit.poles_hz, {"subsystem": subsystem, **weight})
    write_json(out_json, info)
    if out_fig is not None:
        from ..figures import fig7

        fig7(fit, mm.freqs_hz, mm.mag, info["unit"], f"{subsystem} ({u_name} -> {y_name})", out_fig)
    return info
