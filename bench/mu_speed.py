"""Speed and agreement of ``ssamb.mu.mussv`` against SLICOT AB13MD (slycot ``ab13md``).

Run: ``python bench/mu_speed.py [--n 200]``.  Not a test: it prints timings.

Cases (random complex matrices, fixed seeds):
  (a) 3 full 2x2 complex blocks, 6x6 M   (blk [[2,2]]*3,  ab13md nblock [2,2,2])
  (b) 4 complex scalars, 4x4 M           (blk [[1,1]]*4,  ab13md nblock [1,1,1,1])
``mussv`` computes both bounds (and their certificates); ``ab13md`` the upper bound only.
Then (c) a mixed case (2 real scalars, a full 2x2 and a complex scalar) on badly scaled
matrices S A S^-1 (S spanning e^+-4), where the upper bound needs the method-of-centers
refinement.  Then a 500-point μ sweep of the three-block case over the frequency response of a random
stable 6x6 state-space model.
"""
from __future__ import annotations

import os

# Small matrices: BLAS threads only add synchronisation (and, on a loaded 2-core machine,
# spin-waiting) for both libraries.  Set before numpy / slycot load OpenBLAS; override by
# exporting OPENBLAS_NUM_THREADS yourself.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from ssamb.mu import mussv  # noqa: E402
from ssamb.robustness import frequency_response_matrix, mu_frequency_response  # noqa: E402


def _crandn(rng, n):
    return rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))


def _interleaved_times(fns, items, repeat=7):
    """Per-call time of each function, timed in alternation on the same items (so that
    load fluctuations of a shared machine hit all of them alike); the median over repeats."""
    times = [[] for _ in fns]
    outs = [None] * len(fns)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            outs[k] = [fn(x) for x in items]
            times[k].append((time.perf_counter() - t0) / len(items))
    return [float(np.median(t)) for t in times], outs


def bench_case(name, blk, nblock, itype, n, count, seed):
    from slycot import ab13md

    rng = np.random.default_rng(seed)
    mats = [_crandn(rng, n) for _ in range(count)]
    mussv(mats[0], blk)  # JIT compile / load the cache outside the timing
    ab13md(mats[0], np.array(nblock), np.array(itype))
    (t_mu, t_ab), (res, ref) = _interleaved_times(
        [lambda M: mussv(M, blk), lambda M: ab13md(M, np.array(nblock), np.array(itype))[0]],
        mats)
    up = np.array([r.upper for r in res])
    lo = np.array([r.lower for r in res])
    ref = np.array(ref)
    dis = np.max(np.abs(up - ref) / ref) * 100
    print(f"case ({name}): blk={blk}, {count} random {n}x{n} matrices, seed {seed}")
    print(f"  mussv per point: {t_mu * 1e3:.3f} ms   (upper + lower bound + certificates)")
    print(f"  ab13md per point: {t_ab * 1e3:.3f} ms   (upper bound only)")
    print(f"  speed ratio (ab13md/mussv): {t_ab / t_mu:.2f}")
    print(f"  max upper-bound disagreement: {dis:.2e} %")
    print(f"  mussv upper below ab13md by at most: {np.max((ref - up) / ref) * 100:.2e} %")
    print(f"  max relative gap (upper-lower)/upper: {np.max((up - lo) / up):.2e}")
    return t_mu, t_ab, dis


def bench_mixed(count=60, seed=3):
    from slycot import ab13md

    blk, nblock, itype = [[-1, 0], [-1, 0], [2, 2], [1, 1]], [1, 1, 2, 1], [1, 1, 2, 2]
    rng = np.random.default_rng(seed)
    mats = []
    for _ in range(count):
        s = np.exp(rng.uniform(-4, 4, 5))
        mats.append(s[:, None] * _crandn(rng, 5) / s[None, :])
    mussv(mats[0], blk)
    (t_mu, t_ab), (res, ref) = _interleaved_times(
        [lambda M: mussv(M, blk), lambda M: ab13md(M, np.array(nblock), np.array(itype))[0]],
        mats, repeat=3)
    up = np.array([r.upper for r in res])
    ref = np.array(ref)
    print(f"case (c): blk={blk}, {count} badly scaled random 5x5 matrices, seed {seed}")
    print(f"  mussv per point: {t_mu * 1e3:.3f} ms   ab13md per point: {t_ab * 1e3:.3f} ms")
    print(f"  mussv upper above ab13md by at most: {np.max((up - ref) / ref) * 100:.2e} %")
    print(f"  mussv upper below ab13md by at most: {np.max((ref - up) / ref) * 100:.2e} %"
          "   (both certified; ab13md stops early there)")


def bench_sweep(npts=500, seed=7):
    import control

    rng = np.random.default_rng(seed)
    # a random stable 6x6 model with fixed seed (control.rss uses the global numpy RNG)
    A = rng.standard_normal((8, 8))
    A = A - (np.max(np.linalg.eigvals(A).real) + 0.5) * np.eye(8)
    sys = control.ss(A, rng.standard_normal((8, 6)), rng.standard_normal((6, 8)),
                     rng.standard_normal((6, 6)))
    freqs = np.geomspace(1e-2, 1e2, npts)
    resp = frequency_response_matrix(sys, freqs)
    blk = [[2, 2]] * 3
    mussv(resp[0], blk)
    t0 = time.perf_counter()
    sw = mu_frequency_response(resp, freqs, blk, refine=False)
    t = time.perf_counter() - t0
    print(f"{npts}-point sweep: {t:.2f} s   (3 full 2x2 blocks, peak mu {sw.peak:.4f} "
          f"at {sw.peak_hz:.3f} Hz, max gap {np.max((sw.upper - sw.lower) / sw.upper):.1e})")
    return t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="random matrices per case")
    args = ap.parse_args()
    print(f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}, median of 7 interleaved repeats")
    ta = bench_case("a", [[2, 2]] * 3, [2, 2, 2], [2, 2, 2], 6, args.n, seed=1)
    tb = bench_case("b", [[1, 1]] * 4, [1, 1, 1, 1], [2, 2, 2, 2], 4, args.n, seed=2)
    bench_mixed()
    ts = bench_sweep()
    ok = (ta[0] < ta[1] and tb[0] < tb[1] and max(ta[2], tb[2]) < 0.1 and ts < 10.0)
    print("targets (faster than ab13md, agreement < 0.1 %, sweep < 10 s):",
          "met" if ok else "NOT met")


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    main()
