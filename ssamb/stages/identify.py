r"""Stage ``identify``: one subsystem model from closed-loop simulator data (paper section 3).

Reads the estimation and validation experiments, compares SIPPY methods at the configured
order, scans the order for evidence, identifies the paper's structural variant where ours
differs, and writes the selected model, a JSON of evidence and figures. The structures are
those of :mod:`ssamb.channels` (config ``identification.<subsystem>``); why ours differ from the
paper's is in :func:`ssamb.identification.selection.select_model` and the README.

A paper-variant fit that fails is written as a *failed-fit* file
(:func:`ssamb.model_io.save_failed`): reading it raises with the reason, and the evidence JSON
says ``failed`` -- it is never replaced by the selected model.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ..channels import VARIANTS
from ..identification import identify, order_scan, subsystem_io
from ..identification.memo import identification_memo
from ..identification.selection import compare_and_select, model_summary
from ..io import DataError, write_json
from ..model_io import load_record, save_failed, save_model

__all__ = ["run_identify"]


def _load_io(path, subsystem: str, variant: str):
    arrays, meta = load_record(path)
    t_del = meta.get("delevitation_s") if isinstance(meta, dict) else None
    if t_del is not None:
        raise DataError(f"{path}: the rotor delevitated at t = {float(t_del):.4g} s of this experiment; the "
                        f"subsystems are identified from the levitated closed loop only")
    try:
        return subsystem_io(arrays, subsystem, variant), float(arrays["fs_hz"])
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from None


def _cut(io, duration_s: float, fs_hz: float):
    n = min(len(io.u), int(round(duration_s * fs_hz)))
    return io.u[:n], io.y[:n]


def _order_scan(est, val, scan_cfg: Mapping, sel, fs_hz: float, kw: Mapping):
    """Validation fit against order with the selected method on a shorter record (evidence);
    None when the config lists no orders."""
    if not scan_cfg["orders"]:
        return None
    scan_s = float(scan_cfg["duration_s"])
    (us, ys), (uvs, yvs) = _cut(est, scan_s, fs_hz), _cut(val, scan_s, fs_hz)
    return order_scan(us, ys, orders=[int(o) for o in scan_cfg["orders"]], method=sel.method, fs_hz=fs_hz,
                      input_names=est.input_names, output_names=est.output_names, u_val=uvs, y_val=yvs,
                      input_directions=sel.input_directions, **kw)


def _paper_variant(est_npz, val_npz, subsystem: str, variant: str, order: int, method: str,
                   kw: Mapping, out_variant) -> dict:
    """Identify the paper's structure with the selected method; write it, or a failed-fit file."""
    from ..channels import structure

    try:
        (est, fs), (val, _) = _load_io(est_npz, subsystem, variant), _load_io(val_npz, subsystem, variant)
        m2 = identify(est.u, est.y, order, method, fs, est.input_names, est.output_names,
                      input_directions=structure(subsystem, variant).input_directions, **kw)
        fit2 = np.asarray(m2.fit(val.u, val.y))
        if not np.all(np.isfinite(fit2)):
            raise ValueError(f"validation fit not finite: {fit2.tolist()}")
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        reason = f"{type(exc).__name__}: {exc}"
        if out_variant is not None:
            save_failed(out_variant, reason,
                        {"stage": f"identify/{subsystem}", "subsystem": subsystem, "variant": variant})
        return {"variant": variant, "failed": True, "error": reason}
    if out_variant is not None:
        save_model(out_variant, m2)
    return {"variant": variant, "failed": False, "inputs": list(est.input_names),
            "outputs": list(est.output_names), "method": method, "fit_pct": fit2.tolist(),
            "spectral_radius": m2.spectral_radius, "stable": bool(m2.is_stable)}


#: reason written in place of the other structure's model when it is not identified
SKIPPED = "not identified (config identification.structure_evidence: false)"


def _skip_variant(subsystem: str, variant: str, out_variant) -> dict:
    """The other structure not identified (``identification.structure_evidence: false``): a
    marker file that says so (:data:`SKIPPED`; reading it as a model raises)."""
    if out_variant is not None:
        save_failed(out_variant, SKIPPED, {"stage": f"identify/{subsystem}", "subsystem": subsystem,
                                           "variant": variant, "skipped": True})
    return {"variant": variant, "skipped": True, "failed": False, "error": None}


