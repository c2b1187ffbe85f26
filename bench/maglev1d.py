"""The levitated ball's device against its five shipped recordings: the figures behind it.

    python bench/maglev1d.py [--seeds 5] [--repeat 20]

Prints, per recording (resources/maglev1d/*.npz):

1. the controller check: the rig's controller (ssamb.maglev1d.controller) run on the logged
   y, i, yd against the logged u -- the fraction of samples within the log's rounding (u has 4
   decimals) and within one PWM step, the rms and largest difference; for a moving reference
   also with the reference's formula fitted to the logged yd (written rounded to 1 um), its
   settings rounded to three significant figures (the amplitude to 1 um);
2. the physical checks (ssamb.maglev1d.checks): the coil's time constant and the command's
   incremental resistance and offset from the current's response, against the published
   model's; the equilibrium current on the plateaus against the force law; the sensors' noise;
3. the linearised sampled loop of the published-parameter model, and of the model at the
   start estimate (the checks' values), at 4, 5 and 6 mm;
4. replays on the usable (levitated) stretches: rms error per channel (median and range over
   --seeds noise realisations) and whether the replayed ball touches a stop, for the
   published-parameter model, for the model at each recording's own start estimate, and at the
   start estimate of another recording (escalon's for the others, multiescalon's for escalon);
5. the replay's speed: wall time of a replay of the whole recording (best of --repeat).
"""
from __future__ import annotations

import argparse
import copy
import os
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from ssamb.device import get_device  # noqa: E402
from ssamb.maglev1d import checks, controller  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DATA = sorted((ROOT / "resources" / "maglev1d").glob("dataset_*.npz"))


def short(p: Path) -> str:
    return p.stem.split("_")[1]


def fitted_reference(t, yd):
    """The moving reference's formula c + A sin(2 pi (f0 s + f1 s^2)), s = t - t0 (t0: where
    yd first moves), fitted to the logged yd; None for a piecewise-constant reference."""
    k0 = int(np.argmax(np.abs(np.diff(yd)) > 0))
    if np.count_nonzero(np.diff(yd)) <= 20:
        return None
    t0 = t[k0]
    s = t - t0
    c = float(yd[0])
    amp = float(np.max(np.abs(yd - c)))
    m = s > 0
    x = (yd[m] - c) / amp
    # frequency start: zero crossings in the first and second half
    zc = np.nonzero(np.diff(np.sign(x)) != 0)[0]
    best = None
    for f0 in np.linspace(0.05, 1.0, 20):
        for f1 in (0.0, 0.01, 0.03, 0.06):
            r = least_squares(lambda p: p[2] * np.sin(2 * np.pi * (p[0] * s[m] + p[1] * s[m] ** 2)) - x,
                              [f0, f1, 1.0])
            if best is None or r.cost < best.cost:
                best = r
    f0, f1, a = best.x
    # the profile's settings are round numbers: three significant figures, the amplitude in um
    f0, f1 = (float(f"{v:.3g}") if abs(v) > 1e-6 else 0.0 for v in (f0, f1))
    a = round(amp * a * 1e6) / 1e6 / amp
    ref = c + amp * a * np.sin(2 * np.pi * (f0 * s + f1 * s * s))
    ref[~m] = yd[~m]
    return ref, {"t0_s": float(t0), "offset_m": c, "amplitude_m": float(amp * a), "f0_hz": float(f0),
                 "f1_hz_per_s": float(f1), "zero_crossings": int(len(zc)),
                 "max_abs_vs_log_m": float(np.max(np.abs(ref - yd)))}


def with_overrides(cfg, over):
    c = copy.deepcopy(cfg)
    for k, v in over.items():
        sec, key = k.split(".")
        c[sec][key] = v
    return c


def replay_errors(dev, cfg, rec, seeds):
    m = np.zeros(rec.n, bool)
    for a, b in rec.usable:
        m[a:b] = True
    rows, contact = [], 0
    for s in range(1, seeds + 1):
        rep = dev.replay(cfg, rec, [], rec.n, s)
        rows.append([np.sqrt(np.mean((rep.channels[c][m] - rec.channels[c][m]) ** 2)) for c in dev.channels])
        contact += int(rep.contact)
    r = np.array(rows)
    return {c: (np.median(r[:, j]), r[:, j].min(), r[:, j].max()) for j, c in enumerate(dev.channels)}, contact


