"""Acceptance tests of the close-the-loop analysis on rig data (issue 6).

Each library effect alone, with parameters drawn from the ranges any rig may have (one seeded
draw per effect in CI; ``SSAMB_SLOW=1`` runs a sweep of draws): the effect is ranked first by
the evidence and in the result, its main parameter is recovered (delay within 2 us, others
within 10 %) and the held-out rms residual drops by at least 50 % on every channel where it
stood clearly (3x) above the logging noise. Two effects at once are both found; noise alone
gives no effect; an external force the library cannot name is reported as unexplained.

Rig data: 1.2 s, multisine 5-100 Hz on both axes (30 um, 5 Hz lines, independent phases),
logging noise 30 nm on the positions and 0.3 mA on the currents (controller outputs are digital
and noise-free).
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from ssamb.closeloop import analyse
from ssamb.config import load_config
from ssamb.rig import load_scenario, rig_data

REPO = Path(__file__).resolve().parent.parent
EXC = {"kind": "multisine", "point": "position", "axis": "both", "amplitude_m": 3.0e-5, "f_min_hz": 5,
       "f_max_hz": 100, "f_resolution_hz": 5, "periods": 6, "seed": 3}
NOISE = {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 11}
NOISE_RMS = {"x_meas": 3e-8, "y_meas": 3e-8, "y_ss": 3e-8, "currents": 3e-4, "u_x": 0.0, "u_y": 0.0}
SEED = int(os.environ.get("SSAMB_TEST_SEED", "20260101"))
SLOW = bool(os.environ.get("SSAMB_SLOW"))
pytestmark = pytest.mark.slow     # every test here analyses a simulated rig record (tens of seconds)
#: measured failure, issue 13 open: see README "Status with the rig-like simulator"
REPLAY_FLOOR = pytest.mark.xfail(strict=True, reason=(
    "the rig-like simulator's self-sensed y loop depends sensitively on its state (a replay of the rig's own model "
    "with the mass changed by 1e-12 differs by half the rms of u_y: bench/replay_sensitivity.py) and the analysis "
    "still weighs that part of the residual as signal"))


@pytest.fixture(scope="module")
def cfg():
    return load_config()


# the paper's identification experiment: rectangular current pulses before the amplifiers
PULSES = {"kind": "pulses", "point": "current", "axis": "both", "amplitude_a": 0.3, "min_width_s": 2e-4,
          "max_width_s": 4e-3, "seed": 5}


def rig(tmp: Path, effects: list, name: str = "s", noise: dict = NOISE, exc: dict = EXC,
        duration_s: float | None = None):
    """Rig data (arrays, meta) for a scenario with ``effects``."""
    p = tmp / f"{name}.yaml"
    sc = {"config": str(REPO / "config.yaml"), "experiment": exc, "effects": effects, "noise": noise}
    if duration_s is not None:
        sc["duration_s"] = duration_s
    p.write_text(yaml.safe_dump(sc))
    return rig_data(load_scenario(p))


def draw(effect: str, rng: np.random.Generator) -> dict:
    """One effect with parameters drawn from the acceptance ranges."""
    if effect == "sensor_delay":
        return {"name": effect, "axis": str(rng.choice(["x", "y", "both"])), "delay_s": float(rng.uniform(5e-6, 100e-6))}
    if effect == "unbalance":
        f = float(rng.uniform(10.0, 200.0))
        force = float(rng.uniform(0.5, 10.0))
        return {"name": effect, "speed_hz": f, "mass_ecc_kgm": force / (2 * math.pi * f) ** 2,
                "phase_rad": float(rng.uniform(0, 2 * math.pi))}
    if effect == "static_load":
        f, a = float(rng.uniform(1.0, 20.0)), float(rng.uniform(0, 2 * math.pi))
        return {"name": effect, "fx_n": f * math.cos(a), "fy_n": f * math.sin(a)}
    if effect == "sensor_gain":
        # |g - 1| >= 0.005: a perfect sensor is no effect (the detection limit is far lower)
        g = float(rng.uniform(0.005, 0.2)) * float(rng.choice([-1.0, 1.0]))
        return {"name": effect, "axis": str(rng.choice(["x", "y", "both"])), "gain": 1.0 + g}
    if effect == "amplifier_deadtime":
        return {"name": effect, "deadtime_s": float(rng.uniform(0.2e-6, 2e-6))}
    if effect == "cross_coupling":
        return {"name": effect, "coefficient": float(rng.uniform(0.02, 0.2))}
    raise KeyError(effect)


def _params(rep: dict, name: str) -> list[dict]:
    return [e["params"] for e in rep["effects"] if e["name"] == name]


def check_recovered(true: dict, rep: dict) -> None:
    """The main parameter is recovered: delay within 2 us, the others within 10 %."""
    name = true["name"]
    got = _params(rep, name)
    assert got, f"{name} not found: {rep['summary']}"
    if name == "sensor_delay":
        axes = ("x", "y") if true["axis"] == "both" else (true["axis"],)
        for ax in axes:
            vals = [p["delay_s"] for p in got if p["axis"] in (ax, "both")]
            assert vals and abs(vals[0] - true["delay_s"]) < 2e-6, (ax, got, true)
    elif name == "sensor_gain":
        axes = ("x", "y") if true["axis"] == "both" else (true["axis"],)
        for ax in axes:
            vals = [p["gain"] for p in got if p["axis"] in (ax, "both")]
            assert vals and abs(vals[0] - true["gain"]) < 0.1 * true["gain"], (ax, got, true)
    elif name == "static_load":
        f = math.hypot(true["fx_n"], true["fy_n"])
        err = math.hypot(got[0]["fx_n"] - true["fx_n"], got[0]["fy_n"] - true["fy_n"])
        assert err < 0.1 * f, (got, true)
    elif name == "unbalance":
        assert abs(got[0]["speed_hz"] - true["speed_hz"]) < 0.1 * true["speed_hz"]
        assert abs(got[0]["mass_ecc_kgm"] / true["mass_ecc_kgm"] - 1) < 0.1, (got, true)
    elif name == "amplifier_deadtime":
        assert abs(got[0]["deadtime_s"] / true["deadtime_s"] - 1) < 0.1, (got, true)
    elif name == "cross_coupling":
        assert abs(got[0]["coefficient"] / true["coefficient"] - 1) < 0.1, (got, true)


def check_error_drop(rep: dict) -> dict:
    """Held-out rms drops >= 50 % on every channel that stood clearly (3x) above the noise."""
    drops = {}
    for c, noise in NOISE_RMS.items():
        before, after = rep["error_before"][c]["rms"], rep["error_after"][c]["rms"]
        if before > 3 * noise:
            drops[c] = 1 - after / before
            assert after <= 0.5 * before, (c, before, after)
    return drops


def run_case(tmp: Path, cfg, true: dict) -> dict:
    arrays, meta = rig(tmp, [true], name=true["name"])
    rep = analyse(arrays, meta, cfg)
    assert rep["ranking"] and rep["ranking"][0] == true["name"], (rep["ranking"], true)
    assert rep["effects"][0]["name"] == true["name"], rep["summary"]
    check_recovered(true, rep)
    check_error_drop(rep)
    return rep


EFFECTS = ["sensor_delay", "unbalance", "static_load", "sensor_gain", "amplifier_deadtime", "cross_coupling"]


@REPLAY_FLOOR
@pytest.mark.parametrize("effect", EFFECTS)
def test_each_library_effect_alone_is_found(tmp_path, cfg, effect):
    rng = np.random.default_rng([SEED, EFFECTS.index(effect)])
    true = draw(effect, rng)
    rep = run_case(tmp_path, cfg, true)
    assert len(rep["effects"]) <= 2, rep["summary"]


@REPLAY_FLOOR
def test_two_effects_at_once_are_both_found(tmp_path, cfg):
    effects = [{"name": "sensor_delay", "axis": "both", "delay_s": 2.0e-5},
               {"name": "unbalance", "speed_hz": 43.7, "mass_ecc_kgm": 3.0 / (2 * math.pi * 43.7) ** 2}]
    arrays, meta = rig(tmp_path, effects, name="two")
    rep = analyse(arrays, meta, cfg)
    found = {e["name"] for e in rep["effects"]}
    assert found == {"sensor_delay", "unbalance"}, rep["summary"]
    for true in effects:
        check_recovered(true, rep)
    check_error_drop(rep)
    assert rep["unexplained"] is False


@REPLAY_FLOOR
def test_noise_alone_declares_no_effect(tmp_path, cfg):
    arrays, meta = rig(tmp_path, [], name="null", noise={**NOISE, "seed": SEED % 1000})
    rep = analyse(arrays, meta, cfg)
    assert rep["effects"] == [] and rep["unexplained"] is False, rep["summary"]
    for c in ("x_meas", "y_meas", "y_ss"):
        assert abs(rep["error_before"][c]["rms"] / 3e-8 - 1) < 0.05


@REPLAY_FLOOR
def test_external_force_is_unexplained_not_named(tmp_path, cfg):
    t = np.arange(0.0, 1.4, 1e-4)
    fx = 2.0 * np.sin(2 * np.pi * 43.7 * t) + 1.5 * np.sin(2 * np.pi * 71.3 * t)
    np.savetxt(tmp_path / "f.csv", np.column_stack([t, fx, 0 * t]), delimiter=",", header="t,fx_n,fy_n", comments="")
    arrays, meta = rig(tmp_path, [{"name": "external_force", "file": str(tmp_path / "f.csv")}], name="ext")
    rep = analyse(arrays, meta, cfg)
    assert rep["effects"] == [], rep["summary"]
    assert rep["unexplained"] is True
    lines = rep["remaining_signature"]["line_not_excited"]
    freqs = sorted(round(ln["f_hz"], 1) for ln in lines)
    assert 43.7 in freqs and 71.3 in freqs, freqs


@pytest.mark.slow
@pytest.mark.skipif(not SLOW, reason="sweep of random draws: set SSAMB_SLOW=1")
@pytest.mark.parametrize("effect", EFFECTS)
@pytest.mark.parametrize("draw_no", range(8))
def test_sweep_of_draws(tmp_path, cfg, effect, draw_no):
    rng = np.random.default_rng([SEED, EFFECTS.index(effect), 1000 + draw_no])
    run_case(tmp_path, cfg, draw(effect, rng))


@REPLAY_FLOOR
def test_self_sensed_axis_under_current_pulses(tmp_path, cfg):
    """The paper's identification experiment (rectangular current pulses before the amplifiers)
    trips the self-sensing estimator's residual gate at every pulse edge, so the replay of y is
    a discontinuous function of the y sensor parameters (a local fit stops in a ripple of the
    cost, 1 us from the start): the global scan must still recover a y-axis delay."""
    true = {"name": "sensor_delay", "axis": "both", "delay_s": 3.0e-5}
    arrays, meta = rig(tmp_path, [true], name="pulses", exc=PULSES, duration_s=1.2)
    rep = analyse(arrays, meta, cfg)
    assert rep["ranking"][0] == "sensor_delay", rep["ranking"]
    check_recovered(true, rep)
    check_error_drop(rep)
    assert rep["unexplained"] is False, rep["summary"]


@REPLAY_FLOOR
def test_effect_without_a_significant_signature_is_found_by_fitting(tmp_path, cfg):
    """A y-only sensor delay under current pulses: the y ratio estimate is too imprecise for
    a significant signature, yet the time-domain residual is far above noise; fitting each
    library effect must find it, say so in the notes, and explain the residual."""
    true = {"name": "sensor_delay", "axis": "y", "delay_s": 5.0e-5}
    arrays, meta = rig(tmp_path, [true], name="pulses_y", exc=PULSES, duration_s=1.2)
    rep = analyse(arrays, meta, cfg)
    assert [e["name"] for e in rep["effects"]] == ["sensor_delay"], rep["summary"]
    check_recovered(true, rep)
    check_error_drop(rep)
    assert rep["effects"][0]["fit"]["without_signature"] is True
    assert any("no signature was significant" in n for n in rep["notes"])


@REPLAY_FLOOR
def test_effect_that_makes_the_rig_touch_the_backup_bearing(tmp_path, cfg):
    """A 10 % sensor gain error on both axes under current pulses destabilises the rig: the
    measured rotor reaches the backup bearing. The model with the right effect touches too; that
    must not count against it (only a model that touches when the rotor did not is implausible)."""
    true = {"name": "sensor_gain", "axis": "both", "gain": 1.1}
    arrays, meta = rig(tmp_path, [true], name="touch", exc=PULSES, duration_s=1.2)
    clearance = cfg["table1"]["backup_clearance_m"]
    assert np.max(np.hypot(arrays["x_meas"], arrays["y_meas"])) >= 0.95 * clearance
    rep = analyse(arrays, meta, cfg)
    assert rep["effects"] and rep["effects"][0]["name"] == "sensor_gain", rep["summary"]
    check_recovered(true, rep)
