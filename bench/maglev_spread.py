"""The levitated ball's five-recording result under arbitrary choices: its spread is its uncertainty.

    python bench/maglev_spread.py [--design-seeds 0 1 2 3] [--orders 0] [--processes 1]
                                  [--workers 1] [--out DIR]

Runs the analysis of ``docs/validation.md`` (fit escalon, constante, chirp; hold out multiescalon
and senoidal; :func:`ssamb.closeloop.recordings.run_recordings`) once per variant, every variant
an arbitrary choice that a converged estimate would not depend on:

* ``--design-seeds``: the estimator's ``closeloop.estimate.design_seed`` (which orthogonal
  array its finite-difference designs draw; 0 is the default);
* ``--orders K``: K random orders of the device config's ``closeloop.calibration`` keys (the
  estimator sees them sorted, so these must give the default's numbers bit for bit; on code
  that read them in file order, they measure what that order did).

Per variant it prints the held-out rms per channel (pooled over the held-out recordings),
whether the final model hits a stop the data do not, each fitting recording's calibration cost
over its noise floor and whether it stopped short, and the joint calibration's start and cost;
then the median and range of the held-out errors over the variants and how often a stop is hit.
Each variant's ``closeloop.json`` is kept in ``--out``.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
DATA = REPO / "resources" / "maglev1d"
FIT = ("escalon", "constante", "chirp")
HOLD = ("multiescalon", "senoidal")


def _path(kind: str) -> Path:
    return next(DATA.glob(f"dataset_{kind}_*.npz"))


def _config(variant: dict) -> dict:
    from ssamb.device import get_device

    cfg = get_device("maglev1d").load_config(None)
    cl = dict(cfg.get("closeloop") or {})
    if "design_seed" in variant:
        cl["estimate"] = {**(cl.get("estimate") or {}), "design_seed": int(variant["design_seed"])}
    if "order" in variant:
        cal = list((cl.get("calibration") or {}).items())
        perm = np.random.default_rng(variant["order"]).permutation(len(cal))
        cl["calibration"] = dict(cal[i] for i in perm)
    cfg["closeloop"] = cl
    return cfg


def run_variant(args) -> dict:
    """One analysis: ``(variant, out_dir, workers)`` -> its figures (module docstring)."""
    variant, out, workers = args
    from ssamb.closeloop.recordings import run_recordings

    t0 = time.perf_counter()
    cfg = _config(variant)
    rep = run_recordings({k: _path(k) for k in FIT}, {k: _path(k) for k in HOLD}, out, config=cfg,
                         device="maglev1d", progress=False, workers=workers, force=True)
    j = rep.get("joint_calibration") or {}
    return {"variant": variant, "wall_s": time.perf_counter() - t0,
            "calibration_order": list(cfg["closeloop"].get("calibration") or {}),
            "rms_after": {c: rep["error_after"][c]["rms"] for c in rep["error_after"]},
            "rms_before": {c: rep["error_before"][c]["rms"] for c in rep["error_before"]},
            "noise": {c: rep["error_before"][c]["noise_rms"] for c in rep["error_before"]},
            "stop_hit": sorted(n for n, v in rep["stops_hit_by_model_only"].items() if v),
            "fitting": {n: {"cost_over_floor": (r.get("calibration") or {}).get("cost_over_noise_floor"),
                            "stopped_short": (r.get("calibration") or {}).get("stopped_short")}
                        for n, r in rep["recordings"].items()},
            "joint": {"start": j.get("start"), "cost_over_floor": j.get("cost_over_noise_floor"),
                      "stopped_short": j.get("stopped_short")}}


def _fmt(r: dict) -> str:
    a = r["rms_after"]
    fit = ", ".join(f"{n}: {d['cost_over_floor']:.3g}{' (short)' if d['stopped_short'] else ''}"
                    for n, d in r["fitting"].items() if d["cost_over_floor"] is not None)
    j = r["joint"]
    jc = "none" if j["cost_over_floor"] is None else f"{j['cost_over_floor']:.3g}"
    return (f"{json.dumps(r['variant'])}: held-out rms y {1e3 * a['y']:.3g} mm, i {1e3 * a['i']:.3g} mA, "
            f"u {a['u']:.3g} V; stop hit {', '.join(r['stop_hit']) or 'none'}; calibrations' cost / floor "
            f"{fit}; joint from {j['start']}: {jc}"
            f"{' (short)' if j['stopped_short'] else ''} ({r['wall_s']:.0f} s)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design-seeds", type=int, nargs="*", default=[0, 1, 2, 3])
    ap.add_argument("--orders", type=int, default=0, help="random orders of the calibration keys")
    ap.add_argument("--processes", type=int, default=1)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default="bench_maglev_spread")
    a = ap.parse_args(argv)
    variants = [{"design_seed": s} for s in a.design_seeds] + [{"order": k + 1} for k in range(a.orders)]
    out = Path(a.out)
    tasks = [(v, out / "_".join(f"{k}{x}" for k, x in v.items()), a.workers) for v in variants]
    results = []
    if a.processes > 1:
        with mp.get_context("spawn").Pool(a.processes) as pool:
            for r in pool.imap(run_variant, tasks):
                print(_fmt(r), flush=True)
                results.append(r)
    else:
        for t in tasks:
            r = run_variant(t)
            print(_fmt(r), flush=True)
            results.append(r)
    out.mkdir(parents=True, exist_ok=True)
    (out / "spread.json").write_text(json.dumps(results, indent=1))
    print(f"\n{len(results)} variants; held-out rms (pooled over {', '.join(HOLD)}), before -> after:")
    for c, unit, f in (("y", "mm", 1e3), ("i", "mA", 1e3), ("u", "V", 1.0)):
        v = np.array([r["rms_after"][c] for r in results]) * f
        b = results[0]["rms_before"][c] * f
        nz = np.median([r["noise"][c] for r in results]) * f
        print(f"  {c}: {b:.3g} -> median {np.median(v):.3g} {unit} (range {v.min():.3g}-{v.max():.3g}; "
              f"noise median {nz:.3g})")
    hit = sum(bool(r["stop_hit"]) for r in results)
    short = sum(d["stopped_short"] for r in results for d in r["fitting"].values())
    nfit = sum(len(r["fitting"]) for r in results)
    ratios = np.array([d["cost_over_floor"] for r in results for d in r["fitting"].values()
                       if d["cost_over_floor"] is not None])
    jr = np.array([r["joint"]["cost_over_floor"] for r in results if r["joint"]["cost_over_floor"] is not None])
    print(f"  the final model hits a stop the data do not in {hit} of {len(results)}")
    print(f"  fitting recordings' calibrations stopped short: {short} of {nfit}; cost over floor median "
          f"{np.median(ratios):.3g} (range {ratios.min():.3g}-{ratios.max():.3g})")
    if len(jr):
        print(f"  joint calibration cost over floor median {np.median(jr):.3g} (range {jr.min():.3g}-{jr.max():.3g}); "
              f"stopped short in {sum(bool(r['joint']['stopped_short']) for r in results)} of {len(results)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