def _loop_candidates(est, sel, subsystem: str, variant: str, order: int, params: Mapping, fs: float,
                     out_candidates) -> dict:
    """Candidates for the selection by the assembled loop: with ``identification.selection:
    loop`` the grid ``identification.loop_selection`` (the method comparison's models reused),
    else the compared models only; written with :func:`ssamb.model_io.save_candidates`. Returns
    their summary for the evidence JSON."""
    from ..channels import structure
    from ..identification.joint import Candidate, candidate_settings, identify_candidates
    from ..model_io import save_candidates

    base = {"ss_f": int(params["ss_f"]), "ss_p": int(params["ss_p"]), "A_stability": False, "refine": "auto"}
    known = [Candidate(subsystem, {"method": r.method, **base}, r.model, r.error) for r in sel.results]
    if params.get("selection", "subsystem") != "loop":  # the compared models only (no grid to fit)
        save_candidates(out_candidates, subsystem, known)
        return {"n": len(known), "candidates": [c.as_dict() for c in known]}
    settings = candidate_settings(params["loop_selection"], subsystem)
    cands = identify_candidates(est.u, est.y, subsystem, order, settings, fs, est.input_names, est.output_names,
                                input_directions=structure(subsystem, variant).input_directions, known=known,
                                progress=True, affine=bool(params.get("affine", True)))
    save_candidates(out_candidates, subsystem, cands)
    return {"n": len(cands), "candidates": [c.as_dict() for c in cands]}


def run_identify(estimation_npz: str | Path, validation_npz: str | Path, subsystem: str,
                 params: Mapping, out_model: str | Path, out_json: str | Path,
                 out_variant: str | Path | None = None, fig_dir: str | Path | None = None,
                 out_candidates: str | Path | None = None) -> dict:
    """Identify one subsystem; write the selected model, its evidence and figures.

    Parameters
    ----------
    estimation_npz, validation_npz : path
        Simulator outputs (``results/sim/id_pulses.npz``, ``results/sim/id_validation.npz``).
    subsystem : {'plant', 'amplifier', 'selfsensing'}
    params : mapping
        The config section ``identification`` (``ss_f``, ``ss_p``, ``methods``, ``order_scan``
        and the subsystem's own ``order`` and structure key).
    out_model, out_json : path
        The selected model (NPZ + JSON sidecar) and the evidence JSON.
    out_variant : path, optional
        The paper's structural variant of the model (or a failed-fit file).
    fig_dir : path, optional
        Where to write ``<subsystem>_orders.png`` and ``<subsystem>_validation.png``.
    out_candidates : path, optional
        Where to write the candidate models of the grid ``params['loop_selection']`` for the
        selection by the assembled loop (``identification.selection: loop``,
        :func:`ssamb.stages.select.run_select`).
    """
    key, ours, paper = VARIANTS[subsystem]
    sub = dict(params[subsystem])
    variant = sub.get(key, ours)
    order = int(sub["order"])
    kw = {"ss_f": int(params["ss_f"]), "ss_p": int(params["ss_p"]), "affine": bool(params.get("affine", True))}
    (est, fs), (val, _) = _load_io(estimation_npz, subsystem, variant), _load_io(validation_npz, subsystem, variant)
    with identification_memo():  # the identifications below share their common work (exact)
        sel = compare_and_select(est, val, subsystem, variant, order, tuple(params["methods"]), fs, **kw)
        loop_cands = None
        if out_candidates is not None:
            loop_cands = _loop_candidates(est, sel, subsystem, variant, order, params, fs, out_candidates)
        scan = _order_scan(est, val, params["order_scan"], sel, fs, kw)
        other = paper if variant != paper else ours
        if params.get("structure_evidence", True):
            variant_info = _paper_variant(estimation_npz, validation_npz, subsystem, other, order, sel.method, kw,
                                          out_variant)
        else:
            variant_info = _skip_variant(subsystem, other, out_variant)
    save_model(out_model, sel.model)
    info = {"subsystem": subsystem, "variant": {key: variant}, "paper_variant": variant_info,
            "loop_candidates": loop_cands,
            **model_summary(sel, val, fs), "order_scan": None if scan is None else scan.as_dict(),
            "estimation_samples": int(len(est.u)), "validation_samples": int(len(val.u))}
    write_json(out_json, info)
    if fig_dir is not None:
        from ..figures import identification_figures

        identification_figures(info, sel.model, val.u, val.y, fs, Path(fig_dir))
    return info
