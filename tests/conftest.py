"""Shared fixtures: the smoke workflow, run once per test session in a copy of the repository
(tests/test_workflow_*.py read it; it starts in the background as soon as the tests are collected
and runs beside the other tests), and the grouping of tests that share a costly fixture on one
pytest-xdist worker."""
from __future__ import annotations

import atexit
import fcntl
import functools
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
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
#: processes for the replays of a close-the-loop analysis inside a test (the result does not
#: depend on it: tests/test_closeloop.py::test_the_result_does_not_depend_on_the_workers). One
#: on a pytest-xdist worker: the session's workers already keep every CPU busy, and a second
#: process per analysis would only add the forking and the pipes' traffic to the session's CPU
#: time; up to two in a session of one process.
REPLAY_WORKERS = 1 if "PYTEST_XDIST_WORKER" in os.environ else min(2, len(os.sched_getaffinity(0)))


def bench_module(name: str):
    """The script ``bench/<name>.py`` imported as a module (its tests call its functions)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _shared_root() -> Path | None:
    """The folder every process of this test session shares (with pytest-xdist the workers'
    base folders are inside it); None outside a test session (``bench/bad_inputs.py``)."""
    if _CONFIG is None:
        return None
    base = _CONFIG._tmp_path_factory.getbasetemp()
    return base.parent if hasattr(_CONFIG, "workerinput") else base


def _once(name: str, make) -> Path:
    """``make(folder)`` in exactly one process of the test session; the others wait for it and
    get the same folder."""
    root = _shared_root()
    if root is None:
        where = Path(tempfile.mkdtemp(prefix=f"ssamb-{name}-"))
        atexit.register(shutil.rmtree, where, True)
        make(where)
        return where
    where = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (where / ".done").exists():
            shutil.rmtree(where, ignore_errors=True)
            where.mkdir()
            make(where)
            (where / ".done").touch()
    return where


def _make_smoke_rig(where: Path) -> None:
    import yaml

    from ssamb.rig import run_scenario

    sc = yaml.safe_load((ROOT / "resources" / "scenarios" / "rig_demo.yaml").read_text())
    sc["config"] = str(ROOT / "config.yaml")
    sc["experiment"].update(f_min_hz=10.0, f_resolution_hz=10.0, periods=5)
    (where / "rig_smoke.yaml").write_text(yaml.safe_dump(sc))
    run_scenario(where / "rig_smoke.yaml", where / "rig_smoke.npz", progress=False)


@functools.lru_cache(maxsize=1)
def smoke_rig() -> Path:
    """A 0.5 s record of the demo rig (its scenario with a shorter multisine: 10-100 Hz in 10 Hz
    steps, five periods), made once per test session: the smoke workflow closes the loop on it
    (``resources/rig_smoke.npz`` in the copy; the shipped 2 s record costs four times as much)."""
    return _once("smoke-rig", _make_smoke_rig) / "rig_smoke.npz"


def copy_repo(dst: Path) -> None:
    """What the workflow needs (Snakefile, config, workflow/, resources/) and smoke.yaml, into
    ``dst``; the smoke configuration's rig record into ``dst/resources``."""
    for name in ("Snakefile", "config.yaml"):
        shutil.copy(ROOT / name, dst / name)
    for d in ("workflow", "resources"):
        shutil.copytree(ROOT / d, dst / d, ignore=shutil.ignore_patterns("__pycache__", ".snakemake"))
    shutil.copy(ROOT / "tests" / "data" / "smoke_config.yaml", dst / "smoke.yaml")
    shutil.copy(ROOT / "tests" / "data" / "maglev1d_smoke.yaml", dst / "maglev1d_smoke.yaml")
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
    """A clean smoke workflow run in ``wd``, started as soon as the tests that read it are
    collected, so that it runs beside the other tests; the fixture that needs it waits for it.

    One process of the test session starts it (with pytest-xdist every worker collects every
    test; the first to create ``wd`` wins), any process waits for it: the run leaves its exit
    status in ``snakemake.rc``, its log in ``snakemake.log`` and its process group in
    ``snakemake.pid``."""

    def __init__(self, wd: Path):
        self.wd = wd

    def start(self) -> bool:
        """Start the run unless another process of the session has; True if this one did."""
        try:
            self.wd.mkdir()
        except FileExistsError:
            return False
        try:
            copy_repo(self.wd)
            self.proc = subprocess.Popen(
                ["/bin/sh", "-c", '"$@" > snakemake.log 2>&1; echo $? > snakemake.rc', "sh", *SNAKEMAKE,
                 "--cores", "2", *SMOKE_ARGS], cwd=self.wd, start_new_session=True)
        except BaseException as e:
            (self.wd / "snakemake.log").write_text(f"the smoke run could not start: {e!r}")
            (self.wd / "snakemake.rc").write_text("-1")
            raise
        (self.wd / "snakemake.pid").write_text(str(self.proc.pid))
        _STARTED.append(self.proc)
        return True

    def result(self, timeout_s: float = 3600.0) -> Path:
        rc, t0 = self.wd / "snakemake.rc", time.monotonic()
        while not rc.exists():
            if time.monotonic() - t0 > timeout_s:
                raise AssertionError(f"the smoke workflow in {self.wd} did not end in {timeout_s:.0f} s")
            time.sleep(1.0)
        time.sleep(0.1)                         # the status is written
        status = rc.read_text().strip()
        if status != "0":
            tail = (self.wd / "snakemake.log").read_text()[-6000:]
            raise AssertionError(f"the smoke workflow in {self.wd} failed (exit {status}):\n{tail}")
        return self.wd

    def stop(self) -> None:
        """End the run if it is still going (the test session ends)."""
        pid = self.wd / "snakemake.pid"
        if not pid.exists() or (self.wd / "snakemake.rc").exists():
            return
        try:
            os.killpg(int(pid.read_text()), signal.SIGTERM)
        except (ProcessLookupError, ValueError):
            pass


