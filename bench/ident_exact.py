"""The identification stages with and without the memo of shared work: CPU seconds and byte
equality of every output (ssamb.identification.memo).

    python bench/ident_exact.py --results results [--scenario paper] [--subsystems plant amplifier selfsensing]

Runs ``ssamb.stages.identify.run_identify`` on ``<results>/sim/<estimation>.npz`` and
``<validation>.npz`` for each subsystem, once inside ``no_memo()`` (every computation afresh,
SIPPY unpatched: the code path before the memo) and once as the workflow runs it, each in a
fresh process (so that neither inherits the other's compiled kernels or caches), and compares
the written files (models, candidates, the paper variant) array by array, bit for bit, and the
evidence JSON. Prints CPU seconds (``time.process_time`` of the child: the figure that does not
depend on other processes sharing the machine), wall seconds and the load average.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CHILD = """
import json, sys, time
from ssamb.config import load_config, apply_overrides
from ssamb.identification.memo import no_memo
from ssamb.stages.identify import run_identify
cfg = load_config(sys.argv[1])
scen = sys.argv[2]
if scen:
    cfg = apply_overrides(cfg, cfg["scenarios"][scen])
res, sub, out, fresh = sys.argv[3], sys.argv[4], sys.argv[5], sys.argv[6] == "1"
ident = cfg["identification"]
args = (f"{res}/sim/{ident['estimation']}.npz", f"{res}/sim/{ident['validation']}.npz", sub, ident,
        f"{out}/{sub}.npz", f"{out}/{sub}_evidence.json", f"{out}/{sub}_paper.npz", None, f"{out}/{sub}_candidates.npz")
t0, c0 = time.perf_counter(), time.process_time()
if fresh:
    with no_memo():
        run_identify(*args)
else:
    run_identify(*args)
print(json.dumps({"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}))
"""


def _same_npz(a: Path, b: Path) -> bool:
    A, B = np.load(a, allow_pickle=False), np.load(b, allow_pickle=False)
    if sorted(A.files) != sorted(B.files):
        return False
    return all(A[k].shape == B[k].shape and A[k].dtype == B[k].dtype and A[k].tobytes() == B[k].tobytes()
               for k in A.files)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--results", default="results", help="a results folder with the simulations")
    ap.add_argument("--config", default=str(ROOT / "config.yaml"))
    ap.add_argument("--scenario", default="", help="a scenario of the config (default: the default run)")
    ap.add_argument("--subsystems", nargs="+", default=["plant", "amplifier", "selfsensing"])
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    print(f"load average at start {os.getloadavg()[0]:.2f}; scenario {args.scenario or 'default'}")
    print(f"{'subsystem':12s} {'CPU fresh (s)':>14s} {'CPU memo (s)':>13s} {'speed-up':>9s} {'wall fresh':>11s} "
          f"{'wall memo':>10s}  outputs")
    with tempfile.TemporaryDirectory() as tmp:
        for sub in args.subsystems:
            rec = {}
            for mode in ("fresh", "memo"):
                out = Path(tmp) / mode
                out.mkdir(exist_ok=True)
                r = subprocess.run([sys.executable, "-c", CHILD, args.config, args.scenario, args.results, sub,
                                    str(out), "1" if mode == "fresh" else "0"], capture_output=True, text=True, env=env)
                if r.returncode:
                    raise SystemExit(r.stderr[-3000:])
                rec[mode] = json.loads(r.stdout.strip().splitlines()[-1])
            f, m = Path(tmp) / "fresh", Path(tmp) / "memo"
            same = [_same_npz(f / n, m / n) for n in (f"{sub}.npz", f"{sub}_paper.npz", f"{sub}_candidates.npz")
                    if (f / n).exists()]
            same.append(json.loads((f / f"{sub}_evidence.json").read_text())
                        == json.loads((m / f"{sub}_evidence.json").read_text()))
            verdict = "bit-identical" if all(same) else f"DIFFER {same}"
            print(f"{sub:12s} {rec['fresh']['cpu']:14.1f} {rec['memo']['cpu']:13.1f} "
                  f"{rec['fresh']['cpu'] / rec['memo']['cpu']:8.2f}x {rec['fresh']['wall']:11.1f} "
                  f"{rec['memo']['wall']:10.1f}  {verdict}", flush=True)
    print(f"load average at the end {os.getloadavg()[0]:.2f} ({time.strftime('%H:%M')})")


if __name__ == "__main__":
    main()
