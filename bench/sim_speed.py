"""Simulator speed: real-time factor (simulated seconds per wall second, one core, all physics
on -- saturation, hysteresis, the lamination eddy-current ladder, the stator network's
cross-coupling, the DSP's converters with noise, quantisation and computation delay --
compilation excluded) and the ripple-peak error against a run at 10x finer resolution.

    python bench/sim_speed.py [--seconds 2.0] [--repeat 5]
    taskset -c 1 python bench/sim_speed.py      # pinned to one core when the other is busy

The timed call is the whole ``simulate()`` (excitation, equilibrium, DCM calibration, kernel,
output assembly). The real-time factor is wall-clock; on a shared machine it depends on the
load, so the CPU time of the process (``time.process_time``) and the load average are printed
with it. Each figure is the best of ``--repeat`` runs. A per-stage breakdown of the CPU time
follows (the best run of each stage over further ``--repeat`` runs, as fractions of their sum).
"""
from __future__ import annotations

import argparse
import os
import time
from contextlib import contextmanager

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from ssamb.config import apply_overrides, load_config  # noqa: E402
from ssamb.sim import api, simulate  # noqa: E402

#: stages of simulate() timed by the breakdown: the functions of ssamb.sim.api that run them
#: (a stage called inside another, e.g. the kernel runs of the calibration, counts to the outer one)
STAGES = {"excitation": "excitation_arrays", "drive": "_drive", "noise": "converter_noise",
          "equilibrium": "equilibrium", "calibration": "calibrate_selfsensing", "kernel": "run_kernel",
          "assembly": "_assemble"}


@contextmanager
def stage_timers(totals: dict):
    """Wrap the stage functions of :mod:`ssamb.sim.api` so that each adds its exclusive CPU time
    (less the stages nested in it) to ``totals[stage]``; restored on exit."""
    saved = {name: getattr(api, fn) for name, fn in STAGES.items()}
    stack = []                      # CPU time of the nested stages, one entry per open stage

    def timed(stage, fn):
        def wrapper(*args, **kwargs):
            if stack and stack[-1][0] != "drive":     # nested (not the excitation): the outer stage's
                return fn(*args, **kwargs)
            stack.append([stage, 0.0])
            c0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                dt = time.process_time() - c0
                inner = stack.pop()[1]
                totals[stage] = totals.get(stage, 0.0) + dt - inner
                if stack:
                    stack[-1][1] += dt
        return wrapper

    for name, fn in STAGES.items():
        setattr(api, fn, timed(name, saved[name]))
    try:
        yield totals
    finally:
        for name, fn in STAGES.items():
            setattr(api, fn, saved[name])


def breakdown(cfg: dict, seconds: float, repeat: int) -> None:
    """Print the CPU time of every stage of simulate() (best of ``repeat``) and its share."""
    best: dict = {}
    for _ in range(repeat):
        totals: dict = {}
        c0 = time.process_time()
        with stage_timers(totals):
            simulate(cfg, "multisine", duration_s=seconds, progress=False, settle_s=0.0)
        totals["other"] = time.process_time() - c0 - sum(totals.values())
        for k, v in totals.items():
            best[k] = min(best.get(k, np.inf), v)
    total = sum(best.values())
    print(f"per-stage CPU time (best of {repeat} per stage; sum {total:.3f} s):")
    for k in (*STAGES, "other"):
        print(f"  {k:12s} {1e3 * best.get(k, 0.0):8.1f} ms  {100 * best.get(k, 0.0) / total:5.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated duration of the timed run")
    ap.add_argument("--repeat", type=int, default=5, help="timed runs (the best is reported)")
    ap.add_argument("--no-breakdown", action="store_true", help="skip the per-stage breakdown")
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
    print(f"wall time (best of {args.repeat}, incl. calibration): {best_wall:.3f} s = {1e6 * best_wall / n:.3f} "
          "us/sample")
    print(f"CPU time  (best of {args.repeat}, incl. calibration): {best_cpu:.3f} s = {1e6 * best_cpu / n:.3f} us/sample"
          f" (CPU real-time factor {args.seconds / best_cpu:.1f})")
    print(f"real-time factor: {args.seconds / best_wall:.1f}")
    if not args.no_breakdown:
        breakdown(cfg, args.seconds, args.repeat)
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
    from ssamb import pin_blas_threads

    pin_blas_threads()
    main()
