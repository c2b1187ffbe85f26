"""Stage ``summary``: a run's ``summary.json``, the numbers of the paper-versus-reproduction table.

Every value is read from a stage output; nothing is typed in. Keys (stable; docs/formats.md):
``fit_pct`` {x, y}; ``orders`` {plant, amplifier, selfsensing}; ``subsystem_fit_pct``;
``weight_fit_max_db``; ``mu`` {case: {peak, peak_hz, margin, scale_for_unity}};
``delevitation_s`` {nonlinear, nominal_lti, augmented_lti} (null where none);
``iso14839_peak_sensitivity`` {x, y}; ``closeloop`` (the default data set's closeloop.json);
``paper_way`` (the same keys for the paper's structure, with the assembled loop's ``stable`` and
the computed cause of its μ peak); ``sensitivity`` (the assumption study, once it has run);
``failed`` (stage -> reason, for a run whose stage failed). ``details`` carries what the report
needs.

With the noise ensembles (:mod:`ssamb.stages.ensemble`): ``ceiling`` (the Fig. 4 fits no model
can exceed, per axis ``K``, ``median``, ``min``, ``max``: in the default run); once
``snakemake ensemble`` has run, ``ensemble`` (per headline quantity of the default chain ``K``,
``median``, ``min``, ``max``, ``ceiling`` for fits; per yes/no outcome its ``fraction``) and,
for each other chain, its entry (``paper_way``, ``paper_literal``, ``paper_rig``: the keys of
``paper_way`` from realisation 0, with ``stable_fraction`` and the chain's ``ensemble``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from ..io import read_json, write_json

__all__ = ["build_summary", "write_summary", "headline", "ensemble_entries", "ensemble_stats", "first_failure"]


class _Inputs:
    """Reads stage JSONs; a failure marker becomes None and is recorded in ``failed``."""

    def __init__(self):
        self.failed: dict[str, str] = {}

    def read(self, path: str | Path | None, what: str):
        if path is None:
            return None
        obj = read_json(path)
        if isinstance(obj, dict) and obj.get("failed"):
            self.failed[what] = f"{obj.get('stage', what)}: {obj.get('error')}"
            return None
        return obj


def _mu_entry(m: Mapping | None) -> dict | None:
    if m is None:
        return None
    return {"peak": m["peak"], "peak_hz": m["peak_hz"], "margin": m["margin"],
            "scale_for_unity": m["scale_for_unity"], "cause": m.get("peak_cause")}


def headline(asm, ev, unc, mu, base, val) -> dict:
    """The binding headline keys from the stage outputs of one run (None where a stage failed)."""
    aug = [t for t in ((val or {}).get("delevitation_s", {}).get("augmented_lti") or {}).values() if t is not None]
    ok_unc = [u for u in unc.values() if u is not None]
    return {
        "fit_pct": {"x": asm["fit_pct"]["x"], "y": asm["fit_pct"]["y"]} if asm else {"x": None, "y": None},
        "orders": {k: (v or {}).get("order") for k, v in ev.items()},
        "subsystem_fit_pct": {k: (v or {}).get("fit_pct") for k, v in ev.items()},
        "weight_fit_max_db": max(u["max_dev_db"] for u in ok_unc) if ok_unc else None,
        "mu": {k: _mu_entry(m) for k, m in mu.items()},
        "delevitation_s": {"nonlinear": val["delevitation_s"]["nonlinear"] if val else None,
                           "nominal_lti": val["delevitation_s"]["nominal_lti"] if val else None,
                           "augmented_lti": min(aug) if aug else None},
        "iso14839_peak_sensitivity": {ax: base[ax]["peak_sensitivity"] if base else None for ax in ("x", "y")},
    }


def _details(asm, ev, unc, mu, base, val) -> dict:
    ident = {k: {"method": v["method"], "inputs": v["inputs"], "outputs": v["outputs"],
                 "spectral_radius": v["spectral_radius"], "paper_variant": v["paper_variant"],
                 "mean_fit_pct": v["mean_fit_pct"], "poles_hz": v.get("poles_hz"),
                 "methods": [{k2: m.get(k2) for k2 in ("method", "mean_fit", "spectral_radius", "error")}
                             for m in v["methods"]]}
             for k, v in ev.items() if v is not None}
    return {
        "assembly": None if asm is None else {k: asm[k] for k in (
            "stable", "spectral_radius", "order", "paper_structure", "d2c", "fig4_fit_pct", "subsystem_orders",
            "subsystem_inputs")},
        "identification": ident,
        "weights": {k: {"max_dev_db": u["max_dev_db"], "order": u["weight"]["order"], "channel": u["channel"],
                        "unit": u["unit"], "bound_holds": u["bound_holds"], "within_tol": u["within_tol"]}
                    for k, u in unc.items() if u is not None},
        "mu": {k: m for k, m in mu.items() if m is not None},
        "baseline": base,
        "validation": val,
    }


def build_summary(assemble_json: str | Path, evidence_jsons: Mapping[str, str | Path],
                  uncertainty_jsons: Mapping[str, str | Path], mu_jsons: Mapping[str, str | Path],
                  baseline_json: str | Path, validation_json: str | Path,
                  closeloop_json: str | Path | None = None, sim_metas: Sequence[str | Path] = (),
                  closeloop_all: Mapping[str, str | Path] | None = None, paper_json: str | Path | None = None,
                  study_json: str | Path | None = None, selection_json: str | Path | None = None,
                  ceiling_json: str | Path | None = None, ensemble_json: str | Path | None = None) -> dict:
    """Collect one run's stage outputs (and, for the default run, the paper's-way run's summary,
    the study, the ceiling and the noise ensembles) into the summary dictionary."""
    r = _Inputs()
    asm = r.read(assemble_json, "assemble")
    ev = {k: r.read(v, f"identify/{k}") for k, v in evidence_jsons.items()}
    unc = {k: r.read(v, f"uncertainty/{k}") for k, v in uncertainty_jsons.items()}
    mu = {k: r.read(v, f"mu/{k}") for k, v in mu_jsons.items()}
    base, val = r.read(baseline_json, "baseline"), r.read(validation_json, "validate")
    summary = headline(asm, ev, unc, mu, base, val)
    summary["closeloop"] = read_json(closeloop_json) if closeloop_json else None
    if paper_json is not None:
        summary["paper_way"] = paper_way(read_json(paper_json))
    if study_json is not None:
        summary["sensitivity"] = read_json(study_json).get("sensitivity")
    if ceiling_json is not None:
        ch = read_json(ceiling_json)["channels"]
        summary["ceiling"] = {k: {s2: ch[c][s2] for s2 in ("K", "median", "min", "max")}
                              for k, c in (("fit_x_pct", "x_meas"), ("fit_y_pct", "y_meas")) if c in ch}
    if ensemble_json is not None:
        summary.update(ensemble_entries(read_json(ensemble_json), summary.get("paper_way")))
    summary["failed"] = r.failed
    summary["details"] = _details(asm, ev, unc, mu, base, val)
    summary["details"]["selection"] = _selection(r.read(selection_json, "select"))
    summary["details"]["closeloop_datasets"] = {k: read_json(v) for k, v in (closeloop_all or {}).items()}
    summary["details"]["simulations"] = {Path(p).stem: _sim_brief(read_json(p)) for p in sim_metas}
    return summary


def _selection(sel: Mapping | None) -> dict | None:
    """The selection by the assembled loop, briefly: the rule, the winner and how many of the
    combinations gave a stable loop (the full table stays in ``select/select.json``)."""
    if sel is None:
        return None
    keep = ("rule", "selected", "best", "n_combinations", "n_stable", "failed", "error", "validation")
    return {k: sel.get(k) for k in keep if k in sel}


def first_failure(failed: Mapping[str, str] | None) -> dict | None:
    """The failure the others follow from: ``{"stage", "reason"}`` of the entry whose reason does
    not report an upstream stage's failure (the first one when all do); None without failures."""
    if not failed:
        return None
    # a stage that failed because it read a failure marker says "Failed: <file>: stage ... failed"
    roots = [(k, v) for k, v in failed.items() if "Failed: " not in v]
    stage, reason = (roots or list(failed.items()))[0]
    prefix = stage.split("/")[0] + ": "
    return {"stage": stage, "reason": reason[len(prefix):] if reason.startswith(prefix) else reason}


