"""Stage ``summary``: ``results/summary.json``, the numbers of the paper-versus-reproduction table.

Every value is read from a stage output; nothing is typed in. Keys (binding, ARCHITECTURE.md):
``fit_pct`` {x, y}; ``orders`` {plant, amplifier, selfsensing}; ``subsystem_fit_pct``;
``weight_fit_max_db``; ``mu`` {case: {peak, peak_hz, margin, scale_for_unity}};
``delevitation_s`` {nonlinear, nominal_lti, augmented_lti} (null where none);
``iso14839_peak_sensitivity`` {x, y}; ``closeloop`` (the default data set's closeloop.json).
Extra keys carry the detail the report needs.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from ..io import read_json, write_json

__all__ = ["build_summary", "write_summary"]


def build_summary(assemble_json: str | Path, evidence_jsons: Mapping[str, str | Path],
                  uncertainty_jsons: Mapping[str, str | Path], mu_jsons: Mapping[str, str | Path],
                  baseline_json: str | Path, validation_json: str | Path,
                  closeloop_json: str | Path | None = None, sim_metas: Sequence[str | Path] = (),
                  closeloop_all: Mapping[str, str | Path] | None = None) -> dict:
    """Collect the stage outputs into the summary dictionary."""
    asm = read_json(assemble_json)
    ev = {k: read_json(v) for k, v in evidence_jsons.items()}
    unc = {k: read_json(v) for k, v in uncertainty_jsons.items()}
    mu = {k: read_json(v) for k, v in mu_jsons.items()}
    base = read_json(baseline_json)
    val = read_json(validation_json)
    aug = [t for t in val["delevitation_s"]["augmented_lti"].values() if t is not None]
    summary = {
        "fit_pct": {"x": asm["fit_pct"]["x"], "y": asm["fit_pct"]["y"]},
        "orders": {k: v["order"] for k, v in ev.items()},
        "subsystem_fit_pct": {k: v["fit_pct"] for k, v in ev.items()},
        "weight_fit_max_db": max(u["max_dev_db"] for u in unc.values()),
        "mu": {k: {"peak": m["peak"], "peak_hz": m["peak_hz"], "margin": m["margin"],
                   "scale_for_unity": m["scale_for_unity"]} for k, m in mu.items()},
        "delevitation_s": {"nonlinear": val["delevitation_s"]["nonlinear"],
                           "nominal_lti": val["delevitation_s"]["nominal_lti"],
                           "augmented_lti": min(aug) if aug else None},
        "iso14839_peak_sensitivity": {ax: base[ax]["peak_sensitivity"] for ax in ("x", "y")},
        "closeloop": read_json(closeloop_json) if closeloop_json else None,
        # detail for the report
        "details": {
            "assembly": {k: asm[k] for k in ("stable", "spectral_radius", "order", "paper_structure",
                                             "d2c", "fig4_fit_pct", "subsystem_orders", "subsystem_inputs")},
            "identification": {k: {"method": v["method"], "inputs": v["inputs"], "outputs": v["outputs"],
                                   "spectral_radius": v["spectral_radius"], "paper_variant": v["paper_variant"],
                                   "mean_fit_pct": v["mean_fit_pct"],
                                   "methods": [{"method": m["method"], "mean_fit": m["mean_fit"],
                                                "spectral_radius": m["spectral_radius"], "error": m["error"]} for m in v["methods"]]}
                               for k, v in ev.items()},
            "weights": {k: {"max_dev_db": u["max_dev_db"], "order": u["weight"]["order"],
                            "channel": u["channel"], "unit": u["unit"], "bound_holds": u["bound_holds"],
                            "within_tol": u["within_tol"]} for k, u in unc.items()},
            "mu": mu,
            "baseline": base,
            "validation": val,
            "closeloop_datasets": {k: read_json(v) for k, v in (closeloop_all or {}).items()},
            "simulations": {Path(p).stem: _sim_brief(read_json(p)) for p in sim_metas},
        },
    }
    return summary


def _sim_brief(meta: Mapping) -> dict:
    keep = ("experiment", "duration_s", "start", "delevitation_s", "config_hash",
            "selfsensing_calibration", "equilibrium", "excitation")
    return {k: meta.get(k) for k in keep}


def write_summary(out_path: str | Path, **kwargs) -> dict:
    """Build and write ``summary.json`` (atomic)."""
    s = build_summary(**kwargs)
    write_json(out_path, s)
    return s
