"""Close the loop on rigs that are not the model (issue 13): nominal parameters a few per cent
off, in-loop converter noise, logging noise, and library effects.

CI runs one analysis per case (each tens of seconds to two minutes, marked slow):

* a sensor delay on a rig whose nominal parameters (eddy-current conductivity among them) are
  off: the delay is found, the identified parameters are recovered, nothing crashes;
* an unbalance spinning at an exact harmonic of the excitation period (the line sits on the
  grid of the periodic response): found;
* noise only, from the nominal model: no effect declared.

``SSAMB_SLOW=1`` adds the randomized acceptance suite (:func:`test_randomized_acceptance`, 40
draws; :func:`test_randomized_false_alarms`, 50 noise-only draws) and writes its per-draw
outcomes to ``SSAMB_SUITE_OUT`` (default ``closeloop_suite.json`` in the test's temporary folder).
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from ssamb.closeloop import analyse
from ssamb.config import load_config
from ssamb.rig import load_scenario, rig_data
from ssamb.sim import simulate

REPO = Path(__file__).resolve().parent.parent
#: the demo's excitation: 30 um multisine, 5-100 Hz lines every 5 Hz, both axes (independent phases)
EXC = {"kind": "multisine", "point": "position", "axis": "both", "amplitude_m": 3.0e-5, "f_min_hz": 5,
       "f_max_hz": 100, "f_resolution_hz": 5, "periods": 10, "seed": 3}
NOISE = {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 11}
SEED = int(os.environ.get("SSAMB_TEST_SEED", "20260101"))
SLOW = bool(os.environ.get("SSAMB_SLOW"))
#: processes for the analysis's replays (the result does not depend on it; SSAMB_WORKERS=1 when
#: the suite itself runs in several processes)
WORKERS = int(os.environ.get("SSAMB_WORKERS", min(2, len(os.sched_getaffinity(0)))))
pytestmark = pytest.mark.slow
#: the calibratable parameters and how far a rig's may lie from the model's (the acceptance's
#: +-5 %; the calibration offset +-5 um)
PERTURB = {"table1.mass_kg": 0.05, "table1.airgap_m": 0.05, "table1.i_bias_a": 0.05, "table1.coil_turns": 0.05,
           "table1.r_coil_ohm": 0.05, "magnetics.iron_conductivity_s_per_m": 0.05, "table1.mu_r": 0.05,
           "table1.v_supply_v": 0.05, "sensors.x_bandwidth_hz": 0.05, "selfsensing.calibration_gain_error": 0.05,
           "selfsensing.calibration_offset_error_m": 5.0e-6}


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def rig(tmp: Path, effects: list, overrides: dict | None = None, name: str = "s", exc: dict = EXC,
        noise: dict = NOISE):
    """Rig data ``(arrays, meta, scenario)``: the rig's own parameters (``overrides``) and effects."""
    p = tmp / f"{name}.yaml"
    sc = {"config": str(REPO / "config.yaml"), "experiment": exc, "effects": effects, "noise": noise,
          "overrides": overrides or {}}
    p.write_text(yaml.safe_dump(sc))
    scenario = load_scenario(p)
    return (*rig_data(scenario), scenario)


def perturbation(rng: np.random.Generator, cfg: dict) -> tuple[dict, dict]:
    """Every calibratable parameter off by a uniform draw within :data:`PERTURB`: ``(overrides,
    relative or absolute changes)``."""
    ov, delta = {}, {}
    for key, width in PERTURB.items():
        nominal = _get(cfg, key)
        d = float(rng.uniform(-width, width))
        delta[key] = d
        ov[key] = nominal * (1 + d) if nominal != 0 else nominal + d
    return ov, delta


def _get(cfg, key):
    node = cfg
    for part in key.split("."):
        node = node[part]
    return node


