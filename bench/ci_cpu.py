"""CPU time of the test command, per test and in all (the CI time target).

    python bench/ci_cpu.py [--top 15] [--rows FILE] [PYTEST ARGS ...]     # default: the README's `pytest -q`

Runs pytest (with its addopts: two pytest-xdist workers) with this module as a plugin: around
each test's setup, call and teardown it reads the CPU time of the worker process and of its
children that have ended (subprocesses: snakemake, the wheel's fresh environment, replay
workers). Prints the run's wall time and load average at the start, the CPU time of the
whole process tree, the tests' share of it (the rest: collection, the workers' start, the
background smoke workflow), the costliest tests and the costliest files.

The machine is shared: compare CPU time, not wall. With two cores and the tests packed on both,
the run's wall time is about its CPU time over two; the target of 6 minutes for the README's
test command with its install therefore needs the run under about 600 CPU s.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
_ROWS: list = []


def _cpu_s() -> float:
    """CPU time (user and system) of this process and of its children that have ended."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


try:                                     # the plugin half: loaded by pytest (-p ci_cpu)
    import pytest

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        c0, t0 = _cpu_s(), time.monotonic()
        yield
        _ROWS.append((item.nodeid, _cpu_s() - c0, time.monotonic() - t0, time.time(),
                      os.environ.get("PYTEST_XDIST_WORKER", "main")))

    def pytest_sessionfinish(session):
        out = os.environ.get("SSAMB_CI_CPU_DIR")
        if out:
            Path(out, f"tests.{os.getpid()}.json").write_text(json.dumps(_ROWS))
except ImportError:                      # pragma: no cover
    pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--top", type=int, default=15, help="costliest tests to list")
    ap.add_argument("--rows", help="write every test's (node id, CPU s, wall s, end in s from the start, worker) "
                    "to this JSON file")
    args, pytest_args = ap.parse_known_args()
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="ssamb-ci-cpu-") as out:
        path = (str(ROOT / "bench"), str(ROOT), os.environ.get("PYTHONPATH"))
        env = {**os.environ, "SSAMB_CI_CPU_DIR": out, "PYTHONPATH": os.pathsep.join(p for p in path if p)}
        before, t0, start = resource.getrusage(resource.RUSAGE_CHILDREN), time.monotonic(), time.time()
        rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "ci_cpu", *pytest_args], cwd=ROOT, env=env)
        wall = time.monotonic() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        rows = [r for f in Path(out).glob("tests.*.json") for r in json.loads(f.read_text())]
    if args.rows:
        Path(args.rows).write_text(json.dumps([[r[0], r[1], r[2], r[3] - start, r[4]] for r in rows]))
    total = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    tests = sum(r[1] for r in rows)
    print(f"\npytest exit {rc}; load average at the start {load:.2f}")
    print(f"wall {wall:.0f} s; CPU {total:.0f} s in all ({total / max(wall, 1e-9):.2f} cores busy on average), "
          f"{tests:.0f} s in {len(rows)} tests, {total - tests:.0f} s elsewhere (collection, workers' start, "
          "the background smoke workflow)")
    ends = defaultdict(float)
    for r in rows:
        ends[r[4]] = max(ends[r[4]], r[3] - start)
    print("each worker's last test ended at " + ", ".join(f"{w} {t:.0f} s" for w, t in sorted(ends.items()))
          + " (both busy to the end when these are close)")
    print(f"\n{'CPU s':>7} {'wall s':>7}  costliest tests")
    for nodeid, cpu, w, *_ in sorted(rows, key=lambda r: -r[1])[:args.top]:
        print(f"{cpu:7.1f} {w:7.1f}  {nodeid}")
    per_file = defaultdict(float)
    for nodeid, cpu, *_ in rows:
        per_file[nodeid.split("::")[0]] += cpu
    print(f"\n{'CPU s':>7}  costliest files")
    for name, cpu in sorted(per_file.items(), key=lambda kv: -kv[1])[:10]:
        print(f"{cpu:7.1f}  {name}")
    sys.exit(rc)


if __name__ == "__main__":
    main()
