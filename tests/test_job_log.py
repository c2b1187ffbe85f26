"""A failed workflow job says why in its log: :func:`ssamb.stages.job_log`, which
every workflow script runs its job in."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _job(tmp_path: Path, *body: str) -> tuple[subprocess.CompletedProcess, str]:
    """Run the statements ``body`` inside ``job_log`` in a fresh interpreter (as Snakemake runs
    a script); returns the process and the log's text."""
    log = tmp_path / "job.log"
    lines = ["import sys", "from ssamb.io import DataError", "from ssamb.stages import job_log",
             f"with job_log({str(log)!r}, 'simulate'):", "    print('progress line')"]
    lines += ["    " + b for b in body]
    r = subprocess.run([sys.executable, "-c", "\n".join(lines)], capture_output=True, text=True, cwd=tmp_path)
    return r, log.read_text()


def test_bad_input_lands_in_the_log_as_one_line_and_exits_2(tmp_path):
    r, log = _job(tmp_path, "raise DataError(\"d.npz: column 'x_meas' has 1 non-finite value(s) (NaN/inf)\")")
    assert r.returncode == 2, r.stderr
    line = "ssamb simulate: error: d.npz: column 'x_meas' has 1 non-finite value(s)"
    assert log.startswith("progress line\n") and line in log and "Traceback" not in log
    assert line in r.stderr and "Traceback" not in r.stderr and "lost sys.stderr" not in r.stderr


def test_a_bug_leaves_its_traceback_in_the_log_and_on_the_console(tmp_path):
    r, log = _job(tmp_path, "raise RuntimeError('boom')")
    assert r.returncode == 1
    assert "Traceback" in log and "RuntimeError: boom" in log
    assert "RuntimeError: boom" in r.stderr and "lost sys.stderr" not in r.stderr


def test_a_finished_job_keeps_its_output_and_restores_the_streams(tmp_path):
    r, log = _job(tmp_path, "sys.stderr.write('to the log\\n')")
    assert r.returncode == 0 and log == "progress line\nto the log\n" and r.stderr == ""


@pytest.mark.parametrize("script", sorted((ROOT / "workflow" / "scripts").glob("*.py")), ids=lambda p: p.name)
def test_every_workflow_script_runs_its_job_in_job_log(script):
    text = script.read_text()
    assert f'with job_log(snakemake.log[0], "{script.stem}"):' in text
    assert "sys.stderr =" not in text and "open(snakemake.log" not in text
