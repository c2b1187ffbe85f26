"""Reproducible reruns of the workflow (issue 14): params compared by content, byte-identical
results between clean runs, a non-finite config value stopping the workflow before any job."""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys

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


def test_reordered_config_keys_plan_nothing(smoke_workdir):
    path = smoke_workdir / "config.yaml"
    text, st = path.read_text(), path.stat()
    cfg = yaml.safe_load(text)
    reordered = _reversed(cfg)
    assert list(reordered["table1"]) != list(cfg["table1"]) and reordered == cfg
    try:
        path.write_text(yaml.safe_dump(reordered, sort_keys=False))
        # same mtime: only the params comparison is under test (the report rule also reads
        # config.yaml as a file and would rerun on its new mtime)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
        r = run_snakemake(smoke_workdir, "-n", "--cores", "1", *SMOKE_ARGS)
        assert _planned(r) == set(), r.stdout[-3000:]
        assert "Nothing to be done" in r.stdout + r.stderr
    finally:
        path.write_text(text)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def _checksums(results) -> dict:
    files = sorted(list(results.rglob("*.json")) + list(results.rglob("*.npz")))
    return {str(f.relative_to(results)): hashlib.sha256(f.read_bytes()).hexdigest() for f in files}


@pytest.mark.slow
def test_two_clean_runs_give_byte_identical_results(smoke_workdir, smoke_second_workdir):
    first = _checksums(smoke_workdir / "results")
    second = _checksums(smoke_second_workdir / "results")
    assert first.keys() == second.keys()
    assert len(first) > 40
    differ = sorted(k for k in first if first[k] != second[k])
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