def fmt_err(e):
    sc = {"y": (1e6, "um"), "i": (1e3, "mA"), "u": (1.0, "V")}
    return "  ".join(f"{c} {e[c][0] * sc[c][0]:.4g} [{e[c][1] * sc[c][0]:.4g}-{e[c][2] * sc[c][0]:.4g}] {sc[c][1]}"
                     for c in e)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    dev = get_device("maglev1d")
    cfg = dev.default_config()
    recs, arrays = {}, {}
    for p in DATA:
        a, meta = dev.load(p)
        dev.validate(a, str(p))
        arrays[short(p)] = a
        recs[short(p)] = dev.record(a, meta, cfg, str(p))

    print("== 1. controller check (logged u against the controller run on the logged y, i, yd)")
    for name, a in arrays.items():
        r = controller.check(a, cfg)
        print(f"{name:13s} n={r['n']}  within rounding {100 * r['within_rounding']:.1f} %  within one PWM step "
              f"{100 * r['within_pwm_step']:.1f} %  rms {r['rms_v']:.3g} V  max {r['max_abs_v']:.3g} V")
        fr = fitted_reference(a["t"], a["yd"])
        if fr is not None:
            ref, info = fr
            r2 = controller.check(a, cfg, yd=ref)
            print(f"{'':13s} with the reference's formula ({info['offset_m'] * 1e3:.4g} mm + "
                  f"{info['amplitude_m'] * 1e3:.4g} mm "
                  f"sin(2 pi ({info['f0_hz']:.4g} s + {info['f1_hz_per_s']:.4g} s^2)), s = t - {info['t0_s']:.4g} s; "
                  f"max |formula - logged yd| {info['max_abs_vs_log_m'] * 1e6:.3g} um): within rounding "
                  f"{100 * r2['within_rounding']:.1f} %, rms {r2['rms_v']:.3g} V")

    print("\n== 2. physical checks")
    for name, a in arrays.items():
        c = checks.coil_time_constant(a, cfg)
        e = checks.equilibrium_currents(a, cfg)
        nz = checks.noise_levels(a, cfg)
        print(f"{name:13s} coil: tau {c['tau_s'] * 1e3:.2f} ms (published L/R {c['tau_model_s'] * 1e3:.2f} ms; "
              f"L = tau R = {c['inductance_h_if_r_nominal'] * 1e3:.1f} mH "
              f"vs L(y) {c['inductance_model_h'] * 1e3:.1f} mH "
              f"at {c['y_mean_m'] * 1e3:.2f} mm), R/g {c['r_over_gain_ohm']:.2f} ohm "
              f"(model {c['r_over_gain_model_ohm']:.2f}), "
              f"offset {c['offset_v']:.2f} V (model 0); {c['samples']} samples")
        if e["plateaus"]:
            line = (f"length of the line through them {e['length_m'] * 1e3:.2f} mm "
                    f"(law: a = {cfg['magnet']['a_m'] * 1e3:.2f} mm)"
                    if "length_m" in e else "one level")
            print(f"{'':13s} equilibrium: {e['plateaus']} settled 2 s plateaus at "
                  f"{min(e['y_m']) * 1e3:.2f}-{max(e['y_m']) * 1e3:.2f} mm, measured/force-law current "
                  f"{min(np.array(e['i_a']) / np.array(e['i_model_a'])):.3f}-"
                  f"{max(np.array(e['i_a']) / np.array(e['i_model_a'])):.3f}; {line}")
        else:
            print(f"{'':13s} equilibrium: no settled plateau (moving reference)")
        print(f"{'':13s} noise before the ADCs (upper bounds): current {nz['current_a'] * 1e3:.2f} mA "
              f"({nz['current_counts']:.2f} counts), position {nz['position_m'] * 1e6:.1f} um "
              f"({nz['position_counts']:.2f} counts)")

    print("\n== 3. linearised sampled loop (spectral radius; least damped oscillation)")
    starts = {n: dev.initial_estimate(r, cfg) for n, r in recs.items()}
    for lab, c in [("published", cfg), ("start(escalon)", with_overrides(cfg, starts["escalon"]))]:
        gs, os_ = c["sensors"]["position_gain"], c["sensors"]["position_offset_m"]
        parts = []
        for yr in (0.004, 0.005, 0.006):
            r = checks.loop_poles(c, (yr - os_) / gs, {"sensor_gain": gs})
            parts.append(f"{yr * 1e3:.0f} mm: radius {r['spectral_radius']:.3f}, zeta {r['least_damping']:.3f} "
                         f"at {r['least_damped_hz']:.1f} Hz, {'stable' if r['stable'] else 'UNSTABLE'}")
        print(f"{lab:15s} " + "; ".join(parts))
    for n, s in starts.items():
        print(f"start estimate from {n:12s} " + ", ".join(f"{k} {v:.4g}" for k, v in s.items()))

    print(f"\n== 4. replays on the usable stretches: rms error, median [range] over {args.seeds} noise seeds")
    for name, rec in recs.items():
        used = sum(b - a for a, b in rec.usable)
        other = "multiescalon" if name == "escalon" else "escalon"
        print(f"{name:13s} usable {used} of {rec.n} samples in {len(rec.usable)} stretch(es); data sd "
              f"y {np.std(np.concatenate([rec.channels['y'][a:b] for a, b in rec.usable])) * 1e6:.0f} um")
        for lab, c in [("published", cfg), ("own start", with_overrides(cfg, starts[name])),
                       (f"{other} start", with_overrides(cfg, starts[other]))]:
            e, contact = replay_errors(dev, c, rec, args.seeds)
            print(f"{'':13s} {lab:18s} {fmt_err(e)}; touches a stop in {contact} of {args.seeds}")

    print("\n== 5. replay speed")
    for name, rec in recs.items():
        dev.replay(cfg, rec, [], rec.n, 1)
        best = np.inf
        for _ in range(args.repeat):
            t = time.perf_counter()
            dev.replay(cfg, rec, [], rec.n, 1)
            best = min(best, time.perf_counter() - t)
        print(f"{name:13s} {rec.duration_s:.1f} s record: {best * 1e3:.2f} ms per replay "
              f"({sum(b - a for a, b in rec.usable) / rec.fs_hz:.1f} s simulated)")


if __name__ == "__main__":
    main()
