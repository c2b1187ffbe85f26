"""Workflow wall times from a clean results/ in a scratch copy of the repository: the full
reproduction (`snakemake --cores 2`) and, with --ensemble, the noise ensembles that follow it
(`snakemake --cores 2 ensemble`), with --study the assumption study; the per-rule benchmark table
of each target (wall and CPU seconds per job, summed per rule) and the load average at its start
and end (the machine may be shared: the CPU seconds are the load-independent figure).

    python bench/workflow_speed.py [--ensemble] [--study] [--keep DIR] [--configfile FILE ...]
"""
from __future__ import annotations

import argparse
import csv
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _children_cpu_s() -> float:
    """CPU seconds (user + system) of every finished child process and its descendants."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def _run(wd: Path, *targets: str, configfiles: tuple = ()) -> float:
    load0 = os.getloadavg()[0]
    cpu0 = _children_cpu_s()
    t0 = time.perf_counter()
    extra = ["--configfile", *configfiles] if configfiles else []
    r = subprocess.run([sys.executable, "-m", "snakemake", *targets, "--cores", "2", *extra], cwd=wd,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        print(r.stdout[-3000:], r.stderr[-3000:])
        raise SystemExit(f"snakemake {' '.join(targets)} failed")
    print(f"snakemake --cores 2 {' '.join(targets)}: {wall / 60:.2f} min (load average at start {load0:.2f}, "
          f"at the end {os.getloadavg()[0]:.2f}); {_children_cpu_s() - cpu0:.0f} CPU s in all its processes")
    return wall


def _benchmarks(results: Path, since: float = 0.0) -> list[tuple[str, float, float, float]]:
    """``(run/rule/wildcard, wall s, CPU s, max RSS MB)`` of every benchmark written after ``since``."""
    rows = []
    for f in sorted(results.rglob("benchmarks/**/*.tsv")):
        if f.stat().st_mtime < since:
            continue
        with open(f) as fh:
            rec = list(csv.DictReader(fh, delimiter="\t"))[0]
        cpu = float(rec["cpu_time"]) if rec.get("cpu_time") not in (None, "", "NA", "-") else float("nan")
        rows.append((str(f.relative_to(results))[:-4].replace("benchmarks/", ""), float(rec["s"]), cpu,
                     float(rec["max_rss"])))
    return sorted(rows, key=lambda r: -r[1])


def _table(rows, top: int = 25) -> None:
    print(f"{'run / rule / wildcard':60s} {'wall (s)':>9s} {'CPU (s)':>8s} {'max RSS (MB)':>13s}")
    for name, s, cpu, rss in rows[:top]:
        print(f"{name:60s} {s:9.1f} {cpu:8.1f} {rss:13.0f}")
    if len(rows) > top:
        print(f"... {len(rows) - top} more")
    per_rule = defaultdict(lambda: [0, 0.0, 0.0])
    for name, s, cpu, _ in rows:
        stage = name.split("/", 2)[2] if name.startswith("runs/") else name
        r = per_rule[stage.split("/")[0]]
        r[0] += 1
        r[1] += s
        r[2] += cpu
    print(f"{'per rule':20s} {'jobs':>5s} {'wall (s)':>9s} {'CPU (s)':>8s}")
    for k, (n, s, cpu) in sorted(per_rule.items(), key=lambda kv: -kv[1][1]):
        print(f"{k:20s} {n:5d} {s:9.0f} {cpu:8.0f}")
    print(f"sum of rule wall times: {sum(r[1] for r in rows):.1f} s, CPU {sum(r[2] for r in rows):.1f} s "
          f"over {len(rows)} jobs")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--study", action="store_true", help="also run the assumption study")
    ap.add_argument("--ensemble", action="store_true", help="also run the noise ensembles")
    ap.add_argument("--keep", default=None, help="run in this directory and keep it (and reuse what it holds)")
    ap.add_argument("--configfile", nargs="+", default=(), help="config files (copied; e.g. config.yaml "
                                                                  "tests/data/smoke_config.yaml)")
    args = ap.parse_args()
    wd = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="ssamb-bench-"))
    wd.mkdir(parents=True, exist_ok=True)
    for name in ("Snakefile", "config.yaml"):
        shutil.copy(ROOT / name, wd / name)
    for d in ("workflow", "resources"):
        shutil.copytree(ROOT / d, wd / d, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__"))
    cfgs = []
    for c in args.configfile:
        shutil.copy(ROOT / c, wd / Path(c).name)
        cfgs.append(Path(c).name)
        for extra in (ROOT / c).parent.glob("maglev1d*.yaml"):   # a device config the file names beside it
            shutil.copy(extra, wd / extra.name)
    t = time.time()
    _run(wd, configfiles=tuple(cfgs))
    _table(_benchmarks(wd / "results", t))
    for flag, target in ((args.ensemble, "ensemble"), (args.study, "study")):
        if flag:
            t = time.time()
            _run(wd, target, configfiles=tuple(cfgs))
            _table(_benchmarks(wd / "results", t))
    if not args.keep:
        shutil.rmtree(wd, ignore_errors=True)


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    main()
