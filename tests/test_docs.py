"""The documentation builds with no warning (Sphinx, ``-W``): the pages, and the API reference
from the docstrings."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_docs_build_without_warnings(tmp_path):
    r = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                        "-d", str(tmp_path / "doctrees"), str(ROOT / "docs"), str(tmp_path / "html")],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, (r.stdout + r.stderr)[-6000:]
    html = (tmp_path / "html" / "api.html").read_text(encoding="utf-8")
    for name in ("load_config", "simulate", "mussv", "run_closeloop", "pin_blas_threads"):
        assert name in html, name
    for page in ("quickstart", "workflow", "closeloop", "formats", "cli", "modelling", "validation", "development"):
        assert (tmp_path / "html" / f"{page}.html").exists(), page