#: fixtures backed by a clean smoke run of their own
SMOKE_FIXTURES = ("smoke_workdir",)
#: fixtures of module scope shared by several tests and costly to make: with pytest-xdist the
#: tests that use one run on the same worker, which makes it once (the smoke workflow is shared
#: between the workers by its folder: the tests only read it)
SHARED_FIXTURES = ("row1", "row2", "row3", "row4", "row5", "rig_pair", "heavier_rig", "chain", "workflow", "data",
                   "model", "plant_and_physics", "pid", "known")
#: the costliest of them, costliest first (their analyses' CPU times are on the validation page):
#: their groups start first, so that the two workers end on the quick tests together and not one
#: on a long analysis while the other idles
LONGEST_FIRST = ("row5", "row4", "row2", "row3", "row1")
_CONFIG = None
#: the smoke runs this process started (it reaps them)
_STARTED: list[subprocess.Popen] = []


def pytest_configure(config):
    global _CONFIG
    _CONFIG = config


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session):
    """Compile the simulator once, in the controlling process, before pytest-xdist starts its
    workers: numba's on-disk cache (``ssamb/sim/__pycache__``) is then warm for the workers, the
    smoke workflow's jobs and the replay workers. On a clean clone they would otherwise start at
    once and each compile it, several times the cost of loading it from the cache. The rest of
    the compiled code (the ball, mu, the linear simulation) is compiled beside it, in a process
    of its own (tests/warm_caches.py), for the same reason; its failure fails no test here (the
    tests of that code report it)."""
    if hasattr(session.config, "workerinput"):
        return
    from ssamb.config import load_config
    from ssamb.sim import simulate

    warm = subprocess.Popen([sys.executable, str(ROOT / "tests" / "warm_caches.py")], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        simulate(load_config(), "multisine", duration_s=0.01, progress=False)
    finally:
        try:
            warm.wait(timeout=600)
        except subprocess.TimeoutExpired:
            warm.kill()
            warm.wait()


def _run(name: str) -> _Background:
    return _Background(_shared_root() / name.replace("_workdir", ""))


def _cost_rank(item) -> int:
    """Where a test goes in the queue of the two workers: 0, the costly tests (marked ``slow`` or
    ``workflow``: simulations of seconds, Snakemake processes) that do not read the smoke
    workflow; 1, the slow ones that read it (it has run in the background meanwhile); 2, the
    quick tests; 3, the quick readers of the smoke workflow. The session then ends on many short
    tests, which keep both workers busy to the end, and not on one long test (the rerun of the
    smoke workflow's rules) that can start only when the smoke workflow is done while the other
    worker idles beside it."""
    smoke = bool(set(getattr(item, "fixturenames", ())) & set(SMOKE_FIXTURES))
    slow = item.get_closest_marker("slow") is not None
    if smoke:
        return 1 if slow else 3
    return 0 if slow or item.get_closest_marker("workflow") is not None else 2


def _shared(item) -> str | None:
    """The costly fixture ``item`` shares with other tests (SHARED_FIXTURES), if any."""
    shared = sorted(set(getattr(item, "fixturenames", ())) & set(SHARED_FIXTURES))
    return shared[0] if shared else None


def _queue_key(item) -> tuple:
    """Where a test goes in the queue: by :func:`_cost_rank`, and within it the groups of
    LONGEST_FIRST in that order before the rest."""
    group = _shared(item)
    return _cost_rank(item), LONGEST_FIRST.index(group) if group in LONGEST_FIRST else len(LONGEST_FIRST)


def pytest_collection_modifyitems(config, items):
    """With pytest-xdist, every worker orders the tests the same way (:func:`_queue_key`; the
    order of collection within a rank) and writes which tests share a costly fixture
    (``groups.json`` in the session's folder), for the scheduler (:func:`pytest_xdist_make_scheduler`)."""
    if not hasattr(config, "workerinput"):
        return
    items.sort(key=_queue_key)              # stable: the order of collection within a key
    groups = {item.nodeid: _shared(item) for item in items if _shared(item)}
    tmp = _shared_root() / f"groups.json.{os.getpid()}"
    tmp.write_text(json.dumps(groups))
    os.replace(tmp, _shared_root() / "groups.json")


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup``: the tests that share a costly fixture (SHARED_FIXTURES) are one unit
    of work, sent to one worker; every other test is a unit of its own. (pytest-xdist's own
    ``loadgroup`` marks the group in the node id, which pytest 9.2 no longer lets it change.) The
    units go out in the order of the queue (:func:`_queue_key`), not reordered by their number of
    tests."""
    if config.getvalue("dist") != "loadgroup":
        return None
    config.option.loadscopereorder = False
    from xdist.scheduler import LoadScopeScheduling

    class SharedFixtureScheduling(LoadScopeScheduling):
        groups: dict | None = None

        def _split_scope(self, nodeid: str) -> str:
            if self.groups is None:         # all workers have collected (and written the groups)
                path = config._tmp_path_factory.getbasetemp() / "groups.json"
                self.groups = json.loads(path.read_text()) if path.exists() else {}
            group = self.groups.get(nodeid)
            return f"shared fixture {group}" if group else nodeid

    return SharedFixtureScheduling(config, log)


def pytest_collection_finish(session):
    """Start the smoke runs the selected tests need (one per fixture, at most two per session)."""
    needed = {f for item in session.items for f in getattr(item, "fixturenames", ())}
    for name in SMOKE_FIXTURES:
        if name in needed:
            _run(name).start()


def pytest_sessionfinish(session):
    """The process that ends the session (not a pytest-xdist worker) ends the smoke runs."""
    if hasattr(session.config, "workerinput"):    # another worker may still wait for its runs
        return
    for name in SMOKE_FIXTURES:
        _run(name).stop()
    for proc in _STARTED:
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()


def _smoke(name: str) -> Path:
    run = _run(name)
    run.start()                             # collected another way: start it now (no-op if started)
    return run.result()


def _row(tmp_path_factory, name: str, out: bool = False) -> dict:
    """Row ``name`` of issue 23's table (tests/rowcases.py), analysed once per session:
    ``{"report", "oracle_z", "out"}`` (``out``: with ``out=True`` the folder where the analysis is
    written as the command line writes it, ``closeloop.json`` and the figures). The row's tests
    judge the findings and the oracle apart; the format tests read what row 5 wrote."""
    from rowcases import analysed, row

    experiment, effects, duration_s = row(name)
    tmp = tmp_path_factory.mktemp(name)
    rep, z = analysed(tmp, experiment, effects, duration_s=duration_s, workers=REPLAY_WORKERS,
                      out=tmp / "out" if out else None)
    return {"report": rep, "oracle_z": z, "out": tmp / "out" if out else None}


def _row_fixture(name: str, doc: str, out: bool = False):
    """A session fixture ``name`` (pytest finds it by that name) analysing that row (:func:`_row`)."""
    @pytest.fixture(scope="session", name=name)
    def fixture(tmp_path_factory) -> dict:
        return _row(tmp_path_factory, name, out)
    fixture.__doc__ = doc
    return fixture


row1 = _row_fixture("row1", "Row 1: an 8 N x load, the identification's current pulses.")
row2 = _row_fixture("row2", "Row 2: a 37 us sensor delay on both axes, a multisine on y.")
row3 = _row_fixture("row3", "Row 3: the same delay, a multisine on both axes.")
row4 = _row_fixture("row4", "Row 4: a 15 us y sensor delay and a -4 N y load, a multisine on y.")
row5 = _row_fixture("row5", "Row 5: the same rig, a multisine on both axes, written as the command line writes it "
                    "(the format tests read it).", out=True)


@pytest.fixture(scope="session")
def smoke_workdir() -> Path:
    """A finished smoke workflow (shared: tests may dry-run in it, must not change its files)."""
    return _smoke("smoke_workdir")

