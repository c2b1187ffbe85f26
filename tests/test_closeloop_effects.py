"""Close the loop on rigs that are not the model (issue 13): nominal parameters a few per cent
off, in-loop converter noise, logging noise, and library effects.

CI runs one analysis per case (marked slow), on a 1 s record (five periods of the demo's
multisine) with four replays per prediction:

* a sensor delay on a rig whose nominal parameters (eddy-current conductivity among them) are
  off: the delay is found, the identified parameters are recovered, nothing crashes;
* an unbalance spinning at an exact harmonic of the excitation period (the line sits on the
  grid of the periodic response): found;
* noise only, from the nominal model: no effect declared.

The randomized acceptance suite (experiments, parameters and effects drawn; noise-only draws) is
``bench/closeloop_suite.py``.
"""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml
from conftest import REPLAY_WORKERS as WORKERS

from ssamb.closeloop import analyse
from ssamb.config import get as _get, load_config
from ssamb.rig import SUITE_PERTURB as PERTURB, effective_truth, load_scenario, rig_data

REPO = Path(__file__).resolve().parent.parent
#: the demo's excitation (30 um multisine, 5-100 Hz lines every 5 Hz, both axes, independent phases)
#: over five periods instead of its ten (one discarded, two fitted, two held out)
EXC = {"kind": "multisine", "point": "position", "axis": "both", "amplitude_m": 3.0e-5, "f_min_hz": 5,
       "f_max_hz": 100, "f_resolution_hz": 5, "periods": 5, "seed": 3}
NOISE = {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 11}
SEED = 20260101
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def cfg():
    """The repository's config, four replays per prediction (the default eight halve the
    prediction's noise variance once more; these effects stand far above it)."""
    cfg = load_config()
    return {**cfg, "closeloop": {**cfg["closeloop"], "replay_seeds": 4}}


def rig(tmp: Path, effects: list, overrides: dict | None = None, name: str = "s", exc: dict = EXC,
        noise: dict = NOISE):
    """Rig data ``(arrays, meta, scenario)``: the rig's own parameters (``overrides``) and effects."""
    p = tmp / f"{name}.yaml"
    sc = {"config": str(REPO / "config.yaml"), "experiment": exc, "effects": effects, "noise": noise,
          "overrides": overrides or {}}
    p.write_text(yaml.safe_dump(sc))
    scenario = load_scenario(p)
    return (*rig_data(scenario), scenario)


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
