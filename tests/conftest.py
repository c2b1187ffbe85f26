"""Shared fixtures: the smoke workflow, run once per test session in a copy of the repository
(tests/test_workflow_smoke.py and tests/test_workflow_repro.py both read it), and a second clean
run for the byte-reproducibility test. Both start in the background as soon as the tests are
collected and run beside the other tests."""
from __future__ import annotations

import atexit
import functools
import shutil
import subprocess
import sys
import tempfile
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


@functools.lru_cache(maxsize=1)
def smoke_rig() -> Path:
    """A 0.5 s record of the demo rig (its scenario with a shorter multisine: 10-100 Hz in 10 Hz
    steps, five periods), made once per session: the smoke workflow closes the loop on it
    (``resources/rig_smoke.npz`` in the copy; the shipped 2 s record costs four times as much)."""
    import yaml

    from ssamb.rig import run_scenario

    where = Path(tempfile.mkdtemp(prefix="ssamb-smoke-rig-"))
    atexit.register(shutil.rmtree, where, True)
    sc = yaml.safe_load((ROOT / "resources" / "scenarios" / "rig_demo.yaml").read_text())
    sc["config"] = str(ROOT / "config.yaml")
    sc["experiment"].update(f_min_hz=10.0, f_resolution_hz=10.0, periods=5)
    (where / "rig_smoke.yaml").write_text(yaml.safe_dump(sc))
    run_scenario(where / "rig_smoke.yaml", where / "rig_smoke.npz", progress=False)
    return where / "rig_smoke.npz"


def copy_repo(dst: Path) -> None:
    """What the workflow needs (Snakefile, config, workflow/, resources/) and smoke.yaml, into
    ``dst``; the smoke configuration's rig record into ``dst/resources``."""
    for name in ("Snakefile", "config.yaml"):
        shutil.copy(ROOT / name, dst / name)
    for d in ("workflow", "resources"):
        shutil.copytree(ROOT / d, dst / d, ignore=shutil.ignore_patterns("__pycache__", ".snakemake"))
    shutil.copy(ROOT / "tests" / "data" / "smoke_config.yaml", dst / "smoke.yaml")
    rig = smoke_rig()
    for f in (rig, rig.with_suffix(".json")):
        shutil.copy(f, dst / "resources" / f.name)


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


class _Background:
    """A clean smoke workflow run started as soon as the tests that read it are collected, so
    that it runs beside the other tests (the session's two cores are both busy); the fixture
    that needs it waits for it."""

    def __init__(self, wd: Path):
        copy_repo(wd)
        self.wd = wd
        self.log = open(wd / "snakemake.log", "w")
        self.proc = subprocess.Popen(SNAKEMAKE + ["--cores", "2", *SMOKE_ARGS], cwd=wd, stdout=self.log,
                                     stderr=subprocess.STDOUT)

    def result(self) -> Path:
        rc = self.proc.wait()
        self.log.close()
        if rc != 0:
            tail = (self.wd / "snakemake.log").read_text()[-6000:]
            raise AssertionError(f"the smoke workflow in {self.wd} failed (exit {rc}):\n{tail}")
        return self.wd

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self.log.close()


#: the smoke runs under way, by fixture name
_RUNS: dict[str, _Background] = {}
#: fixtures backed by a clean smoke run of their own
SMOKE_FIXTURES = ("smoke_workdir", "smoke_second_workdir")


def pytest_collection_finish(session):
    """Start the smoke runs the selected tests need (one per fixture, at most two per session)."""
    needed = {f for item in session.items for f in getattr(item, "fixturenames", ())}
    factory = session.config._tmp_path_factory
    for name in SMOKE_FIXTURES:
        if name in needed and name not in _RUNS:
            _RUNS[name] = _Background(factory.mktemp(name.replace("_workdir", "")))


def pytest_sessionfinish(session):
    for run in _RUNS.values():
        run.stop()


def _smoke(name: str, tmp_path_factory) -> Path:
    if name not in _RUNS:                   # collected another way: start it now
        _RUNS[name] = _Background(tmp_path_factory.mktemp(name.replace("_workdir", "")))
    return _RUNS[name].result()


@pytest.fixture(scope="session")
def smoke_workdir(tmp_path_factory) -> Path:
    """A finished smoke workflow (shared: tests may dry-run in it, must not change its files)."""
    return _smoke("smoke_workdir", tmp_path_factory)


@pytest.fixture(scope="session")
def smoke_second_workdir(tmp_path_factory) -> Path:
    """A second clean smoke workflow, for the byte-reproducibility test."""
    return _smoke("smoke_second_workdir", tmp_path_factory)
