"""Re-run the whole bad-input table (tests/badinputs.py) and print what happened.

    python bench/bad_inputs.py                  # every row (the workflow rows run snakemake)
    python bench/bad_inputs.py --no-workflow    # without the workflow rows (about 20 s of CPU)
    python bench/bad_inputs.py --subprocess     # each command as `python -m ssamb` (slower)

Prints one line per row that does not stop as it should, then the counts: rows, ok, tracebacks,
silent acceptances (exit 0, or no note on suspicious data), and the other failures (wrong exit
status, more than one line, a message that misses the file or key, a file written). Exit status
1 when any row is not ok.
"""
from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from badinputs import all_cases, run_case, workflow_copy  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-workflow", action="store_true", help="skip the rows that run snakemake")
    ap.add_argument("--subprocess", action="store_true", help="run each command as `python -m ssamb`")
    args = ap.parse_args()
    cases = [c for c in all_cases() if not (args.no_workflow and c.kind == "workflow")]
    counts: collections.Counter = collections.Counter()
    areas: collections.Counter = collections.Counter()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="ssamb-bad-inputs-") as tmp:
        root = Path(tmp)
        wd = workflow_copy(root / "workflow") if any(c.kind == "workflow" for c in cases) else None
        for i, case in enumerate(cases):
            folder = root / f"case{i:03d}"
            folder.mkdir()
            out = run_case(case, folder, workflow_dir=wd, subprocess_cli=args.subprocess)
            counts[out.verdict] += 1
            areas[case.area] += 1
            if out.verdict != "ok":
                detail = " ".join(out.detail.split())[:300]
                print(f"[{out.verdict}] {case.area}: {case.id}: {detail}", flush=True)
    wall = time.perf_counter() - t0
    print(f"rows: {len(cases)} ({', '.join(f'{a} {n}' for a, n in sorted(areas.items()))}); {wall:.0f} s")
    print(f"ok: {counts['ok']}; tracebacks: {counts['traceback']}; silent acceptances: {counts['accepted']}; "
          f"wrong status: {counts['wrong status']}; not one line: {counts['not one line']}; "
          f"message without file or key: {counts['unnamed']}; files written: {counts['wrote files']}; "
          f"skipped: {counts['skipped']}")
    return 0 if counts["ok"] + counts["skipped"] == len(cases) else 1


if __name__ == "__main__":
    sys.exit(main())
