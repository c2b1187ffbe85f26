"""The paper's way on existing simulator data: selection by the assembled loop, Fig. 4 fits,
self-sensing weight, mu peak and its computed cause.

Usage::

    python bench/paper_way.py --results /work/baseline_results --out /tmp/paper_way
                              [--config config.yaml] [--set identification.loop_selection.horizons=[10,30]]
                              [--reuse] [--default-too]

Structures: the paper's (``ssamb.channels.VARIANTS``: plant on all four currents, 4-input
amplifier, ``i_ypos -> y_ss`` self-sensing) at the configured orders. Candidates of the grid
``identification.loop_selection`` are identified on ``sim/<identification.estimation>.npz``
(``--reuse`` keeps candidate files already in ``--out``), every combination is assembled and
scored on ``sim/<identification.validation>.npz`` (``ssamb.stages.select.run_select``); the
winner is compared with the nonlinear run on ``sim/<assembly.fig4>.npz``, its self-sensing
weight is measured on ``sim/<uncertainty.experiment>.npz`` and mu computed with the peak's
cause (``ssamb.stages.mu.run_mu``). With ``--default-too`` the cause of the default loop's
self-sensing mu peak (``ident/*.npz`` and ``uncertainty/selfsensing_weight.npz`` of
``--results``) is computed as well. Prints the figures (and the load average; the machine
is shared) and writes every stage's JSON to ``--out``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from ssamb.channels import SUBSYSTEMS, VARIANTS  # noqa: E402
from ssamb.config import load_config  # noqa: E402

SUBS = SUBSYSTEMS


def _candidates(cfg, sim: Path, out: Path, reuse: bool) -> dict:
    """Candidate files of the three subsystems (the paper's structures)."""
    from ssamb.channels import structure
    from ssamb.identification import subsystem_io
    from ssamb.identification.joint import candidate_settings, identify_candidates
    from ssamb.io import load_npz
    from ssamb.model_io import save_candidates

    idc = cfg["identification"]
    est_arr, _ = load_npz(sim / f"{idc['estimation']}.npz")
    fs = float(est_arr["fs_hz"])
    files = {}
    for sub in SUBS:
        files[sub] = out / f"{sub}_candidates.npz"
        if reuse and files[sub].exists():
            continue
        variant = VARIANTS[sub][2]
        est = subsystem_io(est_arr, sub, variant)
        t0 = time.perf_counter()
        c = identify_candidates(est.u, est.y, sub, int(idc[sub]["order"]),
                                candidate_settings(idc["loop_selection"], sub), fs, est.input_names,
                                est.output_names, input_directions=structure(sub, variant).input_directions,
                                progress=True)
        save_candidates(files[sub], sub, c)
        print(f"{sub}: {len(c)} candidates in {time.perf_counter() - t0:.0f} s "
              f"({sum(x.model is None for x in c)} failed, {sum(x.same_as is not None for x in c)} duplicates)")
    return files


def _print_selection(info: dict) -> None:
    print(f"\ncombinations {info['n_combinations']}, stable {info['n_stable']}")
    rows = sorted(info["table"], key=lambda r: (not r["stable"], -(r.get("mean_fit_pct") or -1e9),
                                               r["spectral_radius"] or 9))
    for r in rows[:12]:
        fits = r.get("fit_pct") or {}
        print(f"  rho {r['spectral_radius']:.6f}  x {fits.get('x_meas', float('nan')):8.2f}  "
              f"y {fits.get('y_meas', float('nan')):8.2f}  | {r['plant']} | {r['amplifier']} | {r['selfsensing']}")
    if info["failed"]:
        print("NO STABLE COMBINATION:", info["error"])
    else:
        print("selected:", info["selected"], "\nvalidation fits:", info["best"]["fit_pct"])


def _downstream(cfg, sim: Path, out: Path, models: dict) -> dict:
    """Fig. 4 fits, self-sensing weight, mu and the peak's cause of the selected loop."""
    from ssamb.stages.assemble import run_assemble
    from ssamb.stages.mu import run_mu
    from ssamb.stages.uncertainty import run_uncertainty

    asm = run_assemble(models, {}, sim / f"{cfg['assembly']['fig4']}.npz", cfg, out / "closed_loop.npz",
                       out / "assemble.json", out / "fig4.png", cfg["assembly"]["continuous_method"])
    unc = run_uncertainty(sim / f"{cfg['uncertainty']['experiment']}.npz", out / "closed_loop.npz",
                          models["selfsensing"], "selfsensing", cfg["uncertainty"], out / "selfsensing_weight.npz",
                          out / "uncertainty.json", out / "fig7.png")
    mu = run_mu(models, {"selfsensing": out / "selfsensing_weight.npz"}, "selfsensing", cfg, cfg["mu"],
                out / "mu.json", out / "mu_curve.npz", out / "fig8.png")
    return {"assemble": asm, "uncertainty": unc, "mu": mu}


def _evidence(cfg, out: Path, files: dict) -> dict:
    """Why the selected loop is stable: the amplifier's position path (selected and every
    amplifier candidate), the loop's radius with that path scaled, and the DC check of mu."""
    from ssamb.identification.joint import position_path, position_path_scan
    from ssamb.model_io import load_candidates, load_model, load_weight
    from ssamb.sim.controller import pid_discrete

    pid = pid_discrete(cfg)
    m = {k: load_model(out / f"{k}_loop.npz") for k in SUBS}
    freqs = (5.0, 40.0, 200.0)
    ev = {"selected": position_path(m["amplifier"], pid, freqs),
          "candidates": {c.label: position_path(c.model, pid, freqs) for c in load_candidates(files["amplifier"])
                         if c.model is not None and c.same_as is None},
          "scan": position_path_scan(m["plant"], m["amplifier"], m["selfsensing"], pid, pid)}
    s = m["selfsensing"]
    s0 = float((s.C @ np.linalg.solve(np.eye(s.order) - s.A, s.B[:, :1]) + s.D[:, :1]).item())
    w0 = abs(complex(np.squeeze(load_weight(out / "selfsensing_weight.npz")(0.0))))
    ev["dc"] = {"selfsensing_static_gain_m_per_a": s0, "weight_dc": w0, "w0_over_s0": w0 / abs(s0)}
    print("\nposition path of the selected amplifier (y):")
    for r in ev["selected"]:
        print(f"  {r['f_hz']:6.1f} Hz |Gu| {r['abs_Gu']:.3g}  |Gp| {r['abs_Gp_a_per_m']:.3g} A/m  "
              f"Gp/(-Gu C) {complex(*r['Gp_over_minus_GuC']):.2f}")
    print("  loop radius with the position path scaled:", [(r["factor"], round(r["spectral_radius"], 6))
                                                          for r in ev["scan"]])
    print(f"  DC: |W(0)| / |S(0)| = {w0:.3g} / {abs(s0):.3g} = {w0 / abs(s0):.3g}")
    return ev


def _default_cause(cfg, results: Path) -> dict:
    """The cause of the default loop's self-sensing mu peak (stored models and weight)."""
    from ssamb.generalized_plant import uncertainty_loop
    from ssamb.model_io import load_model, load_weight
    from ssamb.peak_cause import peak_cause
    from ssamb.robustness import log_grid, mu_for_case
    from ssamb.sim.controller import pid_discrete

    pid = pid_discrete(cfg)
    m = {k: load_model(results / "ident" / f"{k}.npz") for k in SUBS}
    loop = uncertainty_loop(m["plant"], m["amplifier"], m["selfsensing"], pid, pid)
    w = {"selfsensing": load_weight(results / "uncertainty" / "selfsensing_weight.npz")}
    p = cfg["mu"]
    sweep = mu_for_case(loop, w, "selfsensing", log_grid(p["f_min_hz"], p["f_max_hz"], p["n_points"]),
                        refine=bool(p["refine"]))
    return peak_cause(loop, w, "selfsensing", sweep, m["plant"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=ROOT / "results")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--config", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], help="config override a.b=VALUE")
    ap.add_argument("--reuse", action="store_true", help="keep candidate files already in --out")
    ap.add_argument("--default-too", action="store_true")
    a = ap.parse_args()
    cfg = load_config(a.config, a.set)
    sim = a.results / "sim"
    a.out.mkdir(parents=True, exist_ok=True)
    print(f"load average {os.getloadavg()}")
    t0 = time.perf_counter()
    files = _candidates(cfg, sim, a.out, a.reuse)
    from ssamb.stages.select import run_select

    models = {k: a.out / f"{k}_loop.npz" for k in SUBS}
    t1 = time.perf_counter()
    info = run_select(files, sim / f"{cfg['identification']['validation']}.npz", cfg, models, a.out / "select.json")
    print(f"selection: {time.perf_counter() - t1:.0f} s")
    _print_selection(info)
    summary = {"selection": {k: info[k] for k in ("selected", "best", "n_combinations", "n_stable", "failed")}}
    if not info["failed"]:
        d = _downstream(cfg, sim, a.out, models)
        asm, unc, mu = d["assemble"], d["uncertainty"], d["mu"]
        print(f"\nassembled loop: spectral radius {asm['spectral_radius']:.6f}; Fig. 4 fits "
              f"x {asm['fit_pct']['x']:.2f} %, y {asm['fit_pct']['y']:.2f} % (paper 93.76 / 50.76)")
        print(f"self-sensing weight {unc['weight']} ({unc['unit']})")
        print(f"mu peak {mu['peak']:.4g} at {mu['peak_hz']:.4g} Hz, scale for a peak of 1: {mu['scale_for_unity']:.4g}")
        print("cause:", mu["peak_cause"]["sentence"])
        summary["evidence"] = _evidence(cfg, a.out, files)
        summary.update({"fig4_fit_pct": asm["fit_pct"], "spectral_radius": asm["spectral_radius"],
                        "weight": unc["weight"], "mu": {k: mu[k] for k in ("peak", "peak_hz", "scale_for_unity")},
                        "peak_cause": mu["peak_cause"]})
    if a.default_too:
        dc = _default_cause(cfg, a.results)
        print("\ndefault loop:", dc["sentence"])
        summary["default_peak_cause"] = dc
    (a.out / "paper_way.json").write_text(json.dumps(summary, indent=1, default=str))
    print(f"\ntotal {time.perf_counter() - t0:.0f} s, load average {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    sys.exit(main())
