"""The workflow and its inputs: a changed subsystem's order reruns that subsystem
only, an unchanged config lists no params change, and what an interruption leaves (the README's
"Resuming after an interruption"). Bad configs and a failed job's log: the workflow rows of the
bad-input table (tests/badinputs.py)."""
from __future__ import annotations

import os
import signal
import subprocess
import time

import pytest
import yaml
from conftest import SMOKE_ARGS, SNAKEMAKE, copy_repo, run_snakemake

pytestmark = pytest.mark.workflow


def _jobs(r) -> list[tuple[str, str]]:
    """(rule, wildcards) of every job a dry run plans."""
    jobs = []
    for line in (r.stdout + r.stderr).splitlines():
        if line.startswith(("rule ", "localrule ")):
            jobs.append([line.split()[1].rstrip(":"), ""])
        elif line.strip().startswith("wildcards:") and jobs:
            jobs[-1][1] = line.split(":", 1)[1].strip()
    return [tuple(j) for j in jobs]


def test_an_unchanged_config_lists_no_params_change(smoke_workdir):
    r = run_snakemake(smoke_workdir, "--list-changes", "params", *SMOKE_ARGS)
    assert [ln for ln in r.stdout.splitlines() if ln.startswith("results/")] == []


def test_a_subsystem_order_reruns_that_subsystem_and_its_descendants_only(smoke_workdir):
    over = yaml.safe_load((smoke_workdir / "smoke.yaml").read_text())
    over["identification"]["selfsensing"] = {"order": 2}
    (smoke_workdir / "order.yaml").write_text(yaml.safe_dump(over))
    r = run_snakemake(smoke_workdir, "-n", "--cores", "1", "--configfile", "config.yaml", "order.yaml")
    jobs = _jobs(r)
    identify = [w for rule, w in jobs if rule == "identify"]
    assert identify and all("subsystem=selfsensing" in w for w in identify), identify
    changed = run_snakemake(smoke_workdir, "--list-changes", "params", "--configfile", "config.yaml", "order.yaml")
    listed = [ln for ln in changed.stdout.splitlines() if ln.startswith("results/")]
    assert listed and all("ident/selfsensing" in ln for ln in listed), listed
    assert not {rule for rule, _ in jobs} & {"simulate", "closeloop"}


def _interruptible() -> None:
    """Ctrl-C at its default in the child, as a terminal's shell starts a command. A test session
    started in the background by a non-interactive shell (``pytest -q &``, a CI script) has
    SIGINT ignored, and an ignored signal stays ignored in every child: snakemake and its job
    would not see the Ctrl-C at all, the job would finish and snakemake exit 0."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(wd, log):
    """``snakemake`` on one long simulation in its own process group; returns once the job runs."""
    p = subprocess.Popen(SNAKEMAKE + ["results/sim/levitate.npz", "--cores", "1", "--configfile", "config.yaml",
                                      "long.yaml"], cwd=wd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, start_new_session=True, preexec_fn=_interruptible)
    t0 = time.time()
    while time.time() - t0 < 300 and "simulated [" not in (log.read_text() if log.exists() else ""):
        time.sleep(0.5)
    assert p.poll() is None, "the job ended before it could be interrupted"
    return p


def test_what_an_interruption_leaves(tmp_path):
    copy_repo(tmp_path)
    # a simulation of some seconds: long enough to be interrupted, short enough to be waited for
    (tmp_path / "long.yaml").write_text("experiments: {levitate: {duration_s: 10.0, start: rest, excitation: "
                                        "{kind: none}}}\nsimulation: {substeps: 20}\n")
    out = tmp_path / "results" / "sim" / "levitate.npz"
    log = tmp_path / "results" / "logs" / "simulate" / "levitate.log"
    dry = ["-n", "results/sim/levitate.npz", "--cores", "1", "--configfile", "config.yaml", "long.yaml"]

    # Ctrl-C: the terminal interrupts the whole foreground process group
    p = _start(tmp_path, log)
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 1, f"snakemake exited {p.returncode} after Ctrl-C:\n{err[-3000:]}\n{log.read_text()[-2000:]}"
    assert "KeyboardInterrupt" in log.read_text()
    assert not out.exists() and not out.with_suffix(".json").exists()
    r = run_snakemake(tmp_path, *dry)                    # a plain rerun plans the job again
    assert "Missing output files" in r.stdout + r.stderr

    # snakemake killed: its job survives, finishes, and its outputs stay marked incomplete
    log.unlink()
    p = _start(tmp_path, log)
    os.kill(p.pid, signal.SIGKILL)
    p.wait(60)
    t0 = time.time()
    while time.time() - t0 < 300 and "simulated in" not in log.read_text():
        time.sleep(1)
    time.sleep(2)
    assert out.exists() and out.with_suffix(".json").exists()
    r = run_snakemake(tmp_path, *dry, check=False)
    assert r.returncode != 0 and "IncompleteFilesException" in r.stdout + r.stderr
    r = run_snakemake(tmp_path, *dry, "--rerun-incomplete")
    assert "results/sim/levitate.npz" in r.stdout + r.stderr
    run_snakemake(tmp_path, "--unlock")                   # the stale lock goes, as the README says
