"""Workflow wall times from a clean results/ in a scratch copy of the repository: the full
reproduction (`snakemake --cores 2`) and, with --study, the assumption study that follows it
(`snakemake --cores 2 study`); the per-rule benchmark table of every run and the load average.

    python bench/workflow_speed.py [--study] [--keep DIR]
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
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _run(wd: Path, *targets: str) -> float:
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", *targets], cwd=wd, capture_output=True,
                       text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        print(r.stdout[-3000:], r.stderr[-3000:])
        raise SystemExit(f"snakemake {' '.join(targets)} failed")
    print(f"snakemake --cores 2 {' '.join(targets)}: {wall / 60:.2f} min (load average at start {load0:.2f})")
    return wall


def _benchmarks(results: Path) -> list[tuple[str, float, float]]:
    rows = []
    for f in sorted(results.rglob("benchmarks/**/*.tsv")):
        with open(f) as fh:
            rec = list(csv.DictReader(fh, delimiter="\t"))[0]
        rows.append((str(f.relative_to(results))[:-4].replace("benchmarks/", ""), float(rec["s"]),
                     float(rec["max_rss"])))
    return sorted(rows, key=lambda r: -r[1])


def _table(rows) -> None:
    print(f"{'run / rule / wildcard':60s} {'wall (s)':>9s} {'max RSS (MB)':>13s}")
    for name, s, rss in rows[:40]:
        print(f"{name:60s} {s:9.1f} {rss:13.0f}")
    if len(rows) > 40:
        print(f"... {len(rows) - 40} more")
    per_rule = defaultdict(float)
    for name, s, _ in rows:
        stage = name.split("/", 2)[2] if name.startswith("runs/") else name
        per_rule[stage.split("/")[0]] += s
    print("per rule (s): " + ", ".join(f"{k} {v:.0f}" for k, v in sorted(per_rule.items(), key=lambda kv: -kv[1])))
    print(f"sum of rule wall times: {sum(r[1] for r in rows):.1f} s over {len(rows)} jobs")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--study", action="store_true", help="also run the assumption study")
    ap.add_argument("--keep", default=None, help="run in this directory and keep it")
    args = ap.parse_args()
    wd = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="ssamb-bench-"))
    wd.mkdir(parents=True, exist_ok=True)
    for name in ("Snakefile", "config.yaml"):
        shutil.copy(ROOT / name, wd / name)
    for d in ("workflow", "resources"):
        shutil.copytree(ROOT / d, wd / d, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__"))
    _run(wd)
    _table(_benchmarks(wd / "results"))
    if args.study:
        _run(wd, "study")
        _table([r for r in _benchmarks(wd / "results") if r[0].startswith(("runs/study-", "study/"))])
    if not args.keep:
        shutil.rmtree(wd, ignore_errors=True)


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    main()