def effective_truth(scenario: dict, delta: dict, y_gain: float = 1.0) -> dict:
    """The rig's parameters as the model can see them.

    The calibration gain and offset errors act on top of a calibration procedure (three clamped
    positions) that makes the self-sensing map exact at those positions for whatever physics it
    runs on; the model's own procedure is noise-free. So the errors the model must find are the
    rig's procedure's own (its noise, at its physics and with its effects: a cross-coupling or a
    dead time changes what the clamped calibration reads) on top of the scenario's: the rig's
    calibration against a noise-free one at the same physics and effects. (Against the model's
    calibration at the physics it ended with, the constants would differ by what the procedure
    compensates, which is not an error.) A y sensor gain G scales the calibrated estimate,
    y_ss = G (g y_raw + o): it *is* a calibration error, of gain G g and offset G o."""
    rig_cfg, eff = scenario["cfg"], scenario["effects"]
    rig_cal = simulate(rig_cfg, duration_s=0.005, excitation=scenario["excitation"], start=scenario["start"],
                       seed=scenario["seed"], effects=eff, progress=False).meta["selfsensing_calibration"]
    model_cal = simulate(rig_cfg, arrays={"r_y": np.zeros(400)}, calibration_noise=False, effects=eff,
                         progress=False).meta["selfsensing_calibration"]
    g, o = "selfsensing.calibration_gain_error", "selfsensing.calibration_offset_error_m"
    out = dict(delta)
    out[g] = y_gain * rig_cal["gain"] * (1 + delta[g]) / model_cal["gain"] - 1
    out[o] = y_gain * (rig_cal["offset_m"] + delta[o]) - model_cal["offset_m"]
    return out


def _relative(cfg: dict, key: str, value: float, se: bool = False) -> float:
    """A parameter's value (or standard error) relative to nominal (absolute for a zero nominal)."""
    nominal = _get(cfg, key)
    if nominal == 0:
        return value
    return value / abs(nominal) if se else value / nominal - 1


def check_parameters(rep: dict, truth: dict, cfg: dict) -> list[str]:
    """Every identified parameter within a third of its perturbation or two standard errors."""
    bad = []
    for key, p in rep["parameters"].items():
        est, se = _relative(cfg, key, p["value"]), _relative(cfg, key, p["se"], se=True)
        err = abs(est - truth[key])
        if not (err <= abs(truth[key]) / 3 or err <= 2 * se):
            bad.append(f"{key}: estimate {est:+.4g}, truth {truth[key]:+.4g}, se {se:.2g}")
    return bad


def check_effect(true: dict, rep: dict) -> list[str]:
    """The effect ranked first, its main parameter within 10 % (a delay within 3 us)."""
    name = true["name"]
    got = [e["params"] for e in rep["effects"] if e["name"] == name]
    y_gain_only = name == "sensor_gain" and true["axis"] == "y"
    if (not rep["effects"] and not y_gain_only) or (rep["effects"] and rep["effects"][0]["name"] != name):
        return [f"{name} not ranked first: {[e['name'] for e in rep['effects']]}"]
    g = got[0] if got else {}
    if name == "sensor_delay":
        axes = ("x", "y") if true["axis"] == "both" else (true["axis"],)
        vals = {ax: [p["delay_s"] for p in got if p["axis"] in (ax, "both")] for ax in axes}
        return [f"delay {ax}: {v} vs {true['delay_s']}" for ax, v in vals.items()
                if not v or abs(v[0] - true["delay_s"]) > 3e-6]
    if name == "sensor_gain":
        # a y gain is the DCM calibration's own error: carried by the calibration parameters
        # (checked with the parameters) or by the effect, either is right
        axes = ("x", "y") if true["axis"] == "both" else (true["axis"],)
        vals = {ax: [p["gain"] for p in got if p["axis"] in (ax, "both")] for ax in axes}
        return [f"gain {ax}: {v} vs {true['gain']}" for ax, v in vals.items()
                if (v and abs(v[0] - true["gain"]) > 0.1 * true["gain"]) or (not v and ax == "x")]
    if name == "static_load":
        f = math.hypot(true["fx_n"], true["fy_n"])
        err = math.hypot(g["fx_n"] - true["fx_n"], g["fy_n"] - true["fy_n"])
        return [] if err <= 0.1 * f else [f"static load {g} vs {true}"]
    if name == "unbalance":
        ok = abs(g["speed_hz"] / true["speed_hz"] - 1) < 0.1 and abs(g["mass_ecc_kgm"] / true["mass_ecc_kgm"] - 1) < 0.1
        return [] if ok else [f"unbalance {g} vs {true}"]
    key = {"amplifier_deadtime": "deadtime_s", "cross_coupling": "coefficient"}[name]
    return [] if abs(g[key] / true[key] - 1) < 0.1 else [f"{name} {g[key]} vs {true[key]}"]


def check_errors(rep: dict) -> list[str]:
    """Held-out rms after at most half of before on every channel clearly (3x) above its noise,
    or at the noise (within 1.5 times)."""
    bad = []
    for c in ("x_meas", "y_meas", "y_ss", "currents"):
        before, after = rep["error_before"][c]["rms"], rep["error_after"][c]["rms"]
        noise = rep["error_after"][c].get("noise_rms") or 0.0
        if before > 3 * noise and not (after <= 0.5 * before or after <= 1.5 * noise):
            bad.append(f"{c}: {before:.3g} -> {after:.3g} (noise {noise:.3g})")
    return bad


