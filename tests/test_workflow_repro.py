"""Reproducible reruns of the workflow (issue 14): params compared by content, byte-identical
results when every rule's job runs again, a non-finite config value stopping the workflow before any job."""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import time

import pytest
import yaml
from conftest import SMOKE_ARGS, copy_repo, run_snakemake

pytestmark = pytest.mark.workflow


def _reversed(obj):
    """``obj`` with the key order of every mapping reversed (values untouched)."""
    if isinstance(obj, dict):
        return {k: _reversed(obj[k]) for k in reversed(list(obj))}
    return obj


def _planned(r) -> set[str]:
    """Rules a (dry) run would execute, from Snakemake's job listing."""
    lines = (r.stdout + r.stderr).splitlines()
    return {ln.split()[1].rstrip(":") for ln in lines if ln.startswith(("rule ", "localrule "))}


def _replace(path, text: str, mtime_ns: int) -> None:
    """``path`` gets ``text`` and ``mtime_ns`` in one step (a dry run beside sees one or the other)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.utime(tmp, ns=(mtime_ns, mtime_ns))
    os.replace(tmp, path)


def test_reordered_config_keys_plan_nothing(smoke_workdir):
    path = smoke_workdir / "config.yaml"
    text, st = path.read_text(), path.stat()
    cfg = yaml.safe_load(text)
    reordered = _reversed(cfg)
    assert list(reordered["table1"]) != list(cfg["table1"]) and reordered == cfg
    try:
        # same mtime: only the params comparison is under test (the report rule also reads
        # config.yaml as a file and would rerun on its new mtime)
        _replace(path, yaml.safe_dump(reordered, sort_keys=False), st.st_mtime_ns)
        r = run_snakemake(smoke_workdir, "-n", "--cores", "1", *SMOKE_ARGS)
        assert _planned(r) == set(), r.stdout[-3000:]
        assert "Nothing to be done" in r.stdout + r.stderr
    finally:
        _replace(path, text, st.st_mtime_ns)


def _checksums(results) -> dict:
    files = sorted(list(results.rglob("*.json")) + list(results.rglob("*.npz")))
    return {str(f.relative_to(results)): hashlib.sha256(f.read_bytes()).hexdigest() for f in files}


#: the summary, run again first and on its own: it reads every stage, so in a run after the
#: others it would rerun each stage's every job
SUMMARY = "results/summary.json"
#: jobs run again (``--forcerun``) in a copy of the finished smoke workflow: a simulation, an
#: identification, the close-the-loop analyses, the ceiling, the paper's way's selection
FORCED = ("results/sim/levitate.npz", "results/ident/selfsensing.npz", "results/closeloop/rig_demo/closeloop.json",
          "results/rigs/recordings/maglev1d/escalon/closeloop.json", "results/ceiling/fig4.json",
          "results/runs/paper/select/plant.npz")
#: what is asked for downstream of them: one job of each rule the identification feeds (the
#: assembly, one uncertainty, one mu case, the baseline, the validation) and the rig's combination
DOWNSTREAM = ("results/mu/selfsensing.json", "results/mu/baseline.json", "results/validation/sweep.json",
              "results/rigs/maglev1d/closeloop.json")
#: the jobs that run: every rule that writes results (JSON, NPZ), once
RERUN = sorted(["simulate", "identify", "closeloop", "closeloop_recording", "ceiling", "assemble", "baseline",
                "validate", "closeloop_rig", "summary", "select", "uncertainty", "mu"])


def _ran(r) -> list[str]:
    return [ln.split()[1].rstrip(":") for ln in (r.stdout + r.stderr).splitlines()
            if ln.startswith(("rule ", "localrule "))]


@pytest.mark.slow
def test_every_rule_rewrites_the_same_bytes(smoke_workdir, tmp_path):
    """Byte-reproducible results: in a copy of the finished smoke workflow, one job of every rule
    that writes results runs again (Snakemake deletes a job's outputs first) on the inputs the
    first run made: the summary, then a simulation, an identification and one job of each stage
    it feeds in the default run, the close-the-loop analyses, the ceiling, the paper's way's
    selection. Every JSON and NPZ file, the rewritten ones among them, is byte-identical to the
    first run's. A job's bytes depend on its inputs and params alone, so a clean run of the whole
    workflow repeats them job by job (the jobs not repeated run the same rules on other data)."""
    wd = tmp_path / "again"
    shutil.copytree(smoke_workdir, wd, symlinks=True, ignore=shutil.ignore_patterns("snakemake.*"))
    t0 = time.time_ns()
    ran = _ran(run_snakemake(wd, SUMMARY, "--forcerun", SUMMARY, "--cores", "2", *SMOKE_ARGS))
    ran += _ran(run_snakemake(wd, *DOWNSTREAM, *FORCED, "--forcerun", *FORCED, "--cores", "2", *SMOKE_ARGS))
    assert sorted(ran) == RERUN, sorted(ran)
    assert all((wd / f).stat().st_mtime_ns > t0 for f in FORCED + DOWNSTREAM + (SUMMARY,))  # rewritten
    first, again = _checksums(smoke_workdir / "results"), _checksums(wd / "results")
    assert first.keys() == again.keys() and len(first) > 40
    differ = sorted(k for k in first if first[k] != again[k])
    assert not differ, f"{len(differ)} of {len(first)} files differ: {', '.join(differ)}"


def test_nonfinite_config_value_stops_the_workflow(tmp_path):
    copy_repo(tmp_path)
    text = (tmp_path / "config.yaml").read_text()
    assert "mass_kg: 3.86" in text
    (tmp_path / "config.yaml").write_text(text.replace("mass_kg: 3.86", "mass_kg: .nan"))
    r = run_snakemake(tmp_path, "-n", "--cores", "1", check=False)
    out = r.stdout + r.stderr
    assert r.returncode != 0
    assert "table1.mass_kg" in out and "finite" in out
    assert not _planned(r) and not (tmp_path / "results").exists()


def _merged(base: dict, over: dict) -> dict:
    """``over`` merged into ``base`` recursively (what Snakemake does with --configfile)."""
    out = dict(base)
    for k, v in over.items():
        out[k] = _merged(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def test_cli_and_workflow_simulations_are_bit_identical(smoke_workdir, tmp_path):
    """The command line and the workflow (canonical config, params) simulate the same bits."""
    import numpy as np

    cfg = _merged(yaml.safe_load((smoke_workdir / "config.yaml").read_text()),
                  yaml.safe_load((smoke_workdir / "smoke.yaml").read_text()))
    (tmp_path / "merged.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "ms.npz"
    r = subprocess.run([sys.executable, "-m", "ssamb", "simulate", "--experiment", "multisine", "--config",
                        str(tmp_path / "merged.yaml"), "--out", str(out), "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with np.load(out) as a, np.load(smoke_workdir / "results" / "sim" / "multisine.npz") as b:
        assert set(a.files) == set(b.files)
        differ = [k for k in a.files if k != "meta" and a[k].tobytes() != b[k].tobytes()]
    assert not differ, differ
