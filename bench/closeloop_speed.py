"""Close-the-loop speed: wall time of one analysis of 2 s of rig data (target <= 2 min).

    python bench/closeloop_speed.py [--data resources/rig_demo.npz] [--repeat 1]

The data default to the shipped rig data set (2 s, multisine on both axes, two undeclared
effects, so the greedy search runs two rounds and a joint polish). The timed call is
``run_closeloop`` (load, replay, residual analysis, signatures, fits, report and figures) into a
temporary directory; the simulator's compilation is excluded (a short warm-up simulation runs
first). The number of simulations, their share of the wall time, the CPU time and the load
average are printed with it (the machine is shared).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from ssamb.closeloop import run_closeloop  # noqa: E402
from ssamb.config import load_config  # noqa: E402
from ssamb.sim import simulate  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", default=str(REPO / "resources" / "rig_demo.npz"), help="measured data (2 s)")
    ap.add_argument("--repeat", type=int, default=1, help="timed runs (the best is reported)")
    args = ap.parse_args()
    cfg = load_config()
    simulate(cfg, "multisine", duration_s=0.01, progress=False)      # compile (excluded)
    best = None
    load_before = os.getloadavg()
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            t0, c0 = time.perf_counter(), time.process_time()
            rep = run_closeloop(args.data, Path(tmp) / "out", config=cfg, progress=False)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if best is None or wall < best[0]:
            best = (wall, cpu, rep)
    wall, cpu, rep = best
    load_after = os.getloadavg()
    tm = rep["timing"]
    print(f"data: {args.data} ({rep['data']['duration_s']:.2f} s at {rep['data']['fs_hz']:.0f} Hz)")
    print(f"found: {', '.join(e['name'] for e in rep['effects']) or 'nothing'}; unexplained: {rep['unexplained']}")
    print(f"load average (1 min) before/after: {load_before[0]:.2f} / {load_after[0]:.2f} on {os.cpu_count()} CPUs")
    print(f"simulations: {tm['simulations']}; {wall / max(tm['simulations'], 1):.3f} s of wall time per simulation "
          f"(the whole analysis divided by them)")
    print(f"with loading and figures: {wall:.1f} s wall, {cpu:.1f} s CPU")
    print(f"wall time of one closeloop analysis: {wall:.1f} s (target <= 120 s): {'OK' if wall <= 120 else 'SLOW'}")


if __name__ == "__main__":
    main()
