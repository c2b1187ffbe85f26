"""Wall time and peak memory of each subsystem identification (SIPPY at 83.3 kHz, no decimation).

Usage::

    python bench/ident_speed.py [--data results/sim/id_pulses.npz] [--methods N4SID PARSIM-K]
                                [--ss-f 30] [--ss-p 30] [--duration-s 0.5] [--json out.json]
                                [--subsystems plant amplifier] [--blas-threads 1]

Uses ``results/sim/id_pulses.npz`` (the simulator's identification experiment) if it exists,
synthetic data otherwise, and prints which. The synthetic data have the paper's I/O dimensions
and orders (plant 4->2 order 9, amplifier 4->4 order 7, self-sensing 1->1 order 3), the default
length (0.5 s at 83.3 kHz = 41 650 samples), AMB-like operating points (currents 3 A +- pulses
of 0.3 A, positions ~1e-5 m) and 60 dB output noise; the systems are random but stable
(seeded). Each identification runs in a fresh process so that its peak resident memory
(``ru_maxrss``, column "RSS GB"; "+RSS GB" is the increase during the call) is its own; with
``--tracemalloc`` the peak of the arrays allocated through Python/numpy during the call is
reported too ("numpy GB", LAPACK workspace excluded; it slows the Python loops, so the wall
times of that run are inflated). Imports and the numba compilation are done before the timer.
Wall times depend on the machine's load (printed); on a shared 2-core machine
``--blas-threads 1`` was 2-3x faster than the default 2 OpenBLAS threads.
"""
from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import queue
import os
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ssamb.channels import SUBSYSTEMS, VARIANTS, structure, subsystem_data  # noqa: E402
from ssamb.identification import FS_HZ_DEFAULT, identify  # noqa: E402
from ssamb.paper import PAPER  # noqa: E402

#: the paper's structure of each subsystem (its I/O) and its order (section 3)
PAPER_STRUCTURES = {sub: structure(sub, VARIANTS[sub][2]) for sub in SUBSYSTEMS}
PAPER_ORDERS = {sub: int(PAPER[f"order_{sub}"][0]) for sub in SUBSYSTEMS}

REAL_DATA = ROOT / "results" / "sim" / "id_pulses.npz"


def _pulses(n: int, n_ch: int, rng: np.random.Generator, fs_hz: float) -> np.ndarray:
    """Random rectangular pulses of widths 0.2-4 ms, amplitude +-1 or 0 (like id_pulses)."""
    out = np.zeros((n, n_ch))
    for c in range(n_ch):
        i = 0
        while i < n:
            w = int(rng.integers(int(2e-4 * fs_hz), int(4e-3 * fs_hz)))
            out[i:i + w, c] = rng.choice([-1.0, 0.0, 1.0])
            i += w
    return out


def _random_stable(n: int, m: int, l_: int, rng: np.random.Generator, fs_hz: float):
    """A random stable discrete system with poles between 30 Hz and 15 kHz (modal form)."""
    A = np.zeros((n, n))
    i = 0
    while i < n:
        f = np.exp(rng.uniform(np.log(30.0), np.log(1.5e4)))
        r = np.exp(-2 * np.pi * f * rng.uniform(0.05, 0.7) / fs_hz)
        th = 2 * np.pi * f / fs_hz
        if i + 1 < n and rng.random() < 0.6:
            A[i:i + 2, i:i + 2] = r * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
            i += 2
        else:
            A[i, i] = np.exp(-2 * np.pi * f / fs_hz)
            i += 1
    B = rng.standard_normal((n, m)) * (1 - np.abs(np.diag(A)))[:, None]
    C = rng.standard_normal((l_, n))
    return A, B, C


def synthetic_data(duration_s: float, fs_hz: float, seed: int = 1) -> dict:
    """Per-subsystem (u, y, input_names, output_names) with the paper's dimensions."""
    import scipy.signal

    rng = np.random.default_rng(seed)
    n_samples = int(round(duration_s * fs_hz))
    out = {}
    specs = {  # input operating point and pulse amplitude, output scale and offset
        "plant": (np.array([3.57, 2.43, 3.0, 3.0]), 0.3, 1e-5, 0.0),
        "amplifier": (np.array([0.0, 0.57, 0.0, 0.0]), np.array([0.3, 0.3, 1e-5, 1e-5]), 0.3, 3.0),
        "selfsensing": (np.array([3.57]), 0.3, 1e-5, 0.0),
    }
    for sub, (u_op, amp, y_scale, y_off) in specs.items():
        m, l_ = len(PAPER_STRUCTURES[sub].inputs), len(PAPER_STRUCTURES[sub].outputs)
        A, B, C = _random_stable(PAPER_ORDERS[sub], m, l_, rng, fs_hz)
        u = u_op + amp * _pulses(n_samples, m, rng, fs_hz)
        w = (u - u_op) / np.where(np.ravel(amp) > 0, amp, 1.0)
        _, y, _ = scipy.signal.dlsim((A, B, C, np.zeros((l_, m)), 1.0), w)
        y = y_off + y_scale * y / y.std(axis=0)
        y = y + 1e-3 * y_scale * rng.standard_normal(y.shape)
        out[sub] = (u, y, PAPER_STRUCTURES[sub].inputs, PAPER_STRUCTURES[sub].outputs)
    return out


