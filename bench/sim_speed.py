"""Simulator speed: real-time factor (simulated seconds per wall second, one core, all physics
on -- saturation, hysteresis, the lamination eddy-current ladder, the stator network's
cross-coupling, the DSP's converters with noise, quantisation and computation delay --
compilation excluded) and the ripple-peak error against a run at 10x finer resolution.

    python bench/sim_speed.py [--seconds 2.0] [--repeat 5]
    taskset -c 1 python bench/sim_speed.py      # pinned to one core when the other is busy

The timed call is the whole ``simulate()`` (excitation, equilibrium, DCM calibration, kernel,
output assembly). The real-time factor is wall-clock; on a shared machine it depends on the
load, so the CPU time of the process (``time.process_time``) and the load average are printed
with it. Each figure is the best of ``--repeat`` runs.
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from ssamb.config import apply_overrides, load_config  # noqa: E402
from ssamb.sim import simulate  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated duration of the timed run")
    ap.add_argument("--repeat", type=int, default=5, help="timed runs (the best is reported)")
    args = ap.parse_args()
    cfg = load_config()
    mag, conv = cfg["magnetics"], cfg["converters"]
    assert mag["saturation"] and mag["hysteresis"] and mag["eddy_currents"] and mag["cross_coupling"], \
        "benchmark needs all physics on"
    assert conv["current_noise_a"] > 0 and conv["current_adc_bits"] > 0 and conv["computation_delay_samples"] == 1, \
        "benchmark needs the converters in the loop"
    # warm-up: compile the kernel (excluded from the timing)
    simulate(cfg, "multisine", duration_s=0.01, progress=False)
    fs = cfg["controller"]["fs_hz"]
    best_wall = best_cpu = np.inf
    load_before = os.getloadavg()
    for _ in range(args.repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        res = simulate(cfg, "multisine", duration_s=args.seconds, progress=False, settle_s=0.0)
        best_wall = min(best_wall, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    load_after = os.getloadavg()
    n = len(res.data["t"])
    print(f"simulated: {args.seconds:.2f} s of the 100 um multisine ({n} samples at {fs:.0f} Hz), all physics on "
          f"(eddy model {mag['eddy_model']}, estimator {cfg['selfsensing']['estimator']}, converters on)")
    print(f"CPU affinity: {sorted(os.sched_getaffinity(0))}")
    print(f"load average (1 min) before/after: {load_before[0]:.2f} / {load_after[0]:.2f} on {os.cpu_count()} CPUs")
    print(f"wall time (best of {args.repeat}, incl. calibration): {best_wall:.3f} s = {1e6 * best_wall / n:.3f} us/sample")
    print(f"CPU time  (best of {args.repeat}, incl. calibration): {best_cpu:.3f} s = {1e6 * best_cpu / n:.3f} us/sample"
          f" (CPU real-time factor {args.seconds / best_cpu:.1f})")
    print(f"real-time factor: {args.seconds / best_wall:.1f}")
    # ripple peak against 10x finer resolution: rotor clamped, amplifiers at the levitation
    # currents, ideal converters (a quantised PI sample flips a code on a 1e-9 A difference), so
    # that both runs switch alike and only the integration differs
    dur = 0.02
    n = int(dur * fs)
    u_y = res.meta["equilibrium"]["u_y"]
    ideal = apply_overrides(cfg, {"converters.current_noise_a": 0.0, "converters.current_adc_bits": 0})
    runs = [simulate(ideal, duration_s=dur, arrays={"inj_y": np.full(n, u_y)}, substeps=s, track_ripple=True,
                     progress=False, pid_on=False, clamp_m=(0.0, 0.0)) for s in (1, 10)]
    m = min(len(r.ripple["i_max"]) for r in runs)
    pp_b, pp_f = (r.ripple["i_max"][:m] - r.ripple["i_min"][:m] for r in runs)
    err = np.max(np.abs(pp_b - pp_f) / pp_f)
    print(f"ripple-peak error vs 10x finer resolution: {100 * err:.4f} % (max over {m} PWM periods)")


if __name__ == "__main__":
    main()