def draw_effect(effect: str, rng: np.random.Generator) -> dict:
    """One library effect with parameters from the ranges any rig may have (issue 6)."""
    if effect == "sensor_delay":
        return {"name": effect, "axis": str(rng.choice(["x", "y", "both"])), "delay_s": float(rng.uniform(5e-6, 100e-6))}
    if effect == "unbalance":
        f = float(rng.uniform(10.0, 200.0))
        return {"name": effect, "speed_hz": f, "mass_ecc_kgm": float(rng.uniform(0.5, 10.0)) / (2 * math.pi * f) ** 2,
                "phase_rad": float(rng.uniform(0, 2 * math.pi))}
    if effect == "static_load":
        f, a = float(rng.uniform(1.0, 20.0)), float(rng.uniform(0, 2 * math.pi))
        return {"name": effect, "fx_n": f * math.cos(a), "fy_n": f * math.sin(a)}
    if effect == "sensor_gain":
        g = float(rng.uniform(0.02, 0.2)) * float(rng.choice([-1.0, 1.0]))
        return {"name": effect, "axis": str(rng.choice(["x", "y", "both"])), "gain": 1.0 + g}
    if effect == "amplifier_deadtime":
        return {"name": effect, "deadtime_s": float(rng.uniform(0.2e-6, 2e-6))}
    return {"name": "cross_coupling", "coefficient": float(rng.uniform(0.02, 0.2))}


def test_sensor_delay_on_a_rig_with_other_parameters(tmp_path, cfg):
    """Issue 13's first failure: a 30 us sensor delay on x (far above the detection limit) on a
    rig whose mass, airgap, bias current, conductivity (the crash's case) and calibration gain
    are a few per cent off."""
    ov = {"table1.mass_kg": 3.86 * 1.04, "table1.airgap_m": 0.6e-3 * 0.97, "table1.i_bias_a": 3.0 * 1.03,
          "magnetics.iron_conductivity_s_per_m": 2.0e6 * 0.9, "selfsensing.calibration_gain_error": 1.02}
    true = {"name": "sensor_delay", "axis": "x", "delay_s": 3.0e-5}
    arrays, meta, scenario = rig(tmp_path, [true], ov)
    rep = analyse(arrays, meta, cfg, workers=WORKERS)
    assert not check_effect(true, rep), (check_effect(true, rep), rep["summary"])
    delta = {k: (v / _get(cfg, k) - 1) for k, v in ov.items()}
    truth = effective_truth(scenario, {**{k: 0.0 for k in PERTURB}, **delta})
    assert not check_parameters(rep, truth, cfg)
    assert "table1.i_bias_a" in rep["parameters"]          # the common-mode currents give the bias current
    assert not check_errors(rep)


def test_unbalance_on_a_harmonic_of_the_excitation_period(tmp_path, cfg):
    """A 3 N unbalance spinning at 150 Hz, an exact harmonic of the 0.2 s excitation period (a
    grid bin the excitation does not drive): its line is found on the grid, both axes, forward."""
    f = 150.0
    true = {"name": "unbalance", "speed_hz": f, "mass_ecc_kgm": 3.0 / (2 * math.pi * f) ** 2, "phase_rad": 1.1}
    arrays, meta, _ = rig(tmp_path, [true], name="harmonic")
    rep = analyse(arrays, meta, cfg, workers=WORKERS)
    assert rep["ranking"] and rep["ranking"][0] == "unbalance", rep["ranking"]
    assert not check_effect(true, rep), rep["summary"]


def test_noise_alone_declares_no_effect(tmp_path, cfg):
    arrays, meta, _ = rig(tmp_path, [], name="null", noise={**NOISE, "seed": SEED % 1000})
    rep = analyse(arrays, meta, cfg, workers=WORKERS)
    assert rep["effects"] == [], rep["summary"]


# -- the randomized suite (SSAMB_SLOW=1) ----------------------------------------------------
EFFECTS = ["sensor_delay", "unbalance", "static_load", "sensor_gain", "amplifier_deadtime", "cross_coupling"]


