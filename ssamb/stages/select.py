r"""Stage ``select``: the subsystem models chosen by the assembled loop (paper section 3).

Reads the candidate models of the three subsystems (written by
:func:`ssamb.stages.identify.run_identify` with ``out_candidates``), assembles every
combination with the discrete PIDs (:func:`ssamb.identification.joint.select_loop`), and writes
the selected model of each subsystem and the evidence table (every combination's spectral
radius and validation fits). When no combination gives a stable loop, each model file is a
*failed-fit* file (:func:`ssamb.model_io.save_failed`) whose reason gives the smallest
spectral radius reached, and the evidence JSON has ``failed: true``; nothing downstream can
mistake it for a model.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from ..identification.joint import select_loop
from ..io import DataError, write_json
from ..model_io import load_candidates, load_record, save_failed, save_model
from ..sim.controller import pid_discrete

__all__ = ["run_select"]

_NEEDED = ("t", "r_x", "r_y", "x_meas", "y_meas")


def run_select(candidates: Mapping[str, str | Path], validation_npz: str | Path, pid_params: Mapping,
               out_models: Mapping[str, str | Path], out_json: str | Path) -> dict:
    """Select the subsystem models by the stability and validation fit of the assembled loop.

    Parameters
    ----------
    candidates : mapping
        ``plant``, ``amplifier``, ``selfsensing`` -> candidate file
        (:func:`ssamb.model_io.save_candidates`).
    validation_npz : path
        An independent closed-loop record (config ``identification.validation``), replayed by
        every stable combination; not the Fig. 4 record, which stays a test the selection has
        not seen.
    pid_params : mapping
        The config sections the PID needs (``table1``, ``controller``).
    out_models : mapping
        subsystem -> the selected model file (or a failed-fit file).
    out_json : path
        The evidence: rule, selection, every combination, every candidate.
    """
    val, _ = load_record(validation_npz)
    missing = [c for c in _NEEDED if c not in val]
    if missing:
        raise DataError(f"{validation_npz}: missing column(s) {', '.join(missing)}")
    cands = {k: load_candidates(candidates[k]) for k in ("plant", "amplifier", "selfsensing")}
    pid = pid_discrete(pid_params)
    sel = select_loop(cands, pid, pid, val, progress=True)
    info = {**sel.as_dict(), "failed": sel.choice is None, "n_combinations": len(sel.table),
            "n_stable": sum(bool(r["stable"]) for r in sel.table), "validation": str(validation_npz)}
    if sel.choice is None:
        radii = [r["spectral_radius"] for r in sel.table if r["spectral_radius"] is not None]
        reason = (f"no stable assembled loop among {len(sel.table)} combinations of the candidates "
                  f"(smallest spectral radius {min(radii, default=float('nan')):.6f})")
        info["error"] = reason
        for k, path in out_models.items():
            save_failed(path, reason, {"stage": "select", "subsystem": k, "selection": "loop"})
    else:
        for k, path in out_models.items():
            save_model(path, sel.choice[k].model)
    write_json(out_json, info)
    return info
