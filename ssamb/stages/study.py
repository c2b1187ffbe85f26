r"""Parameter study: the μ margin and the delevitation amplitude over one physical parameter.

One study point runs the analysis chain in one process for a config with one value changed
(:func:`run_study_point`): simulate the identification, validation, multisine and sweep
experiments, identify the three subsystems (configured methods and orders; no order scan),
assemble the closed loop, measure the self-sensing weight, compute μ for the self-sensing case,
and find the sweep amplitude at which the nonlinear model and the nominal LTI model delevitate.
The workflow runs the points as separate jobs (``rule study_point``, wildcard ``value``), so they
spread over the cores of one machine or over a cluster, and :func:`collect_study` gathers them.
"""
from __future__ import annotations

import copy
import os
import tempfile
import time
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..config import apply_overrides, validate_config
from ..io import read_json, write_json

__all__ = ["run_study_point", "collect_study"]


def run_study_point(cfg: Mapping, parameter: str, value: float, out_json: str | Path) -> dict:
    """Run the chain for ``cfg`` with ``parameter`` (dotted key) set to ``value``; write a JSON."""
    from ..sim import simulate
    from .assemble import run_assemble
    from .identify import run_identify
    from .mu import run_mu
    from .uncertainty import run_uncertainty
    from .validate import run_validate

    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    t0 = time.perf_counter()
    c = apply_overrides(cfg, {parameter: value})
    validate_config(c)
    idc = copy.deepcopy(c["identification"])
    idc["order_scan"] = {"orders": [idc["plant"]["order"]], "duration_s": idc["order_scan"]["duration_s"]}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        exps = {c["identification"]["estimation"], c["identification"]["validation"], c["assembly"]["fig4"],
                c["uncertainty"]["experiment"], "sweep"}
        delev = {}
        for e in exps:
            res = simulate(c, e, progress=False)
            res.save(d / f"{e}.npz")
            delev[e] = res.meta["delevitation_s"]
        models = {}
        for sub in ("plant", "amplifier", "selfsensing"):
            run_identify(d / f"{idc['estimation']}.npz", d / f"{idc['validation']}.npz", sub, idc,
                         d / f"{sub}.npz", d / f"{sub}_ev.json", d / f"{sub}_paper.npz")
            models[sub] = d / f"{sub}.npz"
        asm = run_assemble(models, {}, d / f"{c['assembly']['fig4']}.npz", c, d / "cl.npz",
                           d / "asm.json", None, c["assembly"]["continuous_method"])
        out = {"parameter": parameter, "value": value, "stable": asm["stable"], "fit_pct": asm["fit_pct"],
               "identification_delevitated": {k: v for k, v in delev.items() if v is not None}}
        if asm["stable"]:
            unc = run_uncertainty(d / f"{c['uncertainty']['experiment']}.npz", d / "cl.npz", models["selfsensing"],
                                  "selfsensing", c["uncertainty"], d / "w.npz", d / "w.json")
            mu = run_mu(models, {"selfsensing": d / "w.npz"}, "selfsensing", c, c["mu"], d / "mu.json", d / "mu.npz")
            val = run_validate(d / "sweep.npz", models, d / "w.npz",
                               {**c, "experiments": {"sweep": c["experiments"]["sweep"]}}, c["validation"],
                               d / "val.json")
            crit = {o["model"]: o.get("critical_amplitude_m") for o in val["outcomes"]}
            out.update({"weight_max_dev_db": unc["max_dev_db"],
                        "mu_peak": mu["peak"], "mu_peak_hz": mu["peak_hz"], "mu_margin": mu["margin"],
                        "critical_amplitude_m": {"nonlinear": crit.get("nonlinear"),
                                                 "nominal_lti": crit.get("nominal LTI")}})
    out["time_s"] = time.perf_counter() - t0
    write_json(out_json, out)
    return out


def collect_study(point_jsons: Sequence[str | Path], out_json: str | Path, out_fig: str | Path | None = None) -> dict:
    """Gather the study points (sorted by value) into one JSON and a figure."""
    pts = sorted((read_json(p) for p in point_jsons), key=lambda r: r["value"])
    res = {"parameter": pts[0]["parameter"] if pts else None, "points": pts}
    write_json(out_json, res)
    if out_fig is not None and pts:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from ..figures import save

        v = np.array([p["value"] for p in pts])
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.4))
        ax[0].plot(v, [p.get("mu_margin", np.nan) for p in pts], "o-")
        ax[0].set_xlabel(res["parameter"])
        ax[0].set_ylabel("mu margin 1/peak (self-sensing)")
        for key, lab in (("nonlinear", "nonlinear"), ("nominal_lti", "nominal LTI")):
            a = [np.nan if not p.get("critical_amplitude_m") or p["critical_amplitude_m"].get(key) is None
                 else p["critical_amplitude_m"][key] * 1e6 for p in pts]
            ax[1].plot(v, a, "o-", label=lab)
        ax[1].set_xlabel(res["parameter"])
        ax[1].set_ylabel("critical sweep amplitude (um)")
        ax[1].legend()
        fig.suptitle("Parameter study")
        fig.tight_layout()
        save(fig, out_fig)
    return res