def _worker(args, queue):
    sub, u, y, ins, outs, order, method, ss_f, ss_p, fs_hz, use_tracemalloc = args
    # warm-up outside the timing: SIPPY's import (control.matlab, ...) and the compiled kernels
    import sippy_unipi  # noqa: F401

    from ssamb.identification.sippy_fast import _jit_kernels

    _jit_kernels()
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if use_tracemalloc:
        tracemalloc.start()
    t0 = time.perf_counter()
    try:
        mdl = identify(u, y, order, method, fs_hz, ins, outs, ss_f=ss_f, ss_p=ss_p)
        err = None
    except Exception as exc:  # report, do not crash the benchmark
        mdl, err = None, f"{type(exc).__name__}: {exc}"
    wall = time.perf_counter() - t0
    peak = math.nan
    if use_tracemalloc:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    res = {"subsystem": sub, "method": method, "order": order, "inputs": len(ins), "outputs": len(outs),
           "n_samples": len(u), "ss_f": ss_f, "ss_p": ss_p, "wall_s": wall,
           "peak_rss_gb": rss * 1024 / 1e9, "rss_increase_gb": (rss - rss0) * 1024 / 1e9,
           "tracemalloc_peak_gb": peak / 1e9, "error": err}
    if mdl is not None:
        res["spectral_radius"] = mdl.spectral_radius
        h = "auto"
        res["fit_estimation_pct"] = np.round(mdl.fit(u, y, horizon=h), 2).tolist()
    queue.put(res)


def run(args) -> list[dict]:
    if args.data is not None or REAL_DATA.exists():
        path = Path(args.data) if args.data is not None else REAL_DATA
        from ssamb.io import load_npz

        arrays, _ = load_npz(path)
        fs_hz = float(arrays.get("fs_hz", FS_HZ_DEFAULT))
        data = {sub: (*subsystem_data(arrays, st), st.inputs, st.outputs) for sub, st in PAPER_STRUCTURES.items()}
        print(f"data: {path} (real simulator data), fs = {fs_hz:g} Hz")
    else:
        fs_hz = FS_HZ_DEFAULT
        data = synthetic_data(args.duration_s, fs_hz, args.seed)
        print(f"data: synthetic (no {REAL_DATA.relative_to(ROOT)}), {args.duration_s} s at {fs_hz:g} Hz, seed "
              f"{args.seed}")
    print(f"cpus: {os.cpu_count()}, load average at start: {os.getloadavg()[0]:.2f}")
    if args.blas_threads is not None:  # inherited by the spawned workers before numpy loads
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(args.blas_threads)
        print(f"BLAS threads per identification: {args.blas_threads}")
    ctx = mp.get_context("spawn")
    rows = []
    hdr = (f"{'subsystem':12s}{'method':10s}{'I/O':>6s}{'order':>6s}{'N':>8s}{'f/p':>7s}{'wall s':>8s}"
           f"{'RSS GB':>8s}{'+RSS GB':>8s}{'numpy GB':>9s}  fit (estimation, %)")
    print(hdr)
    print("-" * len(hdr))
    for sub in args.subsystems:
        u, y, ins, outs = data[sub]
        for method in args.methods:
            q = ctx.Queue()
            p = ctx.Process(target=_worker, args=((sub, u, y, ins, outs, PAPER_ORDERS[sub], method,
                                                   args.ss_f, args.ss_p, fs_hz, args.tracemalloc), q))
            p.start()
            res = None
            while res is None:
                try:
                    res = q.get(timeout=5.0)
                except queue.Empty:
                    if not p.is_alive():  # the worker died (e.g. out of memory): report, go on
                        res = {"subsystem": sub, "method": method, "order": PAPER_ORDERS[sub],
                               "n_samples": len(u), "wall_s": math.nan, "peak_rss_gb": math.nan,
                               "rss_increase_gb": math.nan, "tracemalloc_peak_gb": math.nan,
                               "error": f"worker exited with code {p.exitcode}"}
            p.join()
            rows.append(res)
            fit = res.get("fit_estimation_pct", res["error"])
            print(f"{sub:12s}{method:10s}{len(ins):>3d}>{len(outs):<2d}{res['order']:>6d}{res['n_samples']:>8d}"
                  f"{args.ss_f:>4d}/{args.ss_p:<2d}{res['wall_s']:>8.1f}{res['peak_rss_gb']:>8.2f}"
                  f"{res['rss_increase_gb']:>8.2f}{res['tracemalloc_peak_gb']:>9.2f}  {fit}", flush=True)
    print(f"load average at end: {os.getloadavg()[0]:.2f}  (other processes on the machine inflate wall times)")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="NPZ in the measured-data format (default: the id_pulses result if "
                                                 "present)")
    ap.add_argument("--methods", nargs="+", default=["N4SID", "MOESP", "CVA", "PARSIM-K"])
    ap.add_argument("--ss-f", type=int, default=30)
    ap.add_argument("--ss-p", type=int, default=30)
    ap.add_argument("--duration-s", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--subsystems", nargs="+", default=list(SUBSYSTEMS), choices=list(SUBSYSTEMS))
    ap.add_argument("--blas-threads", type=int, default=None,
                    help="OPENBLAS/OMP/MKL_NUM_THREADS for the workers (default: inherit)")
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    ap.add_argument("--tracemalloc", action="store_true",
                    help="also report the tracemalloc peak (slows the Python loops: wall times inflate)")
    args = ap.parse_args(argv)
    rows = run(args)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    raise SystemExit(main())
