"""Self-sensing estimators in the loop: their error, and why the paper's peak DCM runs away.

    python bench/selfsensing_error.py [--set KEY=VALUE ...]

Part 1 -- error of each estimator (``selfsensing.estimator``: lsq, peak) with the default
converters (noise, quantisation, computation delay) in the loop: rms of y_ss - y_true in the
99 um 11-50 Hz sweep (the experiment as configured, after its pre-roll) and at rest (from the
levitated equilibrium at t = 0, no excitation), and the delevitation time if any (the error is
taken up to it).

Part 2 -- the evidence for the peak estimator's failure:

a. the Table 1 loop itself (units A/m: the loop's natural frequency and damping, and its phase
   margin with an ideal sensor and with the self-sensing's window, low-pass and delays);
b. each estimator's sensitivity to the current it commands: the rotor clamped, a 0.1 A current
   command at 200, 500, 1000 Hz, the raw estimate's response at that frequency (um per A) --
   with the lamination eddy currents on and off, and for peak also without the DSP's R i dt
   term in the volt-seconds; times the controller's gain there (A/m, with the estimate
   low-pass) it is the gain of the parasitic loop estimate -> command -> ripple -> estimate,
   which must stay well below 1;
c. the closed-loop outcome with peak (delevitation time over 0.3 s at rest, from the levitated
   equilibrium at t = 0) as the suspects of
   the issue are removed one at a time: eddy currents, converter noise, computation delay, a
   lower estimate low-pass.

Figures are printed, never asserted; the run takes about a minute.
"""
from __future__ import annotations

import argparse
import math
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from ssamb.config import apply_overrides, load_config  # noqa: E402
from ssamb.sim import amb_params, simulate  # noqa: E402
from ssamb.sim.api import run_kernel  # noqa: E402
from ssamb.sim.kernel import OUT_NAMES  # noqa: E402
from ssamb.sim.statics import equilibrium, linear_stiffness, network_tables  # noqa: E402

IDEAL = {"converters.current_noise_a": 0.0, "converters.current_adc_bits": 0,
         "converters.position_noise_m": 0.0, "converters.position_adc_bits": 0}


def rms_um(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) * 1e6


def part1(cfg) -> None:
    fs = cfg["controller"]["fs_hz"]
    print("1. estimator error in the loop, default converters "
          f"({cfg['converters']['current_adc_bits']}-bit over +/-{cfg['converters']['current_adc_range_a']} A, "
          f"{1e3 * cfg['converters']['current_noise_a']:.1f} mA rms)")
    print(f"   {'estimator':10s} {'sweep rms (um)':>15s} {'sweep delev (s)':>16s} {'rest rms (um)':>14s} "
          f"{'rest delev (s)':>15s}")
    for est in ("lsq", "peak"):
        c = apply_overrides(cfg, {"selfsensing.estimator": est})
        sweep = simulate(c, "sweep", progress=False)
        n = int(0.3 * fs)
        rest = simulate(c, duration_s=0.3, arrays={"r_y": np.zeros(n)}, progress=False, settle_s=0.0)
        row = []
        for r in (sweep, rest):
            d = r.data
            t_end = r.meta["delevitation_s"] if r.meta["delevitation_s"] is not None else np.inf
            keep = d["t"] <= t_end
            row += [rms_um((d["y_ss"] - d["y_true"])[keep]), r.meta["delevitation_s"]]
        fmt = lambda v: "none" if v is None else f"{v:.3f}"   # noqa: E731
        print(f"   {est:10s} {row[0]:15.1f} {fmt(row[1]):>16s} {row[2]:14.1f} {fmt(row[3]):>15s}")


def controller_gain(cfg, f_hz) -> complex:
    """|C(j w) LP(j w)|: the PID (with its derivative filter) and the estimate low-pass."""
    t1, ss = cfg["table1"], cfg["selfsensing"]
    s = 2j * math.pi * f_hz
    wd = 2 * math.pi * cfg["controller"]["derivative_filter_hz"]
    c = t1["pid_kp_a_per_m"] + t1["pid_ki_a_per_m_s"] / s + t1["pid_kd_a_s_per_m"] * s / (1 + s / wd)
    return c / (1 + s / (2 * math.pi * ss["lowpass_hz"])) ** ss["lowpass_order"]


