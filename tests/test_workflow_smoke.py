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
from conftest import ROOT
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


def test_paper_way_and_a_scenario_that_shares_unchanged_stages(workdir):
    res = workdir / "results"
    s = json.loads((res / "summary.json").read_text())
    assert {"stable", "fit_pct", "mu", "mu_peak_cause"} <= set(s["paper_way"])
    assert "The paper's way" in (res / "report.html").read_text()
    # the sweep-only scenario re-simulated the sweep and re-validated; nothing else
    sw = res / "runs" / "sweep_amp"
    assert (sw / "sim" / "sweep.npz").exists() and (sw / "validation" / "sweep.json").exists()
    assert not any((sw / d).exists() for d in ("ident", "model", "uncertainty", "mu"))
    assert len(list((sw / "sim").glob("*.npz"))) == 1
    v = json.loads((sw / "summary.json").read_text())
    assert v["details"]["validation"]["sweep"]["amplitude_m"] == pytest.approx(8e-5)
    assert v["mu"] == s["mu"]  # shared, not recomputed


def _planned(out: str) -> list[tuple[str, str]]:
    """(rule, wildcards) of every job a dry run plans."""
    jobs, rule = [], None
    for line in out.splitlines():
        if line.startswith(("rule ", "localrule ")):
            rule = line.split()[1].rstrip(":")
            jobs.append([rule, ""])
        elif line.strip().startswith("wildcards:") and jobs:
            jobs[-1][1] = line.split(":", 1)[1].strip()
    return [tuple(j) for j in jobs]


def test_changed_override_reruns_only_that_variant(workdir):
    over = yaml.safe_load((workdir / "smoke.yaml").read_text())
    over["scenarios"]["sweep_amp"]["experiments.sweep.excitation.amplitude_m"] = 8.5e-5
    (workdir / "smoke3.yaml").write_text(yaml.safe_dump(over))
    r = _run(workdir, "-n", "--cores", "1", "--configfile", "config.yaml", "smoke3.yaml")
    jobs = [j for j in _planned(r.stdout + r.stderr) if j[0] != "all"]
    assert sorted(j[0] for j in jobs) == ["simulate", "summary", "validate"], jobs
    assert all("run=runs/sweep_amp/" in w for _, w in jobs), jobs


def test_study_plans_one_job_per_stage_and_variant(workdir):
    r = _run(workdir, "study", "-n", "--cores", "1", "--configfile", "config.yaml", "smoke.yaml")
    jobs = _planned(r.stdout + r.stderr)
    runs = {w.split("run=")[1].split(",")[0] for _, w in jobs if "run=runs/study-" in w}
    assert {"runs/study-baseline/", "runs/study-sweep_law=log/", "runs/study-sweep_law=log+bias=3.2/"} <= runs
    # one job per (rule, wildcards): nothing planned twice
    assert len(jobs) == len(set(jobs))
    # the sweep-law variant shares the study baseline's identification: it plans no identify job
    assert not [j for j in jobs if j[0] == "identify" and "run=runs/study-sweep_law=log/" in j[1]]


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


def test_slurm_profile_plans_one_job_per_stage_and_run(tmp_path):
    """The SLURM profile: status by squeue (works without accounting), no cpus_per_task in the
    default resources (it would override every rule's threads), and a dry run that plans every
    stage of every run as its own job."""
    pytest.importorskip("snakemake_executor_plugin_slurm")
    prof = yaml.safe_load((ROOT / "workflow" / "profiles" / "slurm" / "config.yaml").read_text())
    assert prof["slurm-status-command"] == "squeue"
    assert "cpus_per_task" not in prof["default-resources"]
    _copy_repo(tmp_path)
    r = _run(tmp_path, "-n", "--profile", "workflow/profiles/slurm", "--configfile", "config.yaml", "smoke.yaml")
    jobs = _planned(r.stdout + r.stderr)
    assert len(jobs) == len(set(jobs))
    runs = {w.split("run=")[1].split(",")[0] for _, w in jobs if "run=" in w}
    assert {"", "runs/paper/", "runs/sweep_amp/"} <= runs


def test_slurm_profile_plans_the_ensembles_one_job_per_stage_and_realisation(tmp_path):
    """`snakemake -n --profile workflow/profiles/slurm ensemble`: every stage of every noise
    realisation is its own job, nothing planned twice; the paper's way identifies from the default
    run's simulations of the same realisation (no simulate job of its own)."""
    pytest.importorskip("snakemake_executor_plugin_slurm")
    _copy_repo(tmp_path)
    r = _run(tmp_path, "ensemble", "-n", "--profile", "workflow/profiles/slurm", "--configfile", "config.yaml",
             "smoke.yaml")
    jobs = _planned(r.stdout + r.stderr)
    assert len(jobs) == len(set(jobs))
    runs = {w.split("run=")[1].split(",")[0] for _, w in jobs if "run=" in w}
    for chain in ("default", "paper", "paper_literal", "paper_rig"):
        assert f"runs/{chain}.r1/" in runs, chain
        assert ("summary", f"run=runs/{chain}.r1/") in jobs
    ident = {w for rule, w in jobs if rule == "identify"}
    assert {f"run=runs/paper.r1/, subsystem={s}" for s in ("plant", "amplifier", "selfsensing")} <= ident
    assert not [w for rule, w in jobs if rule == "simulate" and "run=runs/paper.r1/" in w]
    assert ("ensemble_collect", "") in jobs and ("ceiling", "kind=fig4") in jobs
