"""Runs of the chain: scenarios and study variants as config overrides, stage sharing between
runs, and failures recorded as data (a failed variant is reported as failed)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ssamb.config import ConfigError, load_config
from ssamb.model_io import Failed, failure_reason, load_model
from ssamb.scenarios import Plan, run_configs, study_variants
from ssamb.stages import run_guarded
from ssamb.stages.assemble import run_assemble
from ssamb.stages.study import collect_study
from ssamb.stages.summary import build_summary


@pytest.fixture(scope="module")
def cfg():
    c = load_config()
    c["scenarios"] = {"slow_sweep": {"experiments.sweep.duration_s": 0.6,
                                     "experiments.sweep.excitation.sweep_duration_s": 0.6}}
    c["study"] = {"overrides": {"mu.cases": ["selfsensing"]},
                  "assumptions": {"bias": {"key": "table1.i_bias_a", "values": [2.5, 3.5]},
                                  "law": {"key": "experiments.sweep.excitation.law", "values": ["log"]}},
                  "pairs": [["bias", "law"]], "criteria": c["study"]["criteria"]}
    c["default_scenarios"] = ["slow_sweep"]
    c["ensemble"]["runs"] = ["default"]
    return c


def test_study_variants_one_at_a_time_and_in_pairs(cfg):
    v = study_variants(cfg)
    assert set(v) == {"study-baseline", "study-bias=2.5", "study-bias=3.5", "study-law=log",
                      "study-bias=2.5+law=log", "study-bias=3.5+law=log"}
    assert v["study-bias=2.5+law=log"] == {"mu.cases": ["selfsensing"], "table1.i_bias_a": 2.5,
                                           "experiments.sweep.excitation.law": "log"}
    assert v["study-baseline"] == {"mu.cases": ["selfsensing"]}


def test_plan_shares_every_stage_a_variant_does_not_change(cfg):
    P = Plan(run_configs(cfg))
    sweep_run = "runs/slow_sweep/"
    # a sweep-only scenario re-simulates the sweep and re-validates; everything else is the default's
    assert P.owner("simulate", sweep_run, experiment="sweep") == sweep_run
    assert P.owner("validate", sweep_run) == sweep_run
    for stage, wc in [("simulate", {"experiment": "id_pulses"}), ("identify", {"subsystem": "plant"}),
                      ("assemble", {}), ("uncertainty", {"subsystem": "selfsensing"}), ("mu", {"case": "all"}),
                      ("baseline", {})]:
        assert P.owner(stage, sweep_run, **wc) == "", stage
    # the study overrides change mu (its cases) but not the identification of the baseline
    assert P.owner("identify", "runs/study-baseline/", subsystem="amplifier") == ""
    assert P.owner("mu", "runs/study-baseline/", case="selfsensing") == ""
    # a physics variant re-simulates everything; the law variant shares with the study baseline
    assert P.owner("simulate", "runs/study-bias=2.5/", experiment="id_pulses") == "runs/study-bias=2.5/"
    assert P.owner("validate", "runs/study-law=log/") == "runs/study-law=log/"
    assert P.owner("validate", "runs/study-bias=2.5+law=log/") == "runs/study-bias=2.5+law=log/"
    assert P.owner("identify", "runs/study-bias=2.5+law=log/", subsystem="plant") == "runs/study-bias=2.5/"


def test_an_override_of_a_missing_key_names_the_run(cfg):
    bad = dict(cfg, scenarios={"typo": {"table1.mas_kg": 4.0}})
    with pytest.raises(ConfigError, match="run 'typo'.*table1.mas_kg"):
        run_configs(bad)


def test_a_failed_stage_is_recorded_downstream_and_in_the_summary(tmp_path):
    """A failing fit in a tolerant (scenario or study) run writes failure markers; the next stage
    reads them as a failure and records it too; the summary names the failed stage."""
    def failing_fit(*_):
        raise np.linalg.LinAlgError("SVD did not converge")

    ident = [tmp_path / f"{s}.npz" for s in ("plant", "amplifier", "selfsensing")]
    ev = tmp_path / "plant_evidence.json"
    run_guarded("identify", [ident[0], ev], failing_fit, tolerate=True)
    with pytest.raises(Failed, match="SVD did not converge"):
        load_model(ident[0])
    with pytest.raises(np.linalg.LinAlgError):  # the default run is not tolerant
        run_guarded("identify", [ident[0]], failing_fit)
    asm = tmp_path / "assemble.json"
    outs = [tmp_path / "cl.npz", asm, tmp_path / "fig4.png"]
    models = dict(zip(("plant", "amplifier", "selfsensing"), ident))
    run_guarded("assemble", outs, run_assemble, models, {}, tmp_path / "none.npz", load_config(), *outs,
                tolerate=True)
    assert "SVD did not converge" in failure_reason(asm)
    val = tmp_path / "val.json"
    val.write_text(json.dumps({"failed": True, "stage": "validate", "error": "upstream"}))
    s = build_summary(asm, {"plant": ev}, {}, {}, val, val)
    assert s["fit_pct"] == {"x": None, "y": None} and s["orders"] == {"plant": None}
    assert "SVD did not converge" in s["failed"]["assemble"] and "identify/plant" in s["failed"]


def test_collect_study_reports_a_failed_variant(tmp_path, cfg):
    ok = {"fit_pct": {"x": 97.0, "y": 80.0}, "mu": {"selfsensing": {"peak": 0.3, "peak_hz": 90.0,
                                                                      "scale_for_unity": 3.3}},
          "delevitation_s": {"nonlinear": None, "nominal_lti": None, "augmented_lti": None},
          "details": {"assembly": {"stable": True}, "validation": {"outcomes": [
              {"model": "nonlinear", "critical_amplitude_m": 1.3e-4}]}}, "failed": {}}
    bad = {"fit_pct": {"x": None, "y": None}, "mu": {"selfsensing": None}, "delevitation_s": {},
           "details": {"assembly": None, "validation": None}, "failed": {"identify/amplifier": "LinAlgError"}}
    runs = ["runs/study-baseline/", "runs/study-bias=2.5/"]
    paths = []
    for r, s in zip(runs, (ok, bad)):
        p = tmp_path / r / "summary.json"
        p.parent.mkdir(parents=True)
        p.write_text(json.dumps(s))
        paths.append(p)
    res = collect_study(cfg["study"], runs, paths, tmp_path / "study.json", tmp_path / "tornado.png")
    v = res["variants"]["study-bias=2.5"]
    assert v["failed"] == {"identify/amplifier": "LinAlgError"} and v["fit_y_pct"] is None
    assert res["variants"]["study-baseline"]["critical_nonlinear_um"] == pytest.approx(130.0)
    assert (tmp_path / "tornado.png").stat().st_size > 1000


def test_study_answers_follow_the_configured_criteria():
    from ssamb.stages.study import answers

    q = {"delevitation_nonlinear_s": 0.18, "delevitation_nominal_lti_s": None, "delevitation_augmented_lti_s": None,
         "mu_peak_hz": 3.5, "fit_y_pct": 58.0}
    loose = answers({"v": q}, {"mu_peak_factor": 2.0, "fit_y_points": 10.0})
    tight = answers({"v": q}, {"mu_peak_factor": 1.5, "fit_y_points": 5.0})
    assert loose == {"delevitation": ["v"], "mu_peak_near_2hz": ["v"], "fit_y_near_paper": ["v"]}
    assert tight == {"delevitation": ["v"], "mu_peak_near_2hz": [], "fit_y_near_paper": []}


def test_the_study_against_the_noise(tmp_path, cfg):
    """With the ensembles, a variant moves a headline only beyond the noise band around the
    baseline, and the answers widen each criterion by the variant's own band."""
    from ssamb.stages.study import answers, noise_bands

    spread = {"fit_y_pct": {"K": 8, "median": 40.0, "min": 35.0, "max": 48.0},
              "mu_peak_hz": {"K": 8, "median": 100.0, "min": 50.0, "max": 200.0}}
    ens = {"chains": {"default": {"quantities": spread}}}
    nb = noise_bands({"fit_y_pct": 30.0, "mu_peak_hz": 10.0}, ens)
    assert (nb["fit_y_pct"]["lo"], nb["fit_y_pct"]["hi"]) == (25.0, 38.0)
    assert (nb["mu_peak_hz"]["lo"], nb["mu_peak_hz"]["hi"]) == (5.0, 20.0)  # log scale: ratios
    assert noise_bands({"fit_y_pct": 30.0}, None) == {}
    q = {"delevitation_nonlinear_s": None, "delevitation_nominal_lti_s": None, "delevitation_augmented_lti_s": None,
         "mu_peak_hz": 5.0, "fit_y_pct": 43.0}
    crit = {"mu_peak_factor": 1.5, "fit_y_points": 0.0}
    # 43 % with a noise band of [38, 51] reaches 50.76 %; a 5 Hz peak with [2.5, 10] reaches 2 Hz x 1.5
    assert answers({"v": q}, crit, ens) == {"delevitation": [], "mu_peak_near_2hz": ["v"], "fit_y_near_paper": ["v"]}
    assert answers({"v": q}, crit) == {"delevitation": [], "mu_peak_near_2hz": [], "fit_y_near_paper": []}
    ok = {"fit_pct": {"x": 97.0, "y": 30.0},
          "mu": {"selfsensing": {"peak": 0.3, "peak_hz": 10.0, "scale_for_unity": 3.3}},
          "delevitation_s": {}, "details": {"assembly": {"stable": True}}, "failed": {}}
    inside = {**ok, "fit_pct": {"x": 97.0, "y": 36.0}}
    beyond = {**ok, "fit_pct": {"x": 97.0, "y": 45.0}}
    runs = ["runs/study-baseline/", "runs/study-bias=2.5/", "runs/study-bias=3.5/"]
    paths = []
    for r, s in zip(runs, (ok, inside, beyond)):
        p = tmp_path / r / "summary.json"
        p.parent.mkdir(parents=True)
        p.write_text(json.dumps(s))
        paths.append(p)
    (tmp_path / "ensemble.json").write_text(json.dumps(ens))
    res = collect_study(cfg["study"], runs, paths, tmp_path / "study.json", ensemble_json=tmp_path / "ensemble.json")
    assert res["variants"]["study-bias=2.5"]["beyond_noise"]["fit_y_pct"] is False
    assert res["variants"]["study-bias=3.5"]["beyond_noise"]["fit_y_pct"] is True