def part2a(cfg) -> None:
    par = amb_params(cfg)
    ki, ks = linear_stiffness(par)          # the static model's own (series magnets + stator network)
    t1 = cfg["table1"]
    k_net = t1["pid_kp_a_per_m"] * ki - ks
    wn = math.sqrt(k_net / par.mass_kg)
    zeta = t1["pid_kd_a_s_per_m"] * ki / (2 * math.sqrt(k_net * par.mass_kg))
    print("2a. the Table 1 loop, gains in A/m (controller output = differential current)")
    print(f"    ki = {ki:.1f} N/A, ks = {ks:.3g} N/m (levitated, network on): Kp ki - ks = {k_net:.3g} N/m, natural "
          "frequency "
          f"{wn / 2 / math.pi:.0f} Hz, damping {zeta:.2f}")
    f = np.logspace(0, 4, 20000)
    s = 2j * np.pi * f
    plant = ki / (par.mass_kg * s**2 - ks)
    ss = cfg["selfsensing"]
    delay = ((ss["window_samples"] / 2 + cfg["converters"]["computation_delay_samples"]) / par.fs_hz
             + 0.5 / par.f_pwm_hz)
    wd = 2 * np.pi * cfg["controller"]["derivative_filter_hz"]
    pid = t1["pid_kp_a_per_m"] + t1["pid_ki_a_per_m_s"] / s + t1["pid_kd_a_s_per_m"] * s / (1 + s / wd)
    for name, h in (("ideal sensor", np.ones_like(s)),
                    ("self-sensing (window, low-pass, delays)",
                     np.exp(-s * delay) / (1 + s / (2 * np.pi * ss["lowpass_hz"])) ** ss["lowpass_order"])):
        loop = pid * plant * h
        i = np.flatnonzero(np.diff(np.sign(np.abs(loop) - 1)))[-1]
        pm = 180 + np.degrees(np.angle(loop[i]))
        print(f"    {name}: crossover {f[i]:.0f} Hz, phase margin {pm:.0f} deg, |S| peak "
              f"{np.max(np.abs(1 / (1 + loop))):.2f}")


def sensitivity_um_per_a(cfg, f_hz, **pack_overrides) -> float:
    """Raw estimate's response (um per A) to a 0.1 A current command at ``f_hz``, rotor clamped."""
    par = amb_params(cfg)
    packed = par.pack(CLAMP=1.0, PID_ON=0.0, **pack_overrides)
    qtab = network_tables(par)
    eq = equilibrium(par, packed, qtab)
    fs = par.fs_hz
    n = int(0.06 * fs)
    t = np.arange(n) / fs
    drive = np.zeros((6, n))
    drive[2] = eq["u_x"]
    drive[3] = eq["u_y"] + 0.1 * np.sin(2 * np.pi * f_hz * t)
    out, _, _, _ = run_kernel(par, packed, qtab, "levitated", eq, drive, np.zeros((6, n)), np.zeros((4, n)))
    y = out[OUT_NAMES.index("y_ss_raw")]
    keep = t > 0.01
    amp = 2 * np.mean((y[keep] - y[keep].mean()) * np.exp(-2j * np.pi * f_hz * t[keep]))
    return abs(amp) / 0.1 * 1e6


def part2b(cfg) -> None:
    freqs = (200.0, 500.0, 1000.0)
    print("2b. estimator response to its own current command (um/A, rotor clamped, ideal converters); "
          "parasitic loop gain = that x |C LP|")
    print("    |C LP| (A/m): " + ", ".join(f"{f:.0f} Hz {abs(controller_gain(cfg, f)):.3g}" for f in freqs))
    base = apply_overrides(cfg, IDEAL)
    cases = [("lsq, eddy ladder", {"selfsensing.estimator": "lsq"}, {}),
             ("lsq, no eddy currents", {"selfsensing.estimator": "lsq", "magnetics.eddy_currents": False}, {}),
             ("peak, eddy ladder", {"selfsensing.estimator": "peak"}, {}),
             ("peak, no eddy currents", {"selfsensing.estimator": "peak", "magnetics.eddy_currents": False}, {}),
             ("peak, no eddy, no R i dt term", {"selfsensing.estimator": "peak", "magnetics.eddy_currents": False},
              {"SS_R": 0.0})]
    for name, ov, pack_ov in cases:
        c = apply_overrides(base, ov)
        sens = [sensitivity_um_per_a(c, f, **pack_ov) for f in freqs]
        gains = [s * 1e-6 * abs(controller_gain(c, f)) for s, f in zip(sens, freqs)]
        print(f"    {name:32s} " + "  ".join(f"{s:7.1f} um/A (gain {g:5.2f})" for s, g in zip(sens, gains)))


def part2c(cfg) -> None:
    fs = cfg["controller"]["fs_hz"]
    n = int(0.3 * fs)
    peak = {"selfsensing.estimator": "peak"}
    cases = [("peak, default", {}), ("peak, no eddy currents", {"magnetics.eddy_currents": False}),
             ("peak, ideal converters", IDEAL),
             ("peak, no computation delay", {"converters.computation_delay_samples": 0}),
             ("peak, estimate low-pass 400 Hz", {"selfsensing.lowpass_hz": 400.0}),
             ("peak, window 25 samples", {"selfsensing.window_samples": 25}),
             ("lsq, default", {"selfsensing.estimator": "lsq"})]
    print("2c. closed loop at rest, 0.3 s: delevitation time (none: levitates) and rms estimate error")
    for name, ov in cases:
        c = apply_overrides(cfg, {**peak, **ov})
        r = simulate(c, duration_s=0.3, arrays={"r_y": np.zeros(n)}, progress=False, settle_s=0.0)
        dl = r.meta["delevitation_s"]
        d = r.data
        keep = d["t"] <= (dl if dl is not None else np.inf)
        print(f"    {name:34s} delevitation {'none' if dl is None else f'{dl:.4f} s':>9s}, "
              f"rms error {rms_um((d['y_ss'] - d['y_true'])[keep]):7.1f} um")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="config overrides")
    args = ap.parse_args()
    cfg = apply_overrides(load_config(), args.set) if args.set else load_config()
    print(f"load average (1 min): {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    part1(cfg)
    part2a(cfg)
    part2b(cfg)
    part2c(cfg)


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    main()
