"""End-to-end smoke test of the Snakemake workflow with a reduced configuration.

Runs the whole workflow (simulate -> identify -> assemble -> uncertainty -> mu -> validate ->
closeloop -> summary -> report) in a copy of the repository, checks that every stage's outputs
exist and are sane, that a changed analysis parameter reruns exactly the dependent rules, and
that a bad config stops before any job with the schema message.
"""
from __future__ import annotations

import json
import math

import pytest
import yaml
from conftest import copy_repo as _copy_repo
from conftest import run_snakemake as _run

pytestmark = pytest.mark.workflow


@pytest.fixture(scope="module")
def workdir(smoke_workdir):
    return smoke_workdir


def test_every_stage_output_exists_and_is_sane(workdir):
    res = workdir / "results"
    s = json.loads((res / "summary.json").read_text())
    for key in ("fit_pct", "orders", "subsystem_fit_pct", "weight_fit_max_db", "mu", "delevitation_s",
                "iso14839_peak_sensitivity", "closeloop"):
        assert key in s
    assert s["orders"] == {"plant": 9, "amplifier": 7, "selfsensing": 3}
    assert s["details"]["assembly"]["stable"] is True
    assert 50 < s["fit_pct"]["x"] <= 100 and 0 < s["fit_pct"]["y"] <= 100
    for case in ("selfsensing", "amplifier", "plant", "all"):
        m = s["mu"][case]
        assert math.isfinite(m["peak"]) and m["peak"] > 0
        assert m["scale_for_unity"] == pytest.approx(1 / m["peak"], rel=1e-9)
    # the all-block case bounds each single-subsystem case from above
    assert s["mu"]["all"]["peak"] >= max(s["mu"][c]["peak"] for c in ("selfsensing", "amplifier", "plant")) * 0.98
    assert s["weight_fit_max_db"] <= 3.0 + 1e-6
    assert s["iso14839_peak_sensitivity"]["x"] >= 1.0
    assert isinstance(s["closeloop"]["effects"], list)
    html = (res / "report.html").read_text()
    assert "Paper versus reproduction" in html and html.count("<img") >= 10
    assert "Traceback" not in html
    for f in ("model/fig4.png", "validation/fig9.png", "mu/selfsensing_fig8.png", "uncertainty/selfsensing_fig7.png"):
        assert (res / f).stat().st_size > 10_000
    # every rule left a log and a benchmark
    assert len(list((res / "benchmarks").rglob("*.tsv"))) >= 15


def test_changed_parameter_reruns_only_dependents(workdir):
    over = yaml.safe_load((workdir / "smoke.yaml").read_text())
    over["mu"]["n_points"] = 41
    (workdir / "smoke2.yaml").write_text(yaml.safe_dump(over))
    r = _run(workdir, "-n", "--cores", "1", "--configfile", "config.yaml", "smoke2.yaml")
    out = r.stdout + r.stderr
    ran = {line.split()[1].rstrip(":") for line in out.splitlines() if line.startswith("rule ")}
    ran |= {line.split()[1].rstrip(":") for line in out.splitlines() if line.startswith("localrule ")}
    assert "mu" in ran and "summary" in ran and "report" in ran
    assert not ran & {"simulate", "identify", "assemble", "uncertainty", "closeloop", "validate"}


def test_bad_config_stops_before_any_job(tmp_path):
    _copy_repo(tmp_path)
    cfg = yaml.safe_load((tmp_path / "config.yaml").read_text())
    cfg["table1"]["mass_kg"] = -3.86
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    r = _run(tmp_path, "--cores", "1", check=False)
    assert r.returncode != 0
    assert "table1.mass_kg" in (r.stdout + r.stderr)
    assert not (tmp_path / "results").exists()
