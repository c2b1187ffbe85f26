r"""Stage ``assemble``: closed-loop LTI model, its stability, the d2c error and Fig. 4.

Interconnects the three identified subsystem models with the discrete PID controllers
(:func:`ssamb.closed_loop.assemble_closed_loop`), reports the stability of the result and of
the paper's structural variants (one subsystem at a time and all together), quantifies the
error of the continuous equivalent (:func:`ssamb.closed_loop.d2c_summary`), and compares the
LTI model with the nonlinear simulation on the Fig. 4 experiment.

Initial state for the comparison: the nonlinear run starts from its settled operating point
with no injection (the pre-roll), so the LTI model starts at its equilibrium for the
references at t = 0 and zero injection -- not for the first input sample, which would put a
pulse's DC response into the initial state.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ..channels import CL_OUTPUTS
from ..closed_loop import assemble_closed_loop, d2c_summary, replay_from_operating_point, stability
from ..identification import nrmse_fit
from ..io import load_npz, write_json
from ..model_io import Failed, load_model, load_record, save_statespace
from ..sim.controller import pid_discrete

__all__ = ["run_assemble", "structure_variants"]


def structure_variants(models: Mapping, paper_models: Mapping[str, str | Path], pid) -> dict:
    """Stability of the loop with each subsystem in the paper's structure, and all together.
    A failed paper fit is reported as failed (with its reason), never replaced; a structure not
    identified (``identification.structure_evidence: false``) as ``skipped``."""
    paper, out = {}, {}
    for k, path in paper_models.items():
        if load_npz(path)[1].get("skipped"):  # not identified (identification.structure_evidence: false)
            out[k] = {"skipped": True}
            continue
        try:
            paper[k] = load_model(path)
        except Failed as exc:
            paper[k] = exc
    for k in list(paper) + (["all"] if paper else []):
        mm = {s: paper.get(s, models[s]) if k == "all" else (paper[k] if s == k else models[s]) for s in models}
        failed = [f"{s}: {v}" for s, v in mm.items() if isinstance(v, Failed)]
        if failed:
            out[k] = {"failed": True, "error": "; ".join(failed)}
            continue
        try:
            rep = stability(assemble_closed_loop(mm["plant"], mm["amplifier"], mm["selfsensing"], pid, pid))
            out[k] = {"spectral_radius": rep.spectral_radius, "stable": rep.stable}
            if k != "all":
                out[k]["inputs"] = list(mm[k].input_names)
        except ValueError as exc:
            out[k] = {"error": str(exc)}
    return out


def _fig4(cl, fig4_npz, out_fig) -> dict:
    """Fits of the LTI loop to the nonlinear Fig. 4 run, per channel; the figure."""
    from ..figures import fig4

    nl, _ = load_record(fig4_npz)
    if not stability(cl).stable:
        if out_fig is not None:
            nan = np.full_like(np.asarray(nl["t"], float), np.nan)
            fig4(nl, {"x_meas": nan, "y_meas": nan}, {"x_meas": np.nan, "y_meas": np.nan}, out_fig)
        return {}
    out = replay_from_operating_point(cl, nl)
    fits = {c: float(nrmse_fit(nl[c], out[c])) for c in CL_OUTPUTS}
    if out_fig is not None:
        fig4(nl, out, fits, out_fig)
    return fits


def run_assemble(models: Mapping[str, str | Path], paper_models: Mapping[str, str | Path],
                 fig4_npz: str | Path, pid_params: Mapping, out_discrete: str | Path, out_json: str | Path,
                 out_fig: str | Path | None = None, continuous_method: str = "tustin") -> dict:
    """Assemble the closed loop, check its conversion, compare it on Fig. 4; write the files.

    Parameters
    ----------
    models : mapping
        ``plant``, ``amplifier``, ``selfsensing`` -> selected model files (``identify``).
    paper_models : mapping
        The same for the paper's structural variants (evidence; may be failed-fit files).
    fig4_npz : path
        The nonlinear simulation of the Fig. 4 experiment.
    pid_params : mapping
        The config sections the PID needs (``table1``, ``controller``).
    continuous_method : {'tustin', 'zoh'}
        The d2c conversion whose error is reported.
    """
    pid = pid_discrete(pid_params)
    m = {k: load_model(v) for k, v in models.items()}
    cl = assemble_closed_loop(m["plant"], m["amplifier"], m["selfsensing"], pid, pid)
    rep = stability(cl)
    save_statespace(out_discrete, cl, {"stable": rep.stable})
    fits = _fig4(cl, fig4_npz, out_fig)
    info = {
        "stable": rep.stable, "spectral_radius": rep.spectral_radius, "order": int(np.asarray(cl.A).shape[0]),
        "inputs": list(cl.input_labels), "outputs": list(cl.output_labels),
        "subsystem_orders": {k: v.order for k, v in m.items()},
        "subsystem_inputs": {k: list(v.input_names) for k, v in m.items()},
        "paper_structure": structure_variants(m, paper_models, pid), "continuous_method": continuous_method,
        "d2c": d2c_summary(cl, continuous_method) if rep.stable else None,
        "fig4_fit_pct": fits, "fit_pct": {"x": fits.get("x_meas"), "y": fits.get("y_meas")},
    }
    write_json(out_json, info)
    return info
