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


@pytest.mark.parametrize("name", ["ssamb.mu.mussv", "ssamb.identification.identify", "ssamb.config.load_config",
                                  "ssamb.report.failures.root_cause", "ssamb.pin_blas_threads",
                                  "ssamb.closeloop.estimate.model_averaged_sd", "ssamb.closeloop.fit.counted_group",
                                  "ssamb.closeloop.excess.excess_z"])
def test_the_examples_of_the_entry_points_run(name, monkeypatch):
    """The Examples sections are doctests that hold (those that write no file)."""
    import doctest
    import importlib

    monkeypatch.chdir(ROOT)
    module, attr = name.rsplit(".", 1)
    obj = getattr(importlib.import_module(module), attr)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    tests = doctest.DocTestFinder().find(obj, name, globs={})
    assert tests and tests[0].examples, f"{name} has no example"
    for t in tests:
        runner.run(t)
    assert runner.failures == 0, name
