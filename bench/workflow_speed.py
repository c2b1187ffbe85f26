"""Full reproduction wall time: `snakemake --cores 2` from a clean results/ (default config),
in a scratch copy of the repository, and the per-rule benchmark table.

    python bench/workflow_speed.py [--keep DIR]
"""
from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--keep", default=None, help="run in this directory and keep it")
    args = ap.parse_args()
    wd = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="ssamb-bench-"))
    wd.mkdir(parents=True, exist_ok=True)
    for name in ("Snakefile", "config.yaml"):
        shutil.copy(ROOT / name, wd / name)
    for d in ("workflow", "resources"):
        shutil.copytree(ROOT / d, wd / d, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__"))
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2"], cwd=wd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        print(r.stdout[-3000:], r.stderr[-3000:])
        raise SystemExit("snakemake failed")
    rows = []
    for f in sorted((wd / "results" / "benchmarks").rglob("*.tsv")):
        rec = list(csv.DictReader(open(f), delimiter="\t"))[0]
        rows.append((str(f.relative_to(wd / "results" / "benchmarks"))[:-4], float(rec["s"]), float(rec["max_rss"])))
    rows.sort(key=lambda r: -r[1])
    print(f"{'rule / wildcard':36s} {'wall (s)':>9s} {'max RSS (MB)':>13s}")
    for name, s, rss in rows:
        print(f"{name:36s} {s:9.1f} {rss:13.0f}")
    print(f"sum of rule wall times: {sum(r[1] for r in rows):.1f} s")
    print(f"load average at start: {load0:.2f}")
    print(f"full reproduction (snakemake --cores 2, clean results/): {wall / 60:.2f} min")
    if not args.keep:
        shutil.rmtree(wd, ignore_errors=True)


if __name__ == "__main__":
    main()
