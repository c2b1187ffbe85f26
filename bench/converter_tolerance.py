"""Which levels of in-loop converter noise and quantisation does the default loop tolerate?

    python bench/converter_tolerance.py [--set KEY=VALUE ...]

A simulated rig sets its DSP's converters through the scenario's ``overrides``
(``converters.*``); this bench measures, for the default config, the levels at which the loop
still holds. One knob at a time from the default converters (then the study's joint variants):

* ``converters.current_noise_a`` (rms analog noise on every sampled coil current),
* ``converters.current_adc_bits`` (over +/- ``current_adc_range_a``),
* ``converters.position_noise_m`` and ``converters.position_adc_bits`` (the x probe: it acts
  on the x loop only; y is self-sensed from the currents).

Each level runs three simulations:

a. **rest**: 0.3 s from the levitated equilibrium, no excitation: rms of the position error
   ``y_meas - r_y`` (``x_meas - r_x``; both read by probes through the position converter, so
   the probe's own noise shows in them), of the rotor's true position ``y_true``, and of the
   command ``u_y`` (``u_x``) about its mean (the weight's static current);
b. **lift-off**: experiment ``levitate`` (0.3 s from the backup bearing): does it lift off and
   stay up;
c. **multisine**: the excitation of ``resources/scenarios/rig_demo.yaml`` (30 um, 5-100 Hz on
   both axes, 5 Hz lines) for 1 s (5 periods) from the levitated equilibrium; rms tracking
   error ``y_meas - r_y`` (``x_meas - r_x``) after the first period (mostly the loop's own
   response to the excitation: about 14 and 10 um with ideal converters).

Each level runs with ``--seeds`` seeds (default 8: the config's seed and the next ones; they
draw the converter noise and the multisine's phases). ``delev`` counts the seeds in which any
run touched the backup bearing after levitating, or never lifted off; the rms figures are
pooled over all seeds (a delevitated run's included). Figures are printed, never asserted; the
run takes about a minute.
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from ssamb.config import apply_overrides, load_config, validate_config  # noqa: E402
from ssamb.sim import simulate  # noqa: E402

#: the close-the-loop demo's excitation (resources/scenarios/rig_demo.yaml), 1 s
MULTISINE = {"kind": "multisine", "point": "position", "axis": "both", "amplitude_m": 3.0e-5, "f_min_hz": 5.0,
             "f_max_hz": 100.0, "f_resolution_hz": 5.0, "periods": 5, "seed": 3}
#: one knob at a time: (key, levels, display scale, display unit)
KNOBS = (
    ("converters.current_noise_a", (0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3, 6e-3, 8e-3), 1e3, "mA"),
    ("converters.current_adc_bits", (9, 10, 11, 12, 13, 14, 15, 16), 1, "bit"),
    ("converters.position_noise_m", (0.05e-6, 0.2e-6, 1e-6, 5e-6, 20e-6, 30e-6, 40e-6), 1e6, "um"),
    ("converters.position_adc_bits", (6, 8, 10, 12, 14, 16), 1, "bit"),
)
#: the assumption study's joint converter variants (config.yaml, study.assumptions.converters)
JOINT = (
    ("12 bit, 1 mA", {"converters.current_adc_bits": 12, "converters.current_noise_a": 1.0e-3}),
    ("16 bit, 0.2 mA", {"converters.current_adc_bits": 16, "converters.current_noise_a": 2.0e-4}),
    ("ideal", {"converters.current_adc_bits": 0, "converters.current_noise_a": 0.0,
               "converters.position_adc_bits": 0, "converters.position_noise_m": 0.0,
               "converters.computation_delay_samples": 0}),
)
REST_S = 0.3


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _status(res, start: str) -> str:
    if start == "rest" and (np.asarray(res.data["contact"]) > 0.5).all():
        return "no lift-off"
    t = res.meta["delevitation_s"]
    return "ok" if t is None else f"delev {t:.3f}"


def measure(cfg: dict, seed: int) -> dict:
    """Rest, lift-off and multisine runs of one configuration and seed: delevitated or not, and
    mean squares (SI units)."""
    kw = {"progress": False, "seed": seed}
    rest = simulate(cfg, duration_s=REST_S, excitation={"kind": "none"}, start="levitated", **kw)
    lift = simulate(cfg, "levitate", **kw)
    ms = simulate(cfg, excitation=dict(MULTISINE), start="levitated", **kw)
    out = {"delev": any(_status(r, st) != "ok" for r, st in ((rest, "levitated"), (lift, "rest"), (ms, "levitated")))}
    d = rest.data
    for ax in ("x", "y"):
        out[f"rest_{ax}_m"] = np.mean(np.square(d[f"{ax}_meas"] - d[f"r_{ax}"]))
        out[f"rest_u{ax}_a"] = np.var(d[f"u_{ax}"])
    out["rest_ytrue_m"] = np.mean(np.square(d["y_true"]))
    d = ms.data
    k = d["t"] >= 1.0 / MULTISINE["f_resolution_hz"]
    for ax in ("x", "y"):
        out[f"ms_{ax}_m"] = np.mean(np.square((d[f"{ax}_meas"] - d[f"r_{ax}"])[k]))
    return out


def measure_seeds(cfg: dict, seeds: list[int]) -> dict:
    """:func:`measure` over seeds: how many delevitated, and each rms pooled over the seeds."""
    runs = [measure(cfg, s) for s in seeds]
    out = {k: float(np.sqrt(np.mean([r[k] for r in runs]))) for k in runs[0] if k != "delev"}
    out["delev"] = sum(r["delev"] for r in runs)
    out["n"] = len(runs)
    return out


def _row(label: str, m: dict) -> str:
    um = {k: 1e6 * v for k, v in m.items() if k.endswith("_m")}
    return (f"  {label:>15s}  {m['delev']:>3d}/{m['n']:<3d}  {um['rest_y_m']:7.2f}  {um['rest_ytrue_m']:7.2f}  "
            f"{m['rest_uy_a']:7.3f}  {um['rest_x_m']:7.2f}  {m['rest_ux_a']:7.3f}  {um['ms_y_m']:7.2f}  "
            f"{um['ms_x_m']:7.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--seeds", type=int, default=8, help="seeds per level (converter noise and excitation)")
    args = ap.parse_args()
    cfg = load_config(overrides=args.overrides)
    seeds = [int(cfg["seed"]) + k for k in range(args.seeds)]
    t0 = time.perf_counter()
    conv = cfg["converters"]
    print(f"default converters: current {1e3 * conv['current_noise_a']:g} mA rms, {conv['current_adc_bits']} bit "
          f"over +/-{conv['current_adc_range_a']:g} A; x probe {1e6 * conv['position_noise_m']:g} um rms, "
          f"{conv['position_adc_bits']} bit over +/-{1e3 * conv['position_adc_range_m']:g} mm; "
          f"delay {conv['computation_delay_samples']} sample")
    print(f"rest: {REST_S} s levitated, no excitation (u: rms about its mean); lift-off: experiment levitate; "
          "multisine: 30 um 5-100 Hz both axes, 1 s, rms after the first period")
    print(f"delev: seeds (of {len(seeds)}) in which any run touched the backup bearing after levitating or "
          "never lifted off; rms pooled over the seeds")
    names = ("delev", "rest y", "y_true", "rest uy", "rest x", "rest ux", "ms y", "ms x")
    head = f"  {'level':>15s}  {names[0]:>7s}" + "".join(f"  {n:>7s}" for n in names[1:])
    units = f"  {'':>15s}  {'':>7s}" + "".join(f"  {u:>7s}" for u in ("um", "um", "A", "um", "A", "um", "um"))
    for key, levels, scale, unit in KNOBS:
        print(f"\n{key} (default {conv[key.split('.')[1]] * scale:g} {unit})")
        print(head + "\n" + units)
        for v in levels:
            c = apply_overrides(cfg, {key: v})
            validate_config(c)
            print(_row(f"{v * scale:g} {unit}", measure_seeds(c, seeds)), flush=True)
    print("\njoint variants (the assumption study's)")
    print(head + "\n" + units)
    for label, ov in JOINT:
        c = apply_overrides(cfg, ov)
        validate_config(c)
        print(_row(label, measure_seeds(c, seeds)), flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s wall")


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    main()