def run_draw(tmp: Path, cfg: dict, k: int, with_effect: bool) -> dict:
    """One randomized draw: every parameter perturbed, one library effect (or none); its outcome."""
    rng = np.random.default_rng([SEED, 13, k])
    ov, delta = perturbation(rng, cfg)
    true = draw_effect(EFFECTS[int(rng.integers(len(EFFECTS)))], rng) if with_effect else None
    seed = int(rng.integers(1, 10_000))
    arrays, meta, scenario = rig(tmp, [true] if true else [], ov, name=f"d{k}", exc={**EXC, "seed": seed},
                                 noise={**NOISE, "seed": seed + 1})
    rep = analyse(arrays, meta, cfg, workers=WORKERS)
    # what a y sensor gain the analysis did not name leaves to the calibration parameters
    g_true = true["gain"] if true and true["name"] == "sensor_gain" and true["axis"] in ("y", "both") else 1.0
    g_found = next((e.get("per_axis", {}).get("y", e["params"])["gain"] for e in rep["effects"]
                    if e["name"] == "sensor_gain" and e["params"]["axis"] in ("y", "both")), 1.0)
    truth = effective_truth(scenario, delta, g_true / g_found)
    fails = check_parameters(rep, truth, cfg)
    if true:
        fails += check_effect(true, rep)
    elif rep["effects"]:
        fails.append(f"effects declared on a draw without: {[e['name'] for e in rep['effects']]}")
    fails += check_errors(rep)
    est = {key: [_relative(cfg, key, p["value"]), truth[key], _relative(cfg, key, p["se"], se=True)]
           for key, p in rep["parameters"].items()}
    return {"draw": k, "effect": true, "perturbation": delta, "failures": fails, "summary": rep["summary"],
            "estimates": est, "effects_found": rep["effects"], "final_model": rep["final_model"],
            "identified": sorted(rep["parameters"]), "found": [e["name"] for e in rep["effects"]],
            "simulations": rep["timing"]["simulations"]}


def _suite_out(tmp: Path, name: str) -> Path:
    return Path(os.environ.get("SSAMB_SUITE_OUT", tmp / "closeloop_suite.json")).with_suffix(f".{name}.json")


@pytest.mark.skipif(not SLOW, reason="randomized acceptance suite: set SSAMB_SLOW=1")
def test_randomized_acceptance(tmp_path, cfg):
    """40 draws, every calibratable parameter perturbed uniformly by up to 5 %, one library
    effect (none in a quarter of the draws): at least 90 % pass every criterion."""
    n = int(os.environ.get("SSAMB_SUITE_DRAWS", "40"))
    k0 = int(os.environ.get("SSAMB_SUITE_START", "0"))        # to split the suite over processes
    log = _suite_out(tmp_path, "acceptance").with_suffix(".jsonl")
    out = []
    for k in range(k0, k0 + n):
        try:
            d = run_draw(tmp_path, cfg, k, with_effect=(k % 4 != 3))
        except Exception as exc:          # a crash is a failure of the draw, reported with the others
            d = {"draw": k, "failures": [f"crash: {type(exc).__name__}: {exc}"]}
        out.append(d)
        with open(log, "a") as fh:        # one line per draw as it ends
            fh.write(json.dumps(d) + "\n")
    rate = sum(not d["failures"] for d in out) / n
    _suite_out(tmp_path, "acceptance").write_text(json.dumps({"pass_rate": rate, "draws": out}, indent=1))
    assert rate >= 0.9, [(d["draw"], d["failures"]) for d in out if d["failures"]]


@pytest.mark.skipif(not SLOW, reason="randomized false alarms: set SSAMB_SLOW=1")
def test_randomized_false_alarms(tmp_path, cfg):
    """50 noise-only draws from the nominal model: the rate of declared effects stays at or below
    the configured significance level (alpha_accept, 1e-3: none of the 50)."""
    n = int(os.environ.get("SSAMB_SUITE_NULL_DRAWS", "50"))
    k0 = int(os.environ.get("SSAMB_SUITE_START", "0"))
    found = []
    for k in range(k0, k0 + n):
        arrays, meta, _ = rig(tmp_path, [], name=f"n{k}", exc={**EXC, "seed": 100 + k}, noise={**NOISE, "seed": 200 + k})
        found.append([e["name"] for e in analyse(arrays, meta, cfg, workers=WORKERS)["effects"]])
    rate = sum(bool(f) for f in found) / n
    _suite_out(tmp_path, "false_alarms").write_text(json.dumps({"rate": rate, "found": found}, indent=1))
    assert rate <= cfg["closeloop"]["alpha_accept"], found
