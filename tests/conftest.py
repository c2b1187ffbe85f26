"""Shared fixtures: the smoke workflow, run once per test session in a copy of the repository
(tests/test_workflow_smoke.py and tests/test_workflow_repro.py both read it)."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import settings as _hyp_settings

import ssamb

# the test session is an entry point like the command line and the workflow: the same BLAS
# threads, so the same bits
ssamb.pin_blas_threads()

# property tests draw the same examples on every run (CI must not pass or fail by luck); a
# developer hunting for new counterexamples runs with HYPOTHESIS_PROFILE=explore
_hyp_settings.register_profile("ci", derandomize=True)
_hyp_settings.register_profile("explore", derandomize=False)
_hyp_settings.load_profile(__import__("os").environ.get("HYPOTHESIS_PROFILE", "ci"))

ROOT = Path(__file__).resolve().parent.parent
SNAKEMAKE = [sys.executable, "-m", "snakemake"]
#: the reduced configuration merged over config.yaml
SMOKE_ARGS = ("--configfile", "config.yaml", "smoke.yaml")


def copy_repo(dst: Path) -> None:
    """What the workflow needs (Snakefile, config, workflow/, resources/) and smoke.yaml, into ``dst``."""
    for name in ("Snakefile", "config.yaml"):
        shutil.copy(ROOT / name, dst / name)
    for d in ("workflow", "resources"):
        shutil.copytree(ROOT / d, dst / d, ignore=shutil.ignore_patterns("__pycache__", ".snakemake"))
    shutil.copy(ROOT / "tests" / "data" / "smoke_config.yaml", dst / "smoke.yaml")


def run_snakemake(cwd: Path, *args, check: bool = True) -> subprocess.CompletedProcess:
    r = subprocess.run(SNAKEMAKE + list(args), cwd=cwd, capture_output=True, text=True)
    if check and r.returncode != 0:
        raise AssertionError(f"snakemake {' '.join(args)} failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return r


def smoke_run(wd: Path) -> Path:
    """A clean run of the smoke workflow in ``wd``; returns ``wd``."""
    copy_repo(wd)
    run_snakemake(wd, "--cores", "2", *SMOKE_ARGS)
    return wd


@pytest.fixture(scope="session")
def smoke_workdir(tmp_path_factory) -> Path:
    """A finished smoke workflow (shared: tests may dry-run in it, must not change its files)."""
    return smoke_run(tmp_path_factory.mktemp("smoke"))