def paper_way(s: Mapping) -> dict:
    """The ``paper_way`` entry from the paper's-way run's summary: its headline keys, the
    assembled loop's stability and the computed cause of its self-sensing μ peak."""
    keys = ("fit_pct", "orders", "subsystem_fit_pct", "weight_fit_max_db", "mu", "delevitation_s",
            "iso14839_peak_sensitivity", "failed")
    asm = (s.get("details") or {}).get("assembly") or {}
    mu_ss = (s.get("mu") or {}).get("selfsensing") or {}
    return {**{k: s.get(k) for k in keys}, "failure": first_failure(s.get("failed")), "stable": asm.get("stable"),
            "spectral_radius": asm.get("spectral_radius"), "mu_peak_cause": mu_ss.get("cause"),
            "structure": asm.get("subsystem_inputs"),
            "selection": (s.get("details") or {}).get("selection"),
            "identification": (s.get("details") or {}).get("identification")}


def ensemble_stats(chain: Mapping) -> dict:
    """A chain of ``ensemble.json`` as in ``summary.json``: per quantity ``K``, ``median``,
    ``min``, ``max`` (and ``ceiling`` for fits), per yes/no outcome ``K`` and ``fraction``."""
    out = {k: {s: q[s] for s in ("K", "median", "min", "max", "ceiling") if s in q}
           for k, q in chain["quantities"].items()}
    out.update({k: {"K": f["K"], "fraction": f["fraction"]} for k, f in chain["fractions"].items()})
    return out


#: summary.json key of each ensemble chain other than the default
CHAIN_KEYS = {"paper": "paper_way"}


def ensemble_entries(ens: Mapping, paper_way_entry: Mapping | None = None) -> dict:
    """``ensemble`` (the default chain) and one entry per other chain (``paper_way``,
    ``paper_literal``, ``paper_rig``, ...: realisation 0's :func:`paper_way` keys with
    ``stable_fraction`` and ``ensemble``) from ``ensemble.json``."""
    out = {}
    for name, chain in ens["chains"].items():
        stats = ensemble_stats(chain)
        if name == "default":
            out["ensemble"] = {**stats, "K_realisations": chain["realisations"]}
            continue
        key = CHAIN_KEYS.get(name, name)
        base = dict(paper_way_entry) if key == "paper_way" and paper_way_entry else dict(chain["realisation_0"])
        out[key] = {**base, "stable_fraction": chain["fractions"]["stable"]["fraction"], "ensemble": stats,
                    "first_failures": chain["failures"]}
    return out


def _sim_brief(meta: Mapping) -> dict:
    keep = ("experiment", "duration_s", "start", "delevitation_s", "config_hash", "selfsensing_calibration",
            "equilibrium", "excitation", "failed", "error")
    return {k: meta.get(k) for k in keep if k in meta or k not in ("failed", "error")}


def write_summary(out_path: str | Path, **kwargs) -> dict:
    """Build and write ``summary.json`` (atomic)."""
    s = build_summary(**kwargs)
    write_json(out_path, s)
    return s
