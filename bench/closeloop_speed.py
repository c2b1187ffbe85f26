"""Close-the-loop speed: wall time of one analysis of 2 s of rig data (target <= 2 min).

    python bench/closeloop_speed.py [--data resources/rig_demo.npz] [--repeat 1] [--workers 2]

The data default to the shipped rig data set (2 s, multisine on both axes, a rig whose own
parameters are a few per cent off the model's and two undeclared effects: the calibration of
eleven nominal parameters, two rounds of effects and the joint refit all run). The timed call is
``run_closeloop`` (load, replays, features, calibration, signatures, fits, joint refit, report
and figures) into a temporary directory; the simulator's compilation is excluded (a short
warm-up simulation runs first). The number of simulations, the wall time they take and per
simulation, the CPU time and the load average are printed with it (the machine is shared), and
the host's own speed: the wall time of one fixed simulation (1 s of the default multisine, best
of 3), so that figures taken on different machines, or on one virtual machine whose host
changed, can be told apart from a change of the code.
``--workers`` runs the independent replays on that many processes (default 2, as the workflow's
rule); run with ``--workers 1`` for the one-process figure.
"""
from __future__ import annotations

import argparse
import math
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
    ap.add_argument("--workers", type=int, default=2, help="processes for the independent replays (as the workflow's "
                                                           "2 threads)")
    args = ap.parse_args()
    cfg = load_config()
    simulate(cfg, "multisine", duration_s=0.01, progress=False)      # compile (excluded)
    host_s = host_reference_s(cfg)
    sims = _count_simulations()
    best = None
    load_before = os.getloadavg()
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            t0, c0 = time.perf_counter(), time.process_time()
            n0 = len(sims["replayers"])
            rep = run_closeloop(args.data, Path(tmp) / "out", config=cfg, progress=False, workers=args.workers)
            sim_wall = sum(r.wall_s for r in sims["replayers"][n0:])
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if best is None or wall < best[0]:
            best = (wall, cpu, rep, sim_wall)
    wall, cpu, rep, sim_wall = best
    load_after = os.getloadavg()
    tm = rep["timing"]
    print(f"data: {args.data} ({rep['data']['duration_s']:.2f} s at {rep['data']['fs_hz']:.0f} Hz)")
    print(f"found: {', '.join(e['name'] for e in rep['effects']) or 'nothing'}; unexplained: {rep['unexplained']}")
    print(f"load average (1 min) before/after: {load_before[0]:.2f} / {load_after[0]:.2f} on {os.cpu_count()} CPUs")
    n = max(tm["simulations"], 1)
    print(f"host reference: 1 s of the default multisine simulated in {host_s:.3f} s wall (best of 3)")
    print(f"workers: {args.workers}")
    print(f"simulations: {tm['simulations']} ({sim_wall:.1f} s of simulation time summed over the workers, "
          f"{sim_wall / n:.3f} s each; {wall / n:.3f} s of the whole analysis's wall time per simulation)")
    print(f"with loading and figures: {wall:.1f} s wall, {cpu:.1f} s CPU of the main process")
    print(f"wall time of one closeloop analysis: {wall:.1f} s (target <= 120 s): {'OK' if wall <= 120 else 'SLOW'}")


def host_reference_s(cfg: dict, repeat: int = 3) -> float:
    """Wall time (s) of one fixed simulation, 1 s of the default multisine, the best of ``repeat``:
    the host's speed for the simulator, printed beside the analysis's time."""
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        simulate(cfg, "multisine", duration_s=1.0, progress=False)
        best = min(best, time.perf_counter() - t0)
    return best


def _count_simulations() -> dict:
    """Remember the replayers the analysis makes: their counters hold every simulation, those
    their worker processes ran included."""
    import ssamb.closeloop.replay as rp

    acc = {"replayers": []}
    run = rp.Replayer.run

    def seen(self, *a, **kw):
        if not any(r is self for r in acc["replayers"]):
            acc["replayers"].append(self)
        return run(self, *a, **kw)
    rp.Replayer.run = seen
    return acc


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    main()
